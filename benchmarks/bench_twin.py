"""Digital-twin rendering: the torch-free renderer (`aat_deploy.diagnose.twin`, numpy) against the training simulator (torch).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_twin [--threads 1] [--repeat 1] [--quick]

The same twin stack both ways: a procedural RGB-D scene (0.5-10 m), a 192 x 288 crop at the top-left corner of
the Canon RF50's 640 x 960 sensor (where its aberrations are strongest), 8 frames focused 0.5-8 m evenly in
diopters, PSFs from the shipped surrogate models/psf_rf50.onnx, anchors every 64 px (`aat-diagnose`'s setting).
Simulators: the thin lens, the AAT simulator (`aberrations`), and AAT with vignetting, sensor tilt and focus
breathing (focus tables from the surrogate's metadata for numpy, traced for torch; tracing is done before timing).
Times are wall clock (best of --repeat) with onnxruntime and torch on --threads threads; numpy's FFT is
single-threaded. "max rel. diff." = max |numpy - torch| / max |torch| over the stack.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from benchmarks.timing import best_of

ROOT = Path(__file__).resolve().parents[1]

SETUPS = {"thin lens": [], "AAT (aberrations)": ["aberrations"],
          "AAT + vignetting + sensor_tilt + focus_breathing": ["aberrations", "vignetting",
                                                               "sensor_tilt:tilt_x_deg=0.4", "focus_breathing"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=1, help="torch and onnxruntime threads")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="96 x 144, 4 frames (smoke run)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.focus_table import diopter_grid
    from aat_deploy.render import effects as fx
    from aat_deploy.render.layered import LayeredConfig
    from aat_deploy.render.optical import optical_stack
    from aat_deploy.render.sources import GaussianSource
    from training.data.scenes import SceneConfig, procedural_scene
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF

    h, w, n = (96, 144, 4) if args.quick else (192, 288, 8)
    lens = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
    onnx = OnnxPSF(ROOT / "models/psf_rf50.onnx", lens, threads=args.threads)
    rgb, depth = procedural_scene(SceneConfig(height=h, width=w, near_m=0.5, far_m=10.0), np.random.default_rng(0))
    rgb = np.ascontiguousarray(rgb.transpose(2, 0, 1), dtype=np.float32)
    depth = depth.astype(np.float32)
    focus = diopter_grid(0.5, 8.0, n)  # tilted corners focus farther: stay in the surrogate's range
    cfg, origin, sensor = LayeredConfig(cell_px=64), (0, 0), (lens.sensor.height_px, lens.sensor.width_px)
    src = onnx.numpy
    rows = []
    for name, specs in SETUPS.items():
        effects = fx.parse(specs)
        sim = Simulator(lens, onnx, effects, cfg)
        ctx_t = sim.context(origin)
        ctx_t.focus_table()  # trace once, outside the timing
        ctx_n = fx.SimContext(lens, sensor, origin, src, src.focus_table(), src.exit_pupil_z_mm())

        def torch_stack():
            rng = np.random.default_rng(0)
            frames = sim.optical(torch.from_numpy(rgb), torch.from_numpy(depth), focus, ctx_t)
            return sim.post(frames, focus, ctx_t, rng).numpy()

        def numpy_stack():
            rng = np.random.default_rng(0)
            frames = optical_stack(effects, GaussianSource(lens), rgb, depth, focus, ctx_n, cfg)
            return np.stack([fx.post_frame(effects, f, float(d), ctx_n, rng) for f, d in zip(frames, focus)])

        a, t_torch = best_of(torch_stack, args.repeat)
        b, t_numpy = best_of(numpy_stack, args.repeat)
        rows.append((name, t_torch, t_numpy, float(np.abs(a - b).max() / np.abs(a).max())))
        print(f"  {name}: torch {t_torch:.2f} s, numpy {t_numpy:.2f} s", file=sys.stderr, flush=True)

    print(f"\n### Twin rendering, torch vs numpy ({h} x {w} RF50 corner crop, {n} frames 0.5-8 m, "
          f"surrogate PSFs, {args.threads} thread(s))\n")
    print("| simulator | torch (training) | numpy (aat_deploy.diagnose.twin) | numpy / torch | max rel. diff. |")
    print("|---|---|---|---|---|")
    for name, tt, tn, diff in rows:
        print(f"| {name} | {tt:.2f} s | {tn:.2f} s | {tn / tt:.2f} | {diff:.1e} |")


if __name__ == "__main__":
    main()
