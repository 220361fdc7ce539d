"""Focusing by moving the sensor (the whole lens moves relative to the sensor, as in unit-focusing lenses).

Distances to objects are measured **from the sensor plane** along the axis, in metres, as cameras report
focus distance (the distance scale on a lens is referenced to the film/sensor plane). In lens coordinates
(z from the first vertex, mm) an object at distance D metres sits at z = sensor_z - 1000 * D.
Use `object_z_mm` to convert.

Best focus = the sensor plane with the smallest RMS spot radius (about the centroid) of an on-axis point,
from real rays filling the entrance pupil at the given wavelength. (The mean axis crossing, used by some
reference code, misses best focus under spherical aberration.)
"""

from __future__ import annotations

import math

import torch

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_image_z_mm
from training.optics.trace import rays_through_pupil, stratified_disk, trace

FOCUS_TOL_MM = 1e-7


def object_z_mm(sensor_z_mm: float, distance_m: float) -> float:
    """Lens-frame z (mm, from the first vertex) of an object `distance_m` metres from the sensor plane."""
    return -math.inf if math.isinf(distance_m) else sensor_z_mm - 1000.0 * distance_m


def best_focus_shift_mm(xy: torch.Tensor, slopes: torch.Tensor, valid: torch.Tensor) -> float:
    """Axial shift of the image plane that minimises the RMS spot radius about the centroid.

    xy: (N, 2) ray positions on a reference plane; slopes: (N, 2) dx/dz, dy/dz; valid: (N,).
    The spread at shift dz is sum |a + dz b|^2 with a, b centred; its minimum is at dz = -sum(a.b)/sum(b.b).
    """
    a = xy[valid] - xy[valid].mean(0)
    b = slopes[valid] - slopes[valid].mean(0)
    return float(-(a * b).sum() / (b * b).sum())


def best_focus_image_z_mm(
    lens: Lens, obj_z_mm: float, wavelength_nm: float | None = None, n_rays: int = 4096
) -> float:
    """z of the min-RMS image plane of an on-axis object at lens-frame z `obj_z_mm` (-inf = infinity)."""
    z_ref = paraxial_image_z_mm(lens, obj_z_mm, wavelength_nm)
    gen = torch.Generator().manual_seed(0)
    pupil = stratified_disk(n_rays, gen)
    obj = None if math.isinf(obj_z_mm) else torch.tensor([0.0, 0.0, obj_z_mm], dtype=torch.float64)
    res = trace(lens, rays_through_pupil(lens, pupil, obj), wavelength_nm, sensor_z_mm=z_ref)
    d = res.rays.d
    slopes = d[:, :2] / d[:, 2:3]
    return z_ref + best_focus_shift_mm(res.rays.o[:, :2], slopes, res.rays.valid)


def focus(lens: Lens, distance_m: float, wavelength_nm: float | None = None, n_rays: int = 4096) -> float:
    """Sensor z (mm from the first vertex) that best focuses an on-axis point `distance_m` metres in front
    of the sensor plane. `distance_m = inf` focuses at infinity.

    The object position depends on the sensor position (distances are sensor-referenced), so this solves
    s = image_z(s - 1000 D) by fixed-point iteration; the map contracts by the longitudinal magnification.
    """
    if distance_m <= 0:
        raise ValueError(f"focus distance must be positive (metres from the sensor), got {distance_m}")
    if math.isinf(distance_m):
        return best_focus_image_z_mm(lens, -math.inf, wavelength_nm, n_rays)
    # Paraxial start, then real-ray refinement.
    s = paraxial_image_z_mm(lens, -math.inf, wavelength_nm)
    for _ in range(100):
        s_new = paraxial_image_z_mm(lens, object_z_mm(s, distance_m), wavelength_nm)
        if abs(s_new - s) < FOCUS_TOL_MM:
            break
        s = s_new
    for _ in range(50):
        s_new = best_focus_image_z_mm(lens, object_z_mm(s, distance_m), wavelength_nm, n_rays)
        if abs(s_new - s) < FOCUS_TOL_MM:
            return s_new
        s = s_new
    raise RuntimeError(f"focus at {distance_m} m did not converge (object inside the focal length?)")
