"""Paraxial (first-order) optics of a lens: EFL, BFL, F-number, pupils, field of view.

Plain float64 y-nu ray tracing (no torch): cheap, exact to rounding, and importable by the file loaders.
Conventions: z from the first vertex (mm), +z towards the sensor; slopes u = dy/dz; reduced angle n*u.
Pupil positions are z of the pupil plane measured from the first vertex.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from aat_deploy.lens.schema import Lens


def _trace(lens: Lens, y: float, u: float, wavelength_nm: float, start: int = 0, stop: int | None = None):
    """Paraxial ray from just before surface `start` (height y at that vertex, slope u in the medium
    before it) through surfaces start..stop-1. Returns (y, u) just after surface stop-1 (at its vertex)."""
    n = lens.indices(wavelength_nm)
    stop = len(lens.surfaces) if stop is None else stop
    for i in range(start, stop):
        s = lens.surfaces[i]
        if i > start:
            y = y + lens.surfaces[i - 1].thickness_mm * u
        if s.kind == "ideal":
            u = u - y / s.focal_length_mm
        else:
            phi = (n[i + 1] - n[i]) * s.paraxial_curvature_per_mm
            u = (n[i] * u - y * phi) / n[i + 1]
    return y, u


@dataclass(frozen=True)
class ParaxialData:
    efl_mm: float
    bfl_mm: float  # last vertex to the paraxial focus for an object at infinity
    fno: float  # EFL / entrance-pupil diameter (object at infinity)
    entrance_pupil_mm: float  # diameter
    entrance_pupil_z_mm: float  # from the first vertex (+ = behind it)
    exit_pupil_mm: float
    exit_pupil_z_mm: float
    hfov_deg: float  # half field of view over the sensor half-diagonal (paraxial, object at infinity)
    hfov_h_deg: float  # horizontal half angle
    hfov_v_deg: float  # vertical half angle
    sensor_mm: tuple[float, float]  # (width, height)
    pixel_um: float
    total_track_mm: float
    wavelength_nm: float

    def as_dict(self) -> dict:
        return asdict(self)


def stop_semi_diameter_for_epd(lens: Lens, epd_mm: float, wavelength_nm: float | None = None) -> float:
    """Stop semi-diameter that gives the requested entrance-pupil diameter."""
    w = wavelength_nm or lens.design_wavelength_nm
    a = _height_at_stop(lens, 1.0, 0.0, w)
    return abs(a) * epd_mm / 2.0


def _height_at_stop(lens: Lens, y0: float, u0: float, w: float) -> float:
    """Height at the stop vertex of a paraxial ray given at the first vertex."""
    if lens.stop_index == 0:
        return y0
    y, u = _trace(lens, y0, u0, w, 0, lens.stop_index)
    return y + lens.surfaces[lens.stop_index - 1].thickness_mm * u


def paraxial_data(lens: Lens, wavelength_nm: float | None = None) -> ParaxialData:
    """First-order properties at `wavelength_nm` (default: the lens's design wavelength)."""
    w = wavelength_nm or lens.design_wavelength_nm
    y_last, u_last = _trace(lens, 1.0, 0.0, w)
    efl = -1.0 / u_last
    bfl = -y_last / u_last
    # Entrance pupil: heights at the stop are linear in (y0, u0) at the first vertex: h = A y0 + B u0.
    a = _height_at_stop(lens, 1.0, 0.0, w)
    b = _height_at_stop(lens, 0.0, 1.0, w)
    r_stop = lens.surfaces[lens.stop_index].semi_diameter_mm
    ep_radius = r_stop / abs(a)
    ep_z = b / a  # the ray (y0 = -B/A, u0 = 1) crosses the axis at z = B/A
    # Exit pupil: image of the stop through the rear group.
    zv = lens.vertex_z_mm
    si = lens.stop_index
    yc, uc = _trace(lens, 0.0, 1.0, w, si)  # chief ray from the stop centre
    z_last = zv[-1]
    if abs(uc) > 1e-15:
        xp_z = z_last - yc / uc
        ye, ue = _trace(lens, r_stop, 0.0, w, si)  # a ray from the stop edge
        xp_radius = abs(ye + ue * (xp_z - z_last))
    else:  # telecentric in image space
        xp_z, xp_radius = math.inf, math.inf
    sen = lens.sensor
    return ParaxialData(
        efl_mm=efl,
        bfl_mm=bfl,
        fno=efl / (2.0 * ep_radius),
        entrance_pupil_mm=2.0 * ep_radius,
        entrance_pupil_z_mm=ep_z,
        exit_pupil_mm=2.0 * xp_radius,
        exit_pupil_z_mm=xp_z,
        hfov_deg=math.degrees(math.atan(sen.half_diagonal_mm / efl)),
        hfov_h_deg=math.degrees(math.atan(0.5 * sen.width_mm / efl)),
        hfov_v_deg=math.degrees(math.atan(0.5 * sen.height_mm / efl)),
        sensor_mm=(sen.width_mm, sen.height_mm),
        pixel_um=sen.pixel_mm * 1000.0,
        total_track_mm=lens.total_track_mm,
        wavelength_nm=w,
    )


def paraxial_image_z_mm(lens: Lens, object_z_mm: float, wavelength_nm: float | None = None) -> float:
    """z of the paraxial image of an on-axis object at z = object_z_mm (< 0, or -inf for infinity)."""
    w = wavelength_nm or lens.design_wavelength_nm
    if math.isinf(object_z_mm):
        y, u = _trace(lens, 1.0, 0.0, w)
    else:
        y, u = _trace(lens, -object_z_mm * 1e-3, 1e-3, w)  # from the axial object point, slope 1e-3
    return lens.vertex_z_mm[-1] - y / u


def paraxial_focus_z_mm(lens: Lens, distance_m: float, wavelength_nm: float | None = None, tol_mm: float = 1e-7) -> float:
    """Sensor z (mm from the first vertex) that paraxially images an on-axis point `distance_m` metres in front of
    the sensor plane; NaN when no sensor position does (the point is closer than the lens can focus).

    Distances are sensor-referenced, so this solves s = image_z(s - 1000 D) by fixed-point iteration (the map
    contracts by the longitudinal magnification). `training.optics.focus` refines the same start with real rays."""
    s_inf = paraxial_image_z_mm(lens, -math.inf, wavelength_nm)
    if math.isinf(distance_m):
        return s_inf
    s = s_inf
    for _ in range(100):
        s_new = paraxial_image_z_mm(lens, s - 1000.0 * distance_m, wavelength_nm)
        if not math.isfinite(s_new) or s_new < s_inf:  # virtual image: inside the focal length
            return math.nan
        if abs(s_new - s) < tol_mm:
            return s_new
        s = s_new
    return math.nan
