"""`chromatic` from per-wavelength surrogates against ray tracing at three wavelengths: kernel agreement and the
time to render one training stack, in one run.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_chromatic RUN_DIR [--n 256] [--reference-rays 16384]

RUN_DIR: a lens-to-model run made with `aat-train --lens ... --effects chromatic` (lens.json, psf.onnx and the
psf_<w>nm.onnx that its stage psf_colour fitted), e.g. the chromatic retraining folder of the diagnosis
benchmark (cache/bench_diagnose_crop4/sets_v2/setNN_retrain).

Kernels: N random queries (field uniform over the sensor, depth and focus uniform in diopters over the
surrogates' range). The reference is the ray-traced effect with `--reference-rays` rays per PSF; compared with it,
as unit-energy kernels (sum over cells of |a - b|, mean over queries and channels; 0 = equal, 2 = disjoint):
the surrogates, ray tracing at the effect's own 1024 rays (what training without surrogates renders), and no
colour at all (every channel the design-wavelength surrogate, centred on its own chief ray). Lateral colour is
compared as the red-minus-blue kernel centroid (pixels): mean |error| against the reference, and the
reference's own mean |R - B| for scale.

Time: one 128 x 128 training stack of 8 frames (procedural scene, 0.6-8 m, focus 0.5-10 m) through the torch
simulator with `chromatic` (surrogates, then `psfs=trace`), best of --repeat; ratio = tracing's time over ours.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from benchmarks.timing import best_of

ROOT = Path(__file__).resolve().parents[1]


def centroid_px(k: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(N, C, k, k) kernels -> (N, C, 2) centroids (x right, y up) in pixels from the window centre."""
    g = np.arange(k.shape[-1]) - k.shape[-1] // 2
    e = np.maximum(k.sum((-1, -2)), 1e-12)
    cx = (k.sum(-2) * g).sum(-1) / e
    cy = -(k.sum(-1) * g).sum(-1) / e
    return np.stack([cx, cy], -1) * scale[:, None, None]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--n", type=int, default=256, help="random kernel queries")
    ap.add_argument("--reference-rays", type=int, default=16384)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(2)

    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.focus_table import diopter_grid
    from aat_deploy.psf.surrogate import PSFSurrogate
    from aat_deploy.render import effects as fx
    from aat_deploy.render.effects.chromatic import surrogate_name
    from training.data.scenes import SceneConfig, procedural_scene
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF, UnitEnergy, thin_lens_source

    run = args.run_dir
    lens = load_lens(run / "lens.json")
    lens_src = OnnxPSF(run / "psf.onnx", lens)
    chroma = fx.make("chromatic")
    missing = [surrogate_name(w) for w in chroma.wavelengths() if not (run / surrogate_name(w)).is_file()]
    if missing:
        raise SystemExit(f"{run}: no {', '.join(missing)}; make it with aat-train --lens ... --effects chromatic")
    s = lens.sensor
    ctx = fx.SimContext(lens, (s.height_px, s.width_px), (0, 0), lens_src)
    thin = thin_lens_source(lens)

    # Kernel queries in the per-wavelength surrogates' range.
    lo, hi = PSFSurrogate(run / surrogate_name(chroma.wavelengths()[0])).depth_range_m
    rng = np.random.default_rng(args.seed)
    x, y = rng.uniform(-1, 1, args.n), rng.uniform(-1, 1, args.n)
    depth, focus = (1.0 / rng.uniform(1 / hi, 1 / lo, args.n) for _ in range(2))

    def kernels(effect_or_source) -> tuple[np.ndarray, np.ndarray]:
        src = effect_or_source.wrap_source(thin, ctx) if isinstance(effect_or_source, fx.Effect) else effect_or_source
        k, sc = src(x, y, depth, focus)
        k = k.numpy() if hasattr(k, "numpy") else k
        sc = sc.numpy() if hasattr(sc, "numpy") else np.asarray(sc)
        return (k if k.ndim == 4 else np.repeat(k[:, None], 3, 1)).astype(np.float64), sc.astype(np.float64)

    print(f"tracing the reference ({args.n} PSFs x 3 wavelengths x {args.reference_rays} rays) ...", flush=True)
    ref, ref_scale = kernels(fx.make("chromatic", psfs="trace", n_rays=args.reference_rays))
    ref_rb = centroid_px(ref, ref_scale)
    ref_rb = ref_rb[:, 0] - ref_rb[:, 2]
    candidates = {
        "per-wavelength surrogates": fx.make("chromatic", psfs=str(run)),
        "ray traced, 1024 rays": fx.make("chromatic", psfs="trace"),
        "no colour (589 nm surrogate)": UnitEnergy(lens_src),
    }
    kernel_rows = []
    for name, c in candidates.items():
        k, sc = kernels(c)
        l1 = np.abs(k - ref).sum((-1, -2)).mean()
        rb = centroid_px(k, sc)
        rb_err = np.abs((rb[:, 0] - rb[:, 2]) - ref_rb).sum(-1).mean()
        kernel_rows.append((name, l1, rb_err))

    # One training stack, both ways.
    rgb, dep = procedural_scene(SceneConfig(height=128, width=128, near_m=0.6, far_m=8.0), np.random.default_rng(1))
    rgb_t = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))).float()
    dep_t = torch.from_numpy(dep).float()
    focus_stack = diopter_grid(0.5, 10.0, 8)
    origin = ((s.height_px - 128) // 2, (s.width_px - 128) // 2)
    times = {}
    for name, spec in (("per-wavelength surrogates", "chromatic"), ("ray traced, 1024 rays", "chromatic:psfs=trace")):
        sim = Simulator(lens, lens_src, fx.parse(spec))
        _, t = best_of(lambda: sim.optical(rgb_t, dep_t, focus_stack, sim.context(origin)), args.repeat)
        times[name] = t

    print(f"\n{lens.name}, {s.width_px} x {s.height_px} px of {s.width_mm:g} x {s.height_mm:g} mm; {args.n} kernels; "
          f"reference: ray traced, {args.reference_rays} rays; mean |R - B| centroid of the reference "
          f"{np.abs(ref_rb).sum(-1).mean():.3f} px\n")
    print("| chromatic PSFs | kernel L1 vs reference | R-B centroid error (px) | 8-frame 128x128 stack (s) | "
          "speed-up vs tracing |")
    print("|---|---|---|---|---|")
    t_ref = times["ray traced, 1024 rays"]
    for name, l1, rb_err in kernel_rows:
        t = times.get(name)
        ts = f"{t:.2f}" if t else "-"
        ratio = f"{t_ref / t:.1f}x" if t else "-"
        print(f"| {name} | {l1:.4f} | {rb_err:.3f} | {ts} | {ratio} |")


if __name__ == "__main__":
    main()
