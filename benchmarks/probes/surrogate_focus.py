"""Where a lens's PSF surrogate (what the test stacks are rendered with) is sharpest across the field, against its
best-focus map (what `--lens` gives the methods).

    OMP_NUM_THREADS=1 python -m benchmarks.probes.surrogate_focus [--lens z35] [--object-m 0.5,1] [--steps 193]

For an object at each distance (m from the sensor) and points on the frame's diagonal (field radius t: 0 centre,
1 corner), the frame focus (D) whose surrogate PSF has the least RMS radius (second moment about its centroid, in
pixels) over a dense sweep of the surrogate's focus range, beside the frame focus the map puts that object in
focus at (object diopters minus the map's shift there). A map traced only (the Z35's: not calibrated on renders)
is checked against the renders this way. Seconds; nothing cached.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

RADII = (0.0, 0.3, 0.5, 0.65, 0.8, 1.0)


def rms_radius_px(k: np.ndarray, cell_px: np.ndarray) -> np.ndarray:
    """(N, k, k) kernels, (N,) cell size (px) -> (N,) RMS radius (px) about each kernel's centroid."""
    p = k / k.sum((-1, -2), keepdims=True)
    g = np.arange(k.shape[-1], dtype=np.float64) - k.shape[-1] // 2
    cx, cy = (p * g[None, None, :]).sum((-1, -2)), (p * g[None, :, None]).sum((-1, -2))
    r2 = (g[None, None, :] - cx[:, None, None]) ** 2 + (g[None, :, None] - cy[:, None, None]) ** 2
    return np.sqrt((p * r2).sum((-1, -2))) * cell_px


def main(argv: list[str] | None = None) -> int:
    from aat_deploy.focus.bestfocus import for_lens
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.sources import OnnxSource
    from benchmarks.bench_anycam import LENSES, ROOT

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", default="z35", choices=list(LENSES))
    ap.add_argument("--object-m", default="0.5,1")
    ap.add_argument("--steps", type=int, default=193, help="focus settings over the surrogate's range")
    a = ap.parse_args(argv)
    spec = LENSES[a.lens]
    lens = load_lens(ROOT / spec["lens"])
    src = OnnxSource(ROOT / spec["psf"], lens, threads=1)
    fmap, _ = for_lens(ROOT / spec["lens"], compute=False)
    flo, fhi = src.model.focus_range_m
    fd = np.linspace(1.0 / fhi, 1.0 / flo, a.steps)
    shift = fmap.shift_diopters(calibrated=True)  # (R, F): D nearer than the frame's focus
    print(f"{lens.name}: {spec['psf']} against lenses/best_focus/ (diagonal, t = field radius; D)")
    print("object | t | surrogate's sharpest frame focus | map's | difference | RMS radius there (px) | worst in sweep")
    print("|---|---|---|---|---|---|---|")
    for obj in (float(v) for v in a.object_m.split(",")):
        for t in RADII:
            k, sc = src(np.full(fd.size, t), np.full(fd.size, t), np.full(fd.size, obj), 1.0 / fd)
            rms = rms_radius_px(k, sc)
            best = float(fd[np.argmin(rms)])
            at = np.array([np.interp(1.0 / obj, fmap.focus_diopters, row) for row in shift])
            pred = 1.0 / obj - float(np.interp(t, fmap.radius, at))
            print(f"| {obj:g} m ({1 / obj:.2f} D) | {t:g} | {best:.2f} | {pred:.2f} | {best - pred:+.2f} | "
                  f"{rms.min():.2f} | {rms.max():.2f} |")
    print(f"(focus step {fd[1] - fd[0]:.3f} D)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
