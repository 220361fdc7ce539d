"""How much of each held-out test set lies beyond its focus sweep at its own pixel (exploratory on test stacks;
on validation stacks, step 2 of the fourteenth run's declared rule, docs/training.md).

    python -m benchmarks.probes.sweep_reach [--lenses paper50 ef50 z35 rf50] [--protocol fixed paper]
        [--cache cache/heldout] [--out results/sweep_reach.json] [--score MODEL.onnx [OTHER.onnx]]
    [--split test|validation]

A depth-from-focus method can place a pixel only between the nearest and the farthest object distance some frame
has in focus there. With a lens's map those limits are per pixel (`FocusMapping.frame_diopters`): field curvature
moves them off-axis. This counts, per test stack, the share of pixels with known depth whose true object diopters
lie beyond the pixel's limits by more than half the sweep's mean frame spacing there, so that no frame has them
within half a spacing of focus, and prints the mean over stacks (procedural and real) with the 5th-95th percentile.
With --score, `dfv_aat` (MODEL, given the lens map) and the classical method given the same map are also scored on
the procedural stacks' pixels within reach and beyond it separately: MAE over the classical method's, paired
bootstrap over scenes (bench_table2's). Analysis of where the stacks hold the answer, not a replacement target.
With a second model, MODEL's MAE over OTHER's within reach and beyond, paired over the same stacks.
`--split validation` uses validation stacks instead (RF50 only, training photographs, their own seed, no real
scene): what may give a reason to change a model.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks import RESULTS
from benchmarks.bench_anycam import LENSES, ROOT, test_spec


def beyond_share(depth_m: np.ndarray, frame_d: np.ndarray) -> dict:
    """depth_m (H, W) metres (0 = unknown), frame_d (S, H, W) each frame's in-focus object diopters at each pixel.
    Shares of the known pixels nearer than the nearest frame's focus and farther than the farthest's by more than
    half the pixel's mean frame spacing."""
    known = depth_m > 0
    true_d = np.where(known, 1.0 / np.where(known, depth_m, 1.0), np.nan)
    beyond = beyond_mask(depth_m, frame_d)
    near = beyond & (true_d > frame_d.max(0))
    n = max(int(known.sum()), 1)
    return {"too_near": float(near.sum() / n), "too_far": float((beyond & ~near).sum() / n)}


def beyond_mask(depth_m: np.ndarray, frame_d: np.ndarray) -> np.ndarray:
    """(H, W) bool: known pixels beyond the sweep (beyond_share's definition)."""
    known = depth_m > 0
    true_d = np.where(known, 1.0 / np.where(known, depth_m, 1.0), np.nan)
    lo, hi = frame_d.min(0), frame_d.max(0)
    half = 0.5 * (hi - lo) / max(frame_d.shape[0] - 1, 1)
    return known & ((true_d > hi + half) | (true_d < lo - half))


def split_mae(pred_m: np.ndarray, depth_m: np.ndarray, beyond: np.ndarray) -> dict:
    """MAE (m) over the known pixels within reach and beyond it (NaN where a part is empty)."""
    err = np.abs(pred_m - depth_m)
    within = (depth_m > 0) & ~beyond
    return {"within": float(err[within].mean()) if within.any() else float("nan"),
            "beyond": float(err[beyond].mean()) if beyond.any() else float("nan")}


def score_split(model_paths: list[Path], lens_key: str, mapping, items) -> list[dict]:
    """Per procedural stack: each method's MAE within reach and beyond: dfv_aat ("dfv"; a second model "other") and
    the classical method (lens map all) and the lens-specific net where one exists ("specific")."""
    from benchmarks.bench_anycam import CL_MAP, DFV_MAP, methods

    fns = methods(model_paths[0], lens_key, threads=1)
    fns = {"dfv": fns[DFV_MAP], "classical": fns[CL_MAP],
           **{"specific": fns[lab] for lab in LENSES[lens_key]["specific"] if lab in fns}}
    if len(model_paths) > 1:
        fns["other"] = methods(model_paths[1], lens_key, threads=1)[DFV_MAP]
    rows = []
    for it in items:
        h, w = it.depth_m.shape
        beyond = beyond_mask(it.depth_m, mapping.frame_diopters(it.focus_m, h, w))
        rows.append({k: split_mae(fn(it)[0], it.depth_m, beyond) for k, fn in fns.items()})
    return rows


def main(argv: list[str] | None = None) -> int:
    from aat_deploy.anycam.model import mapping_from_args
    from training.data.registry_rgbd import SCENES as REGISTRY
    from training.train.testsets import load_test_set

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lenses", nargs="+", default=list(LENSES), choices=list(LENSES))
    ap.add_argument("--protocol", nargs="+", default=["fixed", "paper"], choices=["fixed", "paper"])
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"))
    ap.add_argument("--out", type=Path, default=RESULTS / "sweep_reach.json")
    ap.add_argument("--split", choices=("test", "validation"), default="test")
    ap.add_argument("--score", type=Path, nargs="+", default=None, metavar="MODEL",
                    help="a dfv_aat ONNX file to score within and beyond reach (a second: paired against it)")
    a = ap.parse_args(argv)
    if a.split == "validation" and a.lenses != ["rf50"]:
        ap.error("--split validation: the RF50 only (the held-out lenses choose nothing)")
    scored = {}
    out = {}
    print("| lens | protocol | stacks | beyond the sweep, lens map: mean [5th, 95th pct] | the same, thin lens |")
    print("|---|---|---|---|---|")
    for lens_key in a.lenses:
        mapping = mapping_from_args(lens=ROOT / LENSES[lens_key]["lens"])
        for protocol in a.protocol:
            spec = dataclasses.replace(test_spec(lens_key, protocol, a.n), registry_real=REGISTRY)
            if a.split == "validation":
                from benchmarks.select_focus_noise import VAL_SEED

                spec = dataclasses.replace(spec, seed=VAL_SEED, photo_split="train", middlebury=False, nyu=False,
                                           registry_real=())
            items = load_test_set(spec, a.cache, progress=False)
            rows = {}
            for kind, its in items.items():
                for it in its:
                    h, w = it.depth_m.shape
                    fd = mapping.frame_diopters(it.focus_m, h, w)
                    thin = np.broadcast_to((1.0 / np.asarray(it.focus_m))[:, None, None], fd.shape)
                    rows[it.name] = {"lens_map": beyond_share(it.depth_m, fd), "thin": beyond_share(it.depth_m, thin)}
            out.setdefault(lens_key, {})[protocol] = rows
            cells = []
            for m in ("lens_map", "thin"):
                v = np.array([r[m]["too_near"] + r[m]["too_far"] for r in rows.values()])
                cells.append(f"{v.mean():.3f} [{np.percentile(v, 5):.3f}, {np.percentile(v, 95):.3f}]")
            print(f"| {lens_key} | {protocol} | {len(rows)} | {cells[0]} | {cells[1]} |", flush=True)
            if a.score is not None:
                scored.setdefault(lens_key, {})[protocol] = score_split(a.score, lens_key, mapping,
                                                                        items["procedural"])
    if scored:
        from aat_deploy.eval.stats import fmt_interval, paired_ratio

        print("\n| lens | protocol | part | dfv_aat MAE (m) | classical MAE (m) | dfv / classical [95 %] | lens-specific "
              "net MAE (m) | dfv / lens-specific [95 %] | second model MAE (m) | dfv / second [95 %] |\n"
              + "|---" * 10 + "|")
        for lens_key, by in scored.items():
            for protocol, per in by.items():
                for part in ("within", "beyond"):
                    use = [r for r in per if np.isfinite(r["dfv"][part])]
                    if len(use) < 2:
                        continue
                    got = {"n": len(use), "mae_m": {k: float(np.mean([r[k][part] for r in use])) for k in use[0]}}
                    cells = []
                    for ref in ("classical", "specific", "other"):
                        if ref not in use[0]:
                            cells += ["–", "–"]
                            continue
                        ratio = paired_ratio([{"mae": r["dfv"][part]} for r in use],
                                             [{"mae": r[ref][part]} for r in use])
                        got[ref] = ratio
                        cells += [f"{np.mean([r[ref][part] for r in use]):.3f}", fmt_interval(ratio, 2)]
                    out[lens_key][protocol + "_" + part] = got
                    print(f"| {lens_key} | {protocol} | {part} ({len(use)} stacks) | "
                          f"{np.mean([r['dfv'][part] for r in use]):.3f} | " + " | ".join(cells) + " |")
        out["scored_models"] = [str(p) for p in a.score]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(a.out, json.dumps(out, indent=1))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
