"""Why the classical focus method collapses under sensor noise, and what a pre-filter would buy (exploratory).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.classical_noise [--lens rf50] [--n 12]

Scores the runtime's classical method (aat_deploy.focus, aberration-aware mapping) on the first --n stacks of the
fixed-schedule held-out set (training/train/testsets.py, the ones bench_table2 scores), without and with the
`noise` effect (Poisson-Gaussian, 8000 e- full well, 3 e- read noise), under variants of its settings: no
pre-filter, a wider window, a different measure, and Gaussian pre-filters of each frame (`FocusConfig.prefilter_px`,
sigma in px) before the focus measure. Prints the mean MAE (m) over the stacks. The variants are looked at on test
scenes, so this probe chooses nothing: it says where the weakness lies. The runtime's pre-filter was chosen on
validation stacks by benchmarks/select_focus_noise.py.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from training.train.testsets import LENSES

ROOT = Path(__file__).resolve().parents[2]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", choices=sorted(LENSES), default="rf50")
    ap.add_argument("--n", type=int, default=12)
    a = ap.parse_args(argv)
    from aat_deploy.focus import classical_depth
    from aat_deploy.focus.bestfocus import load_json, map_path_for_lens
    from aat_deploy.focus.method import FocusConfig
    from training.train.testsets import TestSetSpec, load_test_set

    spec = LENSES[a.lens]
    fmap = load_json(map_path_for_lens(ROOT / spec["lens"]))
    sets = {fx or "none": load_test_set(TestSetSpec(spec["lens"], spec["psf"], spec["stack_size"], n_procedural=a.n,
                                                    middlebury=False, effects=(fx,) if fx else ()),
                                        str(ROOT / "cache/heldout"), progress=False)["procedural"]
            for fx in ("", "noise")}
    variants = [("no pre-filter (mlap2, window 15 px)", FocusConfig(prefilter_px=0)),
                ("no pre-filter, window 31 px", FocusConfig(prefilter_px=0, window_px=31)),
                ("no pre-filter, tenengrad", FocusConfig(prefilter_px=0, measure="tenengrad")),
                ("pre-filter 1 px", FocusConfig(prefilter_px=1)),
                ("pre-filter 2 px", FocusConfig(prefilter_px=2))]
    print(f"\n{a.lens}, fixed schedule, first {a.n} held-out stacks, classical aberration-aware: mean MAE (m)\n")
    print("| variant | " + " | ".join(f"effects: {k}" for k in sets) + " |")
    print("|---|" + "---|" * len(sets))
    for name, cfg in variants:
        cells = []
        for items in sets.values():
            mae = [np.abs(classical_depth(it.stack, it.focus_m, fmap, cfg).depth_m
                          - it.depth_m)[it.depth_m > 0].mean() for it in items]
            cells.append(f"{np.mean(mae):.3f}")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
