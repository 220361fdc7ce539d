"""Why the classical focus method collapses under sensor noise, and what a pre-filter would buy (exploratory).

    OMP_WAIT_POLICY=PASSIVE python benchmarks/probe_classical_noise.py [--lens rf50] [--n 12]

Scores the runtime's classical method (aat_deploy.focus, aberration-aware mapping) on the first --n stacks of the
fixed-schedule held-out set (training/train/testsets.py, the ones bench_table2 scores), without and with the
`noise` effect (Poisson-Gaussian, 8000 e- full well, 3 e- read noise), under variants of its settings: the
default, a wider window, a different measure, and a Gaussian pre-filter of each frame (sigma in px) before the
focus measure. Prints the mean MAE (m) over the stacks. The variants are looked at on test scenes, so this probe
chooses nothing: it says where the weakness lies, not what the runtime's setting should be.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_table2 import LENSES  # noqa: E402


def prefilter(stack: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur of every channel of every frame; stack (S, 3, H, W)."""
    if not sigma_px:
        return stack
    return np.stack([np.stack([cv2.GaussianBlur(c, (0, 0), sigma_px) for c in f]) for f in stack])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", choices=sorted(LENSES), default="rf50")
    ap.add_argument("--n", type=int, default=12)
    a = ap.parse_args(argv)
    from aat_deploy.focus import depth_from_focus
    from aat_deploy.focus.bestfocus import load_json, map_path_for_lens
    from aat_deploy.focus.method import FocusConfig
    from training.train.testsets import TestSetSpec, load_test_set

    spec = LENSES[a.lens]
    fmap = load_json(map_path_for_lens(ROOT / spec["lens"]))
    sets = {fx or "none": load_test_set(TestSetSpec(spec["lens"], spec["psf"], spec["stack_size"], n_procedural=a.n,
                                                    middlebury=False, effects=(fx,) if fx else ()),
                                        str(ROOT / "cache/heldout"), progress=False)["procedural"]
            for fx in ("", "noise")}
    variants = [("default (mlap2, window 15 px)", FocusConfig(), 0.0),
                ("window 31 px", FocusConfig(window_px=31), 0.0),
                ("tenengrad", FocusConfig(measure="tenengrad"), 0.0),
                ("pre-filter 1 px", FocusConfig(), 1.0),
                ("pre-filter 2 px", FocusConfig(), 2.0)]
    print(f"\n{a.lens}, fixed schedule, first {a.n} held-out stacks, classical aberration-aware: mean MAE (m)\n")
    print("| variant | " + " | ".join(f"effects: {k}" for k in sets) + " |")
    print("|---|" + "---|" * len(sets))
    for name, cfg, s in variants:
        cells = []
        for items in sets.values():
            mae = [np.abs(depth_from_focus(prefilter(it.stack, s), it.focus_m, fmap, cfg).depth_m
                          - it.depth_m)[it.depth_m > 0].mean() for it in items]
            cells.append(f"{np.mean(mae):.3f}")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
