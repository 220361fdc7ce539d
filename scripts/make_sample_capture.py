"""Regenerate the shipped sample capture: a procedural scene through the RF50's virtual camera.

    python -m scripts.make_sample_capture [--out captures/sample_rf50] [--force] [--scene-seed 2026] [--seed 1]

Writes 8 DNG frames (focus 0.6..6 m, even in diopters) with ground truth, via `aat-render` (the same path a user
takes), from a procedural scene (ours: no third-party data in the repository). Other --scene-seed / --seed values
make other captures rendered like the sample (the diagnosis's focus benchmark, benchmarks/bench_diagnose_focus.py).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def sample_scene(scene_seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The procedural scene --scene-seed makes: (rgb (640, 960, 3) linear in [0, 1], depth (640, 960) metres, 0.7-5 m)."""
    from training.data.scenes import SceneConfig, procedural_scene

    return procedural_scene(SceneConfig(height=640, width=960, near_m=0.7, far_m=5.0),
                            np.random.default_rng(scene_seed))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(ROOT / "captures/sample_rf50"))
    ap.add_argument("--force", action="store_true")
    ap.add_argument("--scene-seed", type=int, default=2026, help="the procedural scene (2026: the shipped sample)")
    ap.add_argument("--seed", type=int, default=1, help="the noise draw (1: the shipped sample)")
    ap.add_argument("--effects", default="vignetting,noise", help="aat-render's extra effects (the sample's: "
                    "vignetting,noise; others only for probes, e.g. vignetting alone for a noiseless copy)")
    args = ap.parse_args()
    from aat_deploy.io.color import linear_to_srgb
    from training.cli.render import main as render
    from training.render.schedule import FocusSchedule

    rgb, depth = sample_scene(args.scene_seed)
    focus = FocusSchedule(0.6, 6.0, 8).distances()
    with tempfile.TemporaryDirectory() as d:
        cv2.imwrite(f"{d}/rgb.png", np.round(linear_to_srgb(rgb)[..., ::-1] * 65535).astype(np.uint16))
        np.save(f"{d}/depth.npy", depth)
        argv = [f"{d}/rgb.png", f"{d}/depth.npy", "--lens", str(ROOT / "lenses/canon_rf50mm_f1.8.json"),
                "--focus-m", ",".join(f"{f:.4f}" for f in focus), "--out", args.out,
                "--effects", args.effects, "--seed", str(args.seed)]
        render(argv + (["--force"] if args.force else []))


if __name__ == "__main__":
    main()
