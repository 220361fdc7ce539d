"""Classical depth from focus (aat_deploy.focus, `aat-infer --method focus`) on held-out stacks: which focus measure
and estimator, thin-lens vs aberration-aware focus mapping, next to the shipped learned models, and its speed.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_focus --lens rf50 [--n 32] [--variants] [--speed] [--threads 2]
    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_focus --lens paper50 [--n 32]

Test stacks: `training.train.testsets` (the cache every DfF benchmark shares), the "fixed" protocol: 8 frames even in
diopters over 0.5-10 m, never looking at the scene; `--n` held-out procedural scenes (photo textures of the test
split, random depth ranges) and Middlebury 2014 Motorcycle, all rendered through the lens's PSF surrogate at its
full sensor. Depth in metres from the sensor over valid ground truth; per scene MAE, AbsRel, delta1 overall, in the
centre (field radius < 0.33) and the outer field (> 0.66), the zones of `aat_deploy.eval.stats` (circular radius over
the half-diagonal, 1 = corner); the mean over scenes with a 95 % bootstrap interval over scenes (`summarise`);
Middlebury is one scene: its interval resamples 16 px tiles (`ratio_bootstrap`). "AA / thin" rows: the ratio of
mean MAEs with a paired bootstrap over scenes (`paired_ratio`).

Mappings: thin lens (each frame in focus at its nominal distance), aberration-aware traced (the lens's best-focus
map, min RMS spot) and aberration-aware calibrated (plus the offset measured on rendered stacks), both from
`<lens folder>/best_focus/<lens stem>.json` (`aat-lens focus-map LENS`). Learned models: models/reproduce/dff_dfvnet_*.onnx
(RF50 only), run as aat-infer runs them.
--variants: the measure / estimator / window / filling comparison (thin-lens mapping, RF50 procedural scenes).
--speed: one 8 x 3 x 640 x 960 stack, best of 5, `--threads` (default 2), thin-lens vs aberration-aware (same run).
--calibration: only print the lens's stored calibration (where the focus measure peaks vs the traced min-RMS best
focus, measured by `aat-lens focus-map` on rendered stacks) as a table; no stacks.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from aat_deploy.eval.stats import (  # the statistics of every DfF table
    N_BOOT,
    bootstrap_mean,
    fmt_interval,
    paired_ratio,
    ratio_bootstrap,
    summarise,
    zone_masks,
)
from aat_deploy.io.atomic import write_text_atomic
from benchmarks import RESULTS
from training.train.testsets import LENSES

ROOT = Path(__file__).resolve().parents[1]

ZONES = ("all", "centre", "outer")
KEYS = ("mae", "abs_rel", "delta1")


def load_items(lens: str, n: int):
    from training.train.testsets import TestSetSpec, load_test_set

    path, psf = LENSES[lens]["lens"], LENSES[lens]["psf"]
    return load_test_set(TestSetSpec(path, psf, 8, protocol="fixed", n_procedural=n), str(ROOT / "cache/heldout"))


def score(depth_m: np.ndarray, gt_m: np.ndarray) -> dict:
    """Per-scene {zone_key: value} for KEYS over ZONES."""
    from aat_deploy.metrics import depth_metrics

    masks = {"all": None, **zone_masks(*gt_m.shape)}
    out = {}
    for z in ZONES:
        m = depth_metrics(depth_m, gt_m, mask=masks[z])
        for k in KEYS:
            out[f"{z}_{k}"] = m[k]
    return out


def tile_interval(depth_m: np.ndarray, gt_m: np.ndarray) -> dict:
    """One scene: {zone_key: [mean, lo, hi]} with a tile bootstrap (`ratio_bootstrap`)."""
    masks = {"all": np.ones(gt_m.shape, bool), **zone_masks(*gt_m.shape)}
    valid = np.isfinite(gt_m) & (gt_m > 0)
    g = np.where(valid, gt_m, 1.0)
    err = np.abs(depth_m - g)
    ratio = np.maximum(depth_m / g, g / np.maximum(depth_m, 1e-6))
    per = {"mae": err, "abs_rel": err / g, "delta1": (ratio < 1.25).astype(np.float64)}
    out = {}
    for z in ZONES:
        ok = valid & masks[z]
        for k in KEYS:
            num = np.where(ok, per[k], np.nan)
            out[f"{z}_{k}"] = list(ratio_bootstrap([num], [np.where(ok, 1.0, np.nan)], n_boot=N_BOOT, seed=1))
    return out


def table(rows: list[tuple[str, dict]]) -> str:
    head = ("| method | MAE (m) | AbsRel | δ1 | MAE centre | AbsRel centre | δ1 centre | MAE outer | AbsRel outer "
            "| δ1 outer |\n|---|" + "---|" * 9)
    lines = [head]
    for lab, s in rows:
        lines.append(f"| {lab} | " + " | ".join(fmt_interval(s[f'{z}_{k}']) for z in ZONES for k in KEYS) + " |")
    return "\n".join(lines)


def classical(items, cfg, fmap=None, volumes=None) -> list[tuple]:
    """[(depth_m, aif)] of classical_depth on every item (volumes: precomputed focus volumes, same measure)."""
    from aat_deploy.focus import classical_depth

    out = []
    for i, it in enumerate(items):
        r = classical_depth(it.stack, it.focus_m, fmap, cfg, volume=None if volumes is None else volumes[i])
        out.append((r.depth_m, r.aif))
    return out


def run_variants(items) -> list[tuple[str, dict]]:
    """Measure x estimator (no filling), window, pre-filter, filling and AiF blending: thin-lens mapping; every row
    with the default pre-filter but the one that drops it."""
    from aat_deploy.focus import FocusConfig
    from aat_deploy.focus.measures import MEASURES, focus_volume
    from aat_deploy.metrics import psnr

    rows = []
    base = FocusConfig()
    for meas in MEASURES:
        vols = [focus_volume(it.stack, meas, base.window_px, prefilter_px=base.prefilter_px) for it in items]
        for est in ("argmax", "parabola", "gauss", "ratio"):
            cfg = replace(base, measure=meas, estimator=est, fill="none")
            res = classical(items, cfg, volumes=vols)
            rows.append((f"{meas}, {est}, no filling", summarise([score(d, it.depth_m) for (d, _), it in zip(res, items)])))
            print(f"  variant {rows[-1][0]}: MAE {rows[-1][1]['all_mae'][0]:.3f}", file=sys.stderr, flush=True)
        del vols
    for w in (w for w in (5.0, 9.0, 15.0) if w != base.window_px):
        cfg = replace(base, window_px=w, fill="none")
        res = classical(items, cfg)
        rows.append((f"{base.measure}, {base.estimator}, window {w:g} px, no filling",
                     summarise([score(d, it.depth_m) for (d, _), it in zip(res, items)])))
    if base.prefilter_px:
        res = classical(items, replace(base, prefilter_px=0.0, fill="none"))
        rows.append((f"{base.measure}, {base.estimator}, no pre-filter, no filling",
                     summarise([score(d, it.depth_m) for (d, _), it in zip(res, items)])))
    for fill in ("fill",):
        res = classical(items, replace(base, fill=fill))
        rows.append((f"{base.measure}, {base.estimator}, edge-aware filling",
                     summarise([score(d, it.depth_m) for (d, _), it in zip(res, items)])))
    aif_rows = []
    for mode in ("weights", "peak"):
        res = classical(items, replace(base, aif=mode, fill="none"))
        p = [psnr(np.clip(a, 0, 1), np.clip(it.aif, 0, 1)) for (_, a), it in zip(res, items)]

        aif_rows.append((mode, list(bootstrap_mean(p, n_boot=N_BOOT, seed=1))))
    return rows, aif_rows


def run_models(items, threads: int = 2) -> list[tuple[str, list]]:
    from aat_deploy.infer.model import DfFModel

    out = []
    for name in ("dff_dfvnet_aat", "dff_dfvnet_thin"):
        path = ROOT / "models" / "reproduce" / f"{name}.onnx"
        if not path.is_file():
            continue
        m = DfFModel(path, threads=threads)
        label = f"learned: DFVNet {'AAT' if name.endswith('aat') else 'thin-lens'} training ({path.name})"
        out.append((label, [(m.infer(it.stack, it.focus_m).depth_m, None) for it in items]))
    return out


def speed(items, fmap, threads: int = 2) -> list[str]:
    import cv2

    from aat_deploy.focus import FocusConfig, classical_depth

    cv2.setNumThreads(threads)
    it = items[0]
    lines = ["| mapping | stack | time (best of 5) | measure | placement | estimate | aif | fill | spread |",
             "|---|---|---|---|---|---|---|---|---|"]
    best = {}
    for lab, m in (("thin lens", None), ("aberration-aware", fmap)):
        if lab != "thin lens" and m is None:
            continue
        runs = []
        for _ in range(5):
            t = time.perf_counter()
            r = classical_depth(it.stack, it.focus_m, m, FocusConfig())
            runs.append((time.perf_counter() - t, r.info["timings_s"]))
        dt, tim = min(runs, key=lambda x: x[0])
        best[lab] = dt
        s = it.stack.shape
        lines.append(f"| {lab} | {s[0]} × {s[1]} × {s[2]} × {s[3]} | {dt:.3f} s | "
                     + " | ".join(f"{tim[k]:.3f}" for k in ("measure", "placement", "estimate", "aif", "fill", "spread"))
                     + " |")
    if len(best) == 2:
        lines.append(f"\naberration-aware / thin lens: {best['aberration-aware'] / best['thin lens']:.3f}")
    return lines


def calibration_table(fmap) -> str:
    """The map's calibration points: field curvature by the traced min-RMS focus and by the measure's peak."""
    pts = fmap.notes.get("calibration_points") or []
    lines = ["| field radius | frame focus (m) | traced best focus − frame (D) | focus-measure peak − frame (D) "
             "| offset (D) |", "|---|---|---|---|---|"]
    for p in pts:
        if not np.isfinite(p.get("offset_diopters", float("nan"))):
            continue
        traced = p["traced_object_diopters"] - 1 / p["focus_m"]
        lines.append(f"| {p['r']:.2f} | {p['focus_m']:g} | {traced:+.3f} | {traced + p['offset_diopters']:+.3f} "
                     f"| {p['offset_diopters']:+.3f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", choices=sorted(LENSES), required=True)
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--variants", action="store_true")
    ap.add_argument("--speed", action="store_true")
    ap.add_argument("--calibration", action="store_true", help="print the stored calibration only")
    ap.add_argument("--threads", type=int, default=2,
                    help="threads of the learned models (onnxruntime) and of --speed (OpenCV)")
    ap.add_argument("--out", default=str(RESULTS))
    a = ap.parse_args(argv)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from aat_deploy.focus import FocusConfig
    from aat_deploy.focus.bestfocus import load_json, map_path_for_lens

    lens_path = ROOT / LENSES[a.lens]["lens"]
    mp = map_path_for_lens(lens_path)
    fmap = load_json(mp) if mp.is_file() else None
    if fmap is None:
        print(f"no best-focus map {mp}: only the thin-lens mapping (make it with aat-lens focus-map LENS)",
              file=sys.stderr)
    if a.calibration:
        if fmap is None:
            raise SystemExit(f"no best-focus map {mp}")
        cal = fmap.notes.get("calibration", {})
        print(f"### {a.lens}: where the focus measure peaks ({cal.get('measure')}, window {cal.get('window_px')} px, "
              f"pre-filter {cal.get('prefilter_px', 0)} px) vs the traced best focus\n")
        print(calibration_table(fmap))
        return 0
    sets = load_items(a.lens, a.n)
    result = {"lens": a.lens, "n": a.n, "config": FocusConfig().__dict__, "sets": {}}
    if a.speed:
        lines = speed(sets["procedural"], fmap, a.threads)
        print(f"\n### Speed ({a.threads} thread{'s' if a.threads > 1 else ''})\n\n" + "\n".join(lines))
        result["speed"] = lines
    if a.variants:
        rows, aif_rows = run_variants(sets["procedural"])
        print(f"\n### Variants ({a.lens}, procedural, {len(sets['procedural'])} stacks, thin-lens mapping)\n")
        print(table(rows))
        print("\n| AiF blending | PSNR (dB) vs the ground-truth all-in-focus |\n|---|---|")
        for mode, v in aif_rows:
            print(f"| {mode} | {fmt_interval(v, 2)} |")
        result["variants"] = dict(rows)
        result["aif"] = dict(aif_rows)
    for sname, items in sets.items():
        methods = [("classical, thin-lens mapping", classical(items, FocusConfig()))]
        if fmap is not None:
            methods.append(("classical, aberration-aware (traced)",
                            classical(items, replace(FocusConfig(), calibrated=False), fmap)))
            if fmap.offset_diopters is not None:
                methods.append(("classical, aberration-aware (calibrated)", classical(items, FocusConfig(), fmap)))
        if a.lens == "rf50":
            methods += run_models(items, a.threads)
        per = {lab: [score(d, it.depth_m) for (d, _), it in zip(res, items)] for lab, res in methods}
        if len(items) > 1:
            rows = [(lab, summarise(p)) for lab, p in per.items()]
        else:
            rows = [(lab, tile_interval(res[0][0], items[0].depth_m)) for lab, res in methods]
        print(f"\n### {a.lens}: {sname}, {len(items)} stack{'s' if len(items) > 1 else ''} "
              f"({'95 % bootstrap over scenes' if len(items) > 1 else '95 % tile bootstrap, one scene'})\n")
        print(table(rows))
        ratios = {}
        if len(items) > 1:
            thin = per["classical, thin-lens mapping"]
            for lab in per:
                if lab.startswith("classical, aberration-aware"):
                    ratios[lab] = {z: paired_ratio(per[lab], thin, f"{z}_mae") for z in ZONES}
            if ratios:
                print("\n| MAE ratio, aberration-aware / thin-lens mapping (paired over scenes) | all | centre "
                      "| outer |\n|---|---|---|---|")
                for lab, r in ratios.items():
                    print(f"| {lab} | " + " | ".join(fmt_interval(r[z]) for z in ZONES) + " |")
        result["sets"][sname] = {"rows": dict(rows), "ratios": ratios, "per_scene": per}
    out = Path(a.out) / f"focus_{a.lens}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps(result, indent=1, default=float))
    print(f"\nwrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
