"""Choose the classical focus method's pre-filter (`FocusConfig.prefilter_px`) and peak estimator together, on
validation stacks, not test ones.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.select_focus_noise [--n 20] [--sigmas 0,0.5,0.75,1,1.5,2,3]

Why: the focus measures are high-pass, so sensor noise dominates them wherever a frame is out of focus
(benchmarks/probes/classical_noise.py looked at it on test scenes; this script is the one that chooses). A
pre-filter also changes the shape of the focus curve near its peak, which the sub-frame estimators model (the
`ratio` estimator assumes power-law tails, `gauss` a Gaussian peak), so the two are chosen jointly.

Validation sets: whole-sensor stacks of each shipped lens (rf50: 8 frames, paper50: 10 frames, the fixed schedule
of bench_table2) rendered through its PSF surrogate, procedural scenes textured with the *training* photographs and
seeded apart from every test set (`TestSetSpec(photo_split="train", seed=VAL_SEED)`), each in three conditions:
clean, with the `noise` effect (Poisson-Gaussian, 8000 e- full well, 3 e- read noise), and `phone`: that noise then
a typical phone's processing (the `phone_jpeg` effect at its defaults: local tone mapping 0.4, denoising 0.03,
unsharp masking 0.8 at 1 px, JPEG quality 90 with 4:2:0). Method: the runtime's classical method with
the lens's best-focus map (aberration-aware, as `aat-infer --method focus --lens` runs it), every other setting at
its default. Depth MAE in metres from the sensor over valid ground truth, mean over scenes with a 95 % bootstrap
interval; each cell's ratio to the reference (`ratio` estimator, no pre-filter: the defaults before this choice) is
paired over scenes.

Choice: the (estimator, sigma) with the lowest geometric mean, over the six (lens, condition) cells, of the MAE ratio
to the reference (scale-free, so each lens and condition weighs alike). Writes
results/focus_noise_selection.json.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from aat_deploy.eval.stats import N_BOOT, bootstrap_mean, paired_ratio
from benchmarks import RESULTS
from training.train.testsets import LENSES

ROOT = Path(__file__).resolve().parents[1]

VAL_SEED = 424242  # apart from the test sets' 777777 and from every training seed
CONDITIONS = {"clean": (), "noise": ("noise",), "phone": ("noise", "phone_jpeg")}
ESTIMATORS = ("ratio", "gauss")
REFERENCE = ("ratio", 0.0)


def choose(ratios: dict[str, dict[tuple, float]]) -> tuple[tuple, dict[tuple, float]]:
    """ratios {cell: {variant: MAE ratio to the reference}} -> (best variant, {variant: geometric mean over cells});
    ties go to the first variant in sorted order."""
    variants = sorted(next(iter(ratios.values())))
    gm = {v: float(np.exp(np.mean([np.log(r[v]) for r in ratios.values()]))) for v in variants}
    return min(variants, key=lambda v: gm[v]), gm


def name(v: tuple) -> str:
    return f"{v[0]}, σ {v[1]:g} px"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=20, help="validation scenes per lens and condition")
    ap.add_argument("--sigmas", default="0,0.5,0.75,1,1.5,2,3", help="pre-filter sigmas (px), comma-separated")
    ap.add_argument("--lenses", default="rf50,paper50")
    ap.add_argument("--out", type=Path, default=RESULTS / "focus_noise_selection.json")
    a = ap.parse_args(argv)
    try:
        sigmas = sorted({float(s) for s in a.sigmas.split(",")} | {0.0})
    except ValueError:
        ap.error(f"--sigmas must be numbers separated by commas, got {a.sigmas!r}")
    if not all(0 <= s <= 50 for s in sigmas):
        ap.error(f"--sigmas must lie between 0 and 50 px, got {a.sigmas!r}")
    unknown = set(a.lenses.split(",")) - set(LENSES)
    if unknown:
        ap.error(f"--lenses: unknown {', '.join(sorted(unknown))} (one of {', '.join(sorted(LENSES))})")
    variants = [(e, s) for e in ESTIMATORS for s in sigmas]
    from tqdm import tqdm

    from aat_deploy.focus import FocusConfig, classical_depth
    from aat_deploy.focus.bestfocus import load_json, map_path_for_lens
    from aat_deploy.focus.measures import focus_volume
    from aat_deploy.io.atomic import write_text_atomic
    from training.train.testsets import TestSetSpec, load_test_set

    base = FocusConfig()
    table, ratios = {}, {}
    for lens in a.lenses.split(","):
        spec_l = LENSES[lens]
        fmap = load_json(map_path_for_lens(ROOT / spec_l["lens"]))
        for cond, fx in CONDITIONS.items():
            spec = TestSetSpec(spec_l["lens"], spec_l["psf"], spec_l["stack_size"], n_procedural=a.n, middlebury=False,
                               seed=VAL_SEED, photo_split="train", effects=fx)
            items = load_test_set(spec, str(ROOT / "cache/heldout"), progress=True)["procedural"]
            per = {v: [] for v in variants}
            for it in tqdm(items, desc=f"{lens} {cond}: scoring", unit="stack"):
                valid = it.depth_m > 0
                for s in sigmas:
                    vol = focus_volume(it.stack, base.measure, base.window_px, prefilter_px=s)  # shared by estimators
                    for e in ESTIMATORS:
                        cfg = replace(base, prefilter_px=s, estimator=e)
                        d = classical_depth(it.stack, it.focus_m, fmap, cfg, volume=vol).depth_m
                        per[(e, s)].append({"mae": float(np.abs(d - it.depth_m)[valid].mean())})
            cell = f"{lens} {cond}"
            table[cell] = {name(v): {"mae": list(bootstrap_mean([p["mae"] for p in per[v]],
                                                                    n_boot=N_BOOT, seed=1)),
                                     "ratio_to_reference": paired_ratio(per[v], per[REFERENCE])} for v in variants}
            ratios[cell] = {v: table[cell][name(v)]["ratio_to_reference"][0] for v in variants}
    best, gm = choose(ratios)

    print(f"\nClassical method (aberration-aware), validation stacks ({a.n} scenes per cell, training photographs, "
          f"seed {VAL_SEED}): depth MAE (m) [95 % CI], and paired ratio to {name(REFERENCE)}\n")
    print("| estimator, pre-filter | " + " | ".join(table) + " | geometric mean of ratios |")
    print("|---|" + "---|" * (len(table) + 1))
    for v in variants:
        cells = []
        for c in table:
            m, r = table[c][name(v)]["mae"], table[c][name(v)]["ratio_to_reference"]
            cells.append(f"{m[0]:.3f} [{m[1]:.3f}, {m[2]:.3f}]"
                         + ("" if v == REFERENCE else f", {r[0]:.2f}× [{r[1]:.2f}, {r[2]:.2f}]"))
        print(f"| {name(v)}{' (chosen)' if v == best else ''} | " + " | ".join(cells) + f" | {gm[v]:.3f} |")
    print(f"\nchosen: estimator = {best[0]}, prefilter_px = {best[1]:g}")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(a.out, json.dumps({"n": a.n, "seed": VAL_SEED, "reference": name(REFERENCE), "cells": table,
                                         "geometric_mean_ratio": {name(v): g for v, g in gm.items()},
                                         "chosen": {"estimator": best[0], "prefilter_px": best[1]}}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
