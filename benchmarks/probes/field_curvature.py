"""A lens's best-focus map in numbers: how much nearer than on axis each field radius is in best focus, per frame
focus setting, and how far the thin lens (no map) is from the map over a range of focus settings (exploratory;
what a calibration has to measure).

    python -m benchmarks.probes.field_curvature lenses/best_focus/cellphone_asphere.json --focus-m 0.07,0.1,0.18,0.5 \
        --range-m 0.07,0.18

Reads the stored map (torch-free). Diopters are object diopters from the sensor plane; "nearer" is positive. The
thin lens's error is RMS over every pixel of a frame of the lens's sensor aspect (the map's radius), over 10 focus
settings even in diopters across --range-m.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from aat_deploy.focus.bestfocus import load_json
from aat_deploy.optics.focus_table import diopter_grid

RADII = (0.3, 0.5, 0.7, 0.85, 1.0)


def curvature(fmap, focus_d: float, calibrated: bool) -> list[float]:
    """Best focus minus on-axis best focus (D) at RADII for a frame focused at focus_d diopters."""
    shift = fmap.shift_diopters(calibrated=calibrated)  # (R, F)
    at = np.array([np.interp(focus_d, fmap.focus_diopters, row) for row in shift])
    return [float(np.interp(r, fmap.radius, at) - at[0]) for r in RADII]


def thin_lens_rms(fmap, near_m: float, far_m: float, h: int, w: int, calibrated: bool) -> float:
    r = fmap.radius_px(h, w).ravel()
    fs = diopter_grid(near_m, far_m, 10)
    err = [fmap.frame_diopters([f], r, calibrated=calibrated)[0] - 1.0 / f for f in fs]
    return float(np.sqrt(np.mean(np.square(err))))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("map", help="a best-focus map (lenses/best_focus/*.json)")
    ap.add_argument("--focus-m", default="0.07,0.1,0.18,0.5", help="frame focus settings (m from the sensor)")
    ap.add_argument("--range-m", default="0.07,0.18", help="near,far (m) of the thin lens's RMS error")
    ap.add_argument("--traced", action="store_true", help="a calibrated map's traced part only (smallest RMS spot)")
    a = ap.parse_args(argv)
    fmap = load_json(a.map)
    cal = fmap.offset_diopters is not None and not a.traced
    sw, sh = fmap.sensor_mm
    h, w = (480, int(round(480 * sw / sh)))  # the error is per pixel of any frame of the sensor's aspect
    print(f"{fmap.lens_name}: {'calibrated' if cal else 'traced (not calibrated)'} map")
    print("frame focus | best focus nearer than on axis (D) at radius " + ", ".join(f"{r:g}" for r in RADII))
    for f in (float(x) for x in a.focus_m.split(",")):
        print(f"{f:g} m ({1 / f:.1f} D) | " + ", ".join(f"{v:+.2f}" for v in curvature(fmap, 1.0 / f, cal)))
    near, far = (float(x) for x in a.range_m.split(","))
    print(f"thin lens against the map, frames focused {near:g}-{far:g} m: RMS "
          f"{thin_lens_rms(fmap, near, far, h, w, cal):.3f} D over the frame")
    return 0


if __name__ == "__main__":
    sys.exit(main())
