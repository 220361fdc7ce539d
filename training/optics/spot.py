"""Spot diagrams and RMS spot radius.

A field is given as a chief-ray angle in object space (degrees, in the y-z plane). For a finite object
distance the object point sits at height (z_EP - z_obj) * tan(angle) on the object plane, i.e. the angle is
seen from the paraxial entrance pupil, as in lens-design programs.
RMS spot radius is taken about the centroid of the surviving rays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_data
from training.optics.focus import focus, object_z_mm
from training.optics.trace import rays_through_pupil, trace, uniform_disk_grid


@dataclass
class Spot:
    xy_mm: torch.Tensor  # (N, 2) sensor-plane hits of the surviving rays
    centroid_mm: tuple[float, float]
    rms_um: float
    n_rays: int  # launched
    n_valid: int  # survived (vignetting)
    sensor_z_mm: float


def rms_radius_mm(xy: torch.Tensor) -> float:
    """RMS distance of points (N, 2) from their centroid."""
    c = xy.mean(0)
    return float(torch.sqrt(((xy - c) ** 2).sum(-1).mean()))


def field_rays(lens: Lens, pupil: torch.Tensor, field_deg: float, object_m: float, sensor_z_mm: float,
               wavelength_nm: float | None = None):
    """Rays from a point at chief-ray angle `field_deg` (y-z plane), `object_m` metres from the sensor plane at
    `sensor_z_mm` (inf = at infinity), aimed at normalised points `pupil` (N, 2) of the paraxial entrance pupil."""
    angle = math.radians(field_deg)
    if math.isinf(object_m):
        return rays_through_pupil(lens, pupil, None, (0.0, angle))
    zo = object_z_mm(sensor_z_mm, object_m)
    z_ep = paraxial_data(lens).entrance_pupil_z_mm  # aim with the design-wavelength pupil, like rays_through_pupil
    p = torch.tensor([0.0, (z_ep - zo) * math.tan(angle), zo], dtype=torch.float64)
    return rays_through_pupil(lens, pupil, p)


def spot(
    lens: Lens,
    field_deg: float,
    focus_m: float = math.inf,
    defocus_mm: float = 0.0,
    object_m: float | None = None,
    wavelength_nm: float | None = None,
    grid: int = 36,
    sensor_z_mm: float | None = None,
) -> Spot:
    """Spot of a point at `field_deg`, object distance `object_m` (default: the focus distance), with the
    sensor focused at `focus_m` (metres from the sensor) and moved by `defocus_mm` (+ = away from the lens).

    Pupil sampling: a grid x grid square grid inside the unit disk of the paraxial entrance pupil.
    """
    zs = focus(lens, focus_m, wavelength_nm) if sensor_z_mm is None else sensor_z_mm
    zs = zs + defocus_mm
    obj_m = focus_m if object_m is None else object_m
    rays = field_rays(lens, uniform_disk_grid(grid), field_deg, obj_m, zs - defocus_mm, wavelength_nm)
    res = trace(lens, rays, wavelength_nm, sensor_z_mm=zs)
    xy = res.rays.o[res.rays.valid][:, :2]
    if xy.shape[0] == 0:
        raise ValueError(f"every ray is vignetted at field {field_deg} deg")
    c = xy.mean(0)
    return Spot(xy, (float(c[0]), float(c[1])), 1000.0 * rms_radius_mm(xy), rays.o.shape[0], xy.shape[0], zs)
