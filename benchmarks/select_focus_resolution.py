"""Choose the classical focus method's automatic working resolution (`aat_deploy.focus.scale`: STEP_MIN_PX and
SIDE_MIN_PX) on validation stacks, so that reducing the frames loses no accuracy.

    flock /work/heavy.lock nice -n 10 env OMP_WAIT_POLICY=PASSIVE python -m benchmarks.select_focus_resolution [--n 20]

Validation sets (never test stacks): procedural scenes textured with the *training* photographs, seeded apart
from every test set (the seed of benchmarks/select_focus_noise.py), each without and with sensor noise (8000 e- full
well): whole-sensor RF50 stacks (960 x 640, its working size) rendered through its PSF surrogate with 5, 8 and 16
frames over 0.5-10 m even in diopters (blur steps of about 18, 11 and 5 px), scored with the lens's best-focus map;
and a thin lens with the RF50's optics on a sensor of twice the pixels (1920 x 1280, 8 frames: a step of about
22 px; half as many scenes), scored with the thin-lens mapping. Method: the runtime's classical method with default settings, at the
native size and reduced by k (area averaging); the depth is enlarged back to the native grid bilinearly in diopters
and scored against the ground truth there (MAE, metres), so detail lost to the reduction counts as error.

1. The blur-step estimate (`blur_step_px`, from the native frames) against the thin-lens step of the set's
   schedule (the lens's blur-disk diameter per diopter times the frames' spacing).
2. Fixed reductions k: MAE and its paired ratio to k = 1 over scenes (95 % bootstrap), with the step left at
   the working size (estimated step / k).
3. The rule itself, k = min(step / T, longer side / L) (none below k = 1.25), for each candidate (T, L px):
   the paired MAE ratio to the native size over every validation stack. Chosen: among the candidates whose ratio
   is at most 1 + TOLERANCE in every (set, noise) cell, the one that reduces the most (largest mean k), and
   among equals the larger thresholds (where these sets do not decide, the more cautious rule).
Writes results/focus_resolution_selection.json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.eval.stats import N_BOOT, bootstrap_mean, paired_ratio
from benchmarks import RESULTS
from benchmarks.select_focus_noise import CONDITIONS, VAL_SEED

ROOT = Path(__file__).resolve().parents[1]


# (label, lens, PSF surrogate, simulator, frames, aberration-aware): the RF50 at its 960 x 640 working size through
# its PSFs, and a thin lens with the RF50's optics on a sensor of twice the pixels (1920 x 1280), thin-lens mapping
SETS = (("rf50 960", "lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", "aat", 5, True),
        ("rf50 960", "lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", "aat", 8, True),
        ("rf50 960", "lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", "aat", 16, True),
        ("thin 1920", "cache/lenses/ideal_thin_rf50_1920x1280.json", None, "thin_lens", 8, False))
FACTORS = (1.5, 2.0, 3.0, 4.0)
STEP_CANDIDATES = (2.0, 3.0, 4.0, 6.0, 8.0)
SIDE_CANDIDATES = (480, 640, 960, 1024, 1280)
TOLERANCE = 0.02  # "no accuracy lost": the paired MAE ratio to the native size at most 1.02 in every cell


def reduced_depth(stack: np.ndarray, focus_m: np.ndarray, fmap, k: float) -> np.ndarray:
    """Depth (H, W) at the native grid of the classical method run on the stack reduced by k."""
    import cv2

    from aat_deploy.focus import classical_depth

    s, _, h, w = stack.shape
    if k <= 1:
        return classical_depth(stack, focus_m, fmap).depth_m
    wh = (max(1, round(w / k)), max(1, round(h / k)))
    small = np.stack([cv2.resize(np.ascontiguousarray(f.transpose(1, 2, 0)), wh, interpolation=cv2.INTER_AREA)
                      .transpose(2, 0, 1) for f in stack])
    d = classical_depth(small, focus_m, fmap).depth_m
    inv = cv2.resize((1.0 / d).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    return 1.0 / np.maximum(inv, 1e-3)


def rule_factor(step_px: float | None, side: int, t: float, l: float) -> float:
    """k of the rule for candidate thresholds (the form of aat_deploy.focus.scale.working_factor)."""
    from aat_deploy.focus.scale import K_MIN

    if step_px is None:
        return 1.0
    k = min(step_px / t, side / l)
    return k if k >= K_MIN else 1.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=16, help="validation scenes per set and condition (half for "
                    "the 1920 x 1280 set)")
    ap.add_argument("--sets", default="", help="only these sets, e.g. 'rf50 960 8,thin 1920 8' (default all)")
    ap.add_argument("--out", type=Path, default=RESULTS / "focus_resolution_selection.json")
    a = ap.parse_args(argv)
    from tqdm import tqdm

    from aat_deploy.calibrate import thin_lens_defocus_scale_px_per_d
    from aat_deploy.focus.bestfocus import load_json, map_path_for_lens
    from aat_deploy.focus.scale import TileSampler, blur_step_px
    from aat_deploy.io.atomic import write_text_atomic
    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.paraxial import paraxial_data
    from training.train.testsets import TestSetSpec, load_test_set

    thin = ROOT / SETS[-1][1]
    if not thin.is_file():  # the thin lens at twice the pixels: written once into cache/
        from dataclasses import replace

        from aat_deploy.lens.io import save_lens

        ideal = load_lens(ROOT / "lenses/ideal_thin_rf50.json")
        thin.parent.mkdir(parents=True, exist_ok=True)
        save_lens(replace(ideal, sensor=ideal.sensor.with_resolution(1920, 1280)), thin)
    wanted = {s.strip() for s in a.sets.split(",")} if a.sets else None
    cands = [(t, l) for t in STEP_CANDIDATES for l in SIDE_CANDIDATES]
    cells, rule_rows = {}, {c: [] for c in cands}
    for label, lens_path, psf, simulator, size, aware in SETS:
        if wanted is not None and f"{label} {size}" not in wanted:
            continue
        lens = load_lens(ROOT / lens_path)
        par = paraxial_data(lens)
        fmap = load_json(map_path_for_lens(ROOT / lens_path)) if aware else None
        for cond, fx in CONDITIONS.items():
            n = a.n if label.startswith("rf50") else max(2, a.n // 2)  # 1920 x 1280 renders take 8x longer
            spec = TestSetSpec(lens_path, psf, size, n_procedural=n, middlebury=False, simulator=simulator,
                               seed=VAL_SEED, photo_split="train", effects=fx)
            items = load_test_set(spec, str(ROOT / "cache/heldout"), progress=True)["procedural"]
            name = f"{label}, {size} frames, {cond}"
            per = {k: [] for k in (1.0, *FACTORS)}
            steps, thin_steps = [], []
            rule = {c: [] for c in cands}
            for it in tqdm(items, desc=f"{name}: scoring", unit="stack"):
                s, _, h, w = it.stack.shape
                frames = [f.transpose(1, 2, 0) for f in it.stack]
                sampler = TileSampler.for_size((h, w))
                step, _ = blur_step_px([np.stack(lev) for lev in zip(*(sampler.sample(f) for f in frames))])
                spacing = float(np.mean(np.abs(np.diff(1.0 / it.focus_m))))
                k_px = thin_lens_defocus_scale_px_per_d(par.efl_mm, par.fno, lens.sensor.pixel_mm * 1000,
                                                        float(np.median(it.focus_m)))
                steps.append(np.nan if step is None else step)
                thin_steps.append(k_px * spacing)
                valid = it.depth_m > 0
                cache: dict[float, float] = {}

                def mae(k: float) -> float:
                    key = round(k, 2)
                    if key not in cache:
                        d = reduced_depth(it.stack, it.focus_m, fmap, key)
                        cache[key] = float(np.abs(d - it.depth_m)[valid].mean())
                    return cache[key]

                for k in per:
                    per[k].append({"mae": mae(k)})
                for c in cands:
                    k = rule_factor(step, max(h, w), *c)
                    rule[c].append({"mae": mae(k), "k": k})
            base = per[1.0]
            est = np.array(steps)
            cells[name] = {
                "step_estimated_px": [float(np.nanmedian(est)), float(np.nanpercentile(est, 10)),
                                      float(np.nanpercentile(est, 90))],
                "step_unmeasured": int(np.isnan(est).sum()),
                "step_thin_lens_px": float(np.median(thin_steps)),
                "fixed": {str(k): {"mae": list(bootstrap_mean([p["mae"] for p in v], n_boot=N_BOOT,
                                                                 seed=1)),
                                   "ratio": paired_ratio(v, base), "step_at_working_px": float(np.nanmedian(est) / k),
                                   "side_px": round(max(it.stack.shape[2:]) / k)} for k, v in per.items()},
                "rule": {f"{t:g},{l}": {"ratio": paired_ratio(rule[(t, l)], base),
                                        "mean_k": float(np.mean([r["k"] for r in rule[(t, l)]]))}
                         for t, l in cands},
            }
            for c in cands:
                rule_rows[c].append(cells[name]["rule"][f"{c[0]:g},{c[1]}"])

    ok = [c for c in cands if all(r["ratio"][0] <= 1 + TOLERANCE for r in rule_rows[c])]
    mean_k = {c: float(np.mean([r["mean_k"] for r in rule_rows[c]])) for c in cands}
    # the most reduction; among equals the larger thresholds (the more cautious rule where these sets do not decide)
    chosen = max(ok, key=lambda c: (round(mean_k[c], 3), c[0], c[1])) if ok else None

    print(f"\n#### Blur step: estimated from the frames vs the thin-lens step of the schedule ({a.n} validation "
          f"stacks per cell, {max(2, a.n // 2)} at 1920 x 1280)\n")
    print("| set | estimated, median [10 %, 90 %] px | thin-lens px | not measurable |")
    print("|---|---|---|---|")
    for name, c in cells.items():
        e = c["step_estimated_px"]
        print(f"| {name} | {e[0]:.1f} [{e[1]:.1f}, {e[2]:.1f}] | {c['step_thin_lens_px']:.1f} | "
              f"{c['step_unmeasured']} |")
    print("\n#### Fixed reductions: depth MAE (m) at the native grid [95 % CI], paired ratio to the native size\n")
    print("| set | " + " | ".join(f"k = {k:g}" for k in (1.0, *FACTORS)) + " |")
    print("|---|" + "---|" * (len(FACTORS) + 1))
    for name, c in cells.items():
        row = []
        for k in (1.0, *FACTORS):
            f = c["fixed"][str(k)]
            cell = f"{f['mae'][0]:.3f}"
            if k > 1:
                cell += (f", {f['ratio'][0]:.2f}× [{f['ratio'][1]:.2f}, {f['ratio'][2]:.2f}]; step "
                         f"{f['step_at_working_px']:.1f} px, {f['side_px']} px")
            row.append(cell)
        print(f"| {name} | " + " | ".join(row) + " |")
    print(f"\n#### The rule k = min(step / T, longer side / L): largest paired MAE ratio to the native size over the "
          f"{len(cells)} cells, and the mean k\n")
    print("| T px \\ L px | " + " | ".join(str(l) for l in SIDE_CANDIDATES) + " |")
    print("|---|" + "---|" * len(SIDE_CANDIDATES))
    for t in STEP_CANDIDATES:
        row = []
        for l in SIDE_CANDIDATES:
            worst = max(r["ratio"][0] for r in rule_rows[(t, l)])
            row.append(f"{worst:.3f} (k {mean_k[(t, l)]:.2f})" + (" **chosen**" if chosen == (t, l) else ""))
        print(f"| {t:g} | " + " | ".join(row) + " |")
    print(f"\nchosen: STEP_MIN_PX = {chosen[0]:g}, SIDE_MIN_PX = {chosen[1]}" if chosen else
          "\nno candidate keeps every cell within the tolerance")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(a.out, json.dumps({"n": a.n, "seed": VAL_SEED, "tolerance": TOLERANCE, "cells": cells,
                                         "chosen": None if chosen is None else {"step_min_px": chosen[0],
                                                                                "side_min_px": chosen[1]}},
                                        indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
