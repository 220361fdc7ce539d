"""Stage 1 of the chain: read the lens, put the user's sensor behind it, and check that the pair makes sense.

- Paraxial summary (`aat_deploy.optics.paraxial`): EFL, BFL, F-number, entrance pupil, field of view over the
  sensor (horizontal, vertical, diagonal; full angles in degrees), pixel pitch.
- Image circle: the largest image height (mm) at which at least `MIN_RELATIVE_ILLUMINATION` of the on-axis light
  still gets through the lens, found by real-ray tracing a pupil grid at field angles from the axis outwards
  (object at infinity, nominal sensor position). If tracing fails the paraxial estimate is used instead: the
  field at which the chief ray reaches a clear aperture (about 50 % vignetting). The report says which.
  A sensor whose half-diagonal exceeds the image circle's radius gets a warning (dark, unusable corners).
- Nearest focus (m from the sensor): a focus range starting closer is an error.
- Defocus blur: the thin-lens blur (px) of a point at the near end of the focus range with focus at the far end;
  under 2 px the stack carries almost no focus cue at this resolution (warning).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from aat_deploy.lens.io import load_lens, validate
from aat_deploy.lens.schema import Lens, Sensor
from aat_deploy.optics.paraxial import _trace, paraxial_data

MIN_RELATIVE_ILLUMINATION = 0.1
MIN_BLUR_PX = 2.0


def resolve_lens(path, sensor_mm: tuple[float, float] | None, resolution: tuple[int, int] | None) -> Lens:
    """The lens from `path` (.json / .zmx / .txt) with the sensor replaced: size (W, H) mm and working resolution
    (W, H) px. Either may be None (the file's value; a missing size follows the resolution's aspect ratio at the
    file's diagonal, a missing resolution the size's aspect ratio at the file's pixel count along the width)."""
    lens = load_lens(path)
    s = lens.sensor
    if sensor_mm is None and resolution is None:
        return lens
    if sensor_mm is None:
        new = Sensor.from_half_diagonal(s.half_diagonal_mm, *resolution)
    elif resolution is None:
        w_px = s.width_px
        new = Sensor(float(sensor_mm[0]), float(sensor_mm[1]), w_px, max(1, round(w_px * sensor_mm[1] / sensor_mm[0])))
    else:
        new = Sensor(float(sensor_mm[0]), float(sensor_mm[1]), int(resolution[0]), int(resolution[1]))
    out = replace(lens, sensor=new)
    validate(out, f"{path} with sensor {new.width_mm:g}x{new.height_mm:g} mm at {new.width_px}x{new.height_px} px")
    return out


def _relative_transmission(lens: Lens, angle_deg: float, pupil, n_axis: int | None) -> tuple[float, float, int]:
    """(fraction of the on-axis ray count that survives at `angle_deg`, mean image height mm, surviving rays)."""
    from training.optics.trace import rays_through_pupil, trace

    res = trace(lens, rays_through_pupil(lens, pupil, None, (0.0, math.radians(angle_deg))))
    v = res.rays.valid
    n = int(v.sum())
    h = float(res.rays.o[v][:, 1].mean()) if n else float("nan")
    return (n / n_axis if n_axis else 1.0), h, n


def image_circle_traced(lens: Lens, threshold: float = MIN_RELATIVE_ILLUMINATION, step_deg: float = 1.0,
                        max_deg: float = 85.0) -> float:
    """Image-circle radius (mm) by real-ray tracing; raises ValueError when no ray gets through on axis.

    Rays sample a disk of twice the paraxial entrance pupil (pupil aberrations move the real pupil at large
    fields); the count that survives, relative to the axis, is the relative illumination (without cos^4)."""
    from training.optics.trace import uniform_disk_grid

    pupil = uniform_disk_grid(41) * 2.0
    _, _, n0 = _relative_transmission(lens, 0.0, pupil, None)
    if n0 == 0:
        raise ValueError("no ray passes the lens on axis")
    good, good_h, bad = 0.0, 0.0, None
    a = step_deg
    while a <= max_deg:
        frac, h, _ = _relative_transmission(lens, a, pupil, n0)
        if frac < threshold or not math.isfinite(h):
            bad = a
            break
        good, good_h = a, h
        a += step_deg
    if bad is None:
        return abs(good_h)
    for _ in range(6):  # bisection to step / 64
        mid = 0.5 * (good + bad)
        frac, h, _ = _relative_transmission(lens, mid, pupil, n0)
        if frac >= threshold and math.isfinite(h):
            good, good_h = mid, h
        else:
            bad = mid
    return abs(good_h)


def image_circle_paraxial(lens: Lens) -> float:
    """Paraxial estimate (mm): EFL x tan of the field angle at which the chief ray (through the entrance-pupil
    centre) first reaches a surface's clear aperture."""
    p = paraxial_data(lens)
    w = lens.design_wavelength_nm
    u0 = 1.0  # chief ray slope (heights scale linearly with it)
    y0 = -u0 * p.entrance_pupil_z_mm
    tmax = math.inf
    for i, s in enumerate(lens.surfaces):
        if i == lens.stop_index:
            continue
        if i == 0:
            y = y0
        else:
            yi, ui = _trace(lens, y0, u0, w, 0, i)
            y = yi + lens.surfaces[i - 1].thickness_mm * ui
        if abs(y) > 1e-12:
            tmax = min(tmax, s.semi_diameter_mm / abs(y))
    return p.efl_mm * tmax if math.isfinite(tmax) else math.inf


def nearest_focus_m(lens: Lens) -> float:
    """The closest focus distance (m from the sensor) of the lens's focus table (training.psf.geometry), which
    the PSF tracing uses; building it here also warms its cache for the PSF stage."""
    from training.psf.geometry import focus_table

    return float(1.0 / focus_table(lens).diopters[-1])


def lens_report(lens: Lens, source: str | Path, focus_range_m: tuple[float, float]) -> dict:
    """Everything stage 1 reports (JSON-ready); `warnings` lists problems in one line each."""
    from aat_deploy.optics.thin_lens import thin_lens_blur_px

    p = paraxial_data(lens)
    s = lens.sensor
    paraxial_r = image_circle_paraxial(lens)
    try:
        radius, method = image_circle_traced(lens), "trace"
    except Exception as e:  # noqa: BLE001 (any tracing failure falls back to the paraxial estimate)
        radius, method = paraxial_r, f"paraxial (tracing failed: {str(e).splitlines()[0][:120]})"
    near, far = focus_range_m
    blur = float(thin_lens_blur_px(lens, near, far))
    nearest = nearest_focus_m(lens)
    if near < nearest:
        raise ValueError(f"{lens.name}: focuses no closer than {nearest:.3f} m from the sensor; "
                         f"--focus-range-m must start at or beyond that (got {near:g})")
    warnings = []
    if s.half_diagonal_mm > radius:
        how = ("real-ray trace, relative illumination >= "
               f"{MIN_RELATIVE_ILLUMINATION:.0%}" if method == "trace" else "paraxial estimate")
        warnings.append(f"the sensor diagonal ({2 * s.half_diagonal_mm:.1f} mm) exceeds the image circle "
                        f"({2 * radius:.1f} mm, {how}): the corners get little or no light")
    if blur < MIN_BLUR_PX:
        warnings.append(f"defocus blur across the focus range is only {blur:.2f} px at {s.width_px}x{s.height_px} "
                        f"px: too little focus cue; use a higher --resolution or a wider --focus-range-m")
    return {
        "name": lens.name,
        "source": str(source),
        "prescription_hash": lens.prescription_hash(),
        "surfaces": len(lens.surfaces),
        "efl_mm": p.efl_mm,
        "bfl_mm": p.bfl_mm,
        "f_number": p.fno,
        "entrance_pupil_mm": p.entrance_pupil_mm,
        "total_track_mm": p.total_track_mm,
        "sensor_mm": [s.width_mm, s.height_mm],
        "sensor_px": [s.width_px, s.height_px],
        "pixel_um": s.pixel_mm * 1000.0,
        "fov_deg": {"horizontal": 2 * p.hfov_h_deg, "vertical": 2 * p.hfov_v_deg, "diagonal": 2 * p.hfov_deg},
        "sensor_diagonal_mm": 2 * s.half_diagonal_mm,
        "image_circle_mm": 2 * radius,
        "image_circle_method": method,
        "image_circle_paraxial_mm": 2 * paraxial_r,
        "min_relative_illumination": MIN_RELATIVE_ILLUMINATION,
        "focus_range_m": [near, far],
        "nearest_focus_m": nearest,
        "defocus_blur_px": blur,
        "warnings": warnings,
    }


def format_report(r: dict) -> str:
    """A few lines for the terminal."""
    fov = r["fov_deg"]
    lines = [
        f"lens: {r['name']} ({r['surfaces']} surfaces, prescription {r['prescription_hash']})",
        f"  EFL {r['efl_mm']:.2f} mm, F/{r['f_number']:.2f}, entrance pupil {r['entrance_pupil_mm']:.2f} mm",
        (f"  sensor {r['sensor_mm'][0]:g} x {r['sensor_mm'][1]:g} mm at {r['sensor_px'][0]} x {r['sensor_px'][1]} px "
        f"({r['pixel_um']:.2f} um pixels), diagonal {r['sensor_diagonal_mm']:.1f} mm"),
        f"  field of view {fov['horizontal']:.1f} x {fov['vertical']:.1f} deg (diagonal {fov['diagonal']:.1f} deg)",
        (f"  image circle {r['image_circle_mm']:.1f} mm ({r['image_circle_method']}; paraxial estimate "
        f"{r['image_circle_paraxial_mm']:.1f} mm)"),
        (f"  nearest focus {r['nearest_focus_m']:.3f} m; defocus blur over {r['focus_range_m'][0]:g}-"
        f"{r['focus_range_m'][1]:g} m: {r['defocus_blur_px']:.1f} px"),
    ]
    lines += [f"  warning: {w}" for w in r["warnings"]]
    return "\n".join(lines)
