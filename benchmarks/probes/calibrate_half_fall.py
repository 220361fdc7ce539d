"""How much defocus blur makes a chart tile's focus curve fall to half its peak (exploratory; sweep design).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.calibrate_half_fall [--lens rf50]

On benchmarks/bench_calibrate.py's nominal chart sweeps of a lens (cached under cache/calibrate/, rendered on first
use), per counted tile: the thin-lens blur (px: the frame's distance from the tile's peak in diopters x the lens's
blur per diopter) at which its focus curve first falls under half its peak, the nearer side of the two. A sweep must
reach past it for the tile to count (the fit's contrast rule). bench_calibrate's sweeps designed in pixels of blur
(SWEEP_STEP_PX, SWEEP_MARGIN_PX) come from the RF50's rows; it prints the sweep's step and reach in px beside them.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks import bench_calibrate as B


def half_fall_px(curves: np.ndarray, defocus_px: np.ndarray) -> np.ndarray:
    """curves (S, N) one tile's focus measure per frame and column; defocus_px (S, N) signed blur from its peak.
    Returns (N,) the least |blur| at which the curve is under half its maximum on either side (NaN: never)."""
    out = np.full(curves.shape[1], np.nan)
    for j in range(curves.shape[1]):
        v = curves[:, j] / curves[:, j].max()
        for side in (defocus_px[:, j] > 0, defocus_px[:, j] < 0):
            b = np.abs(defocus_px[side, j])
            under = b[v[side] < 0.5]
            if under.size:
                out[j] = np.nanmin([out[j], under.min()])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", choices=sorted(B.LENSES), default="rf50")
    a = ap.parse_args(argv)
    rig = B.Rig(B.LENSES[a.lens])
    print(f"{a.lens}: {rig.blur_px_per_d:.2f} px of thin-lens blur per diopter")
    print("| chart (m) | tiles | step (px) | reach beyond the chart (px) | half-fall blur (px): median | 90 % | max |")
    print("|---|---|---|---|---|---|---|")
    for i in range(len(rig.setup.distances_m)):
        sw = B.sweep(rig, "nominal", i)
        pk = B.measures(rig, [sw], "nominal")[0].peaks
        ok = pk.counted
        defocus = (pk.reported_d[:, None] - pk.peak_d[ok][None, :]) * rig.blur_px_per_d
        h = half_fall_px(pk.curves[:, ok], defocus)
        h = h[np.isfinite(h)]
        fd = 1.0 / sw["true_m"]
        print(f"| {sw['distance_m']:g} | {int(ok.sum())} | {np.diff(fd).mean() * rig.blur_px_per_d:.2f} | "
              f"{min(fd.max() - 1 / sw['distance_m'], 1 / sw['distance_m'] - fd.min()) * rig.blur_px_per_d:.1f} | "
              f"{np.median(h):.2f} | {np.quantile(h, 0.9):.2f} | {h.max():.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
