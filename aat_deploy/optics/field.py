"""Field positions: where on the sensor an image point is, which pixel looks there, and which object direction it
names.

Field coordinates (x, y) in [-1, 1] are normalised positions on the upright image (x right, y up; +-1 = the
sensor edges). They name an object-space **direction** seen from the entrance pupil:
    tan(theta_x) = x * W/2 / EFL,  tan(theta_y) = y * H/2 / EFL
so that an ideal lens focused at infinity images it exactly at (x * W/2, y * H/2). A PSF's object point is on that
ray at a depth in metres from the sensor plane (`training.psf.geometry.object_points_mm`). A real lens lands the
point elsewhere by its distortion and focus breathing; PSFs are centred on the real chief ray's hit
(`training.psf.raytrace`), and the landing offset is a separate, optional geometric effect.

Pixels of a crop placed on the full sensor (`field_of`, `pixel_fields`: pure, no lens) are what the renderers (torch
simulator, torch-free twin) and the field-aware DfF nets' `field_xy` input use.
"""

from __future__ import annotations

import numpy as np

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_data


def field_to_tan(lens: Lens, x, y):
    """tan(theta) of the object direction for normalised field (x, y): arrays broadcast together."""
    efl = paraxial_data(lens).efl_mm
    return (np.asarray(x) * lens.sensor.width_mm / 2 / efl, np.asarray(y) * lens.sensor.height_mm / 2 / efl)


def field_radius(lens: Lens, x, y):
    """Normalised image radius in [0, 1] (1 = the sensor corner) of field (x, y)."""
    w, h = lens.sensor.width_mm, lens.sensor.height_mm
    return np.hypot(np.asarray(x) * w / 2, np.asarray(y) * h / 2) / lens.sensor.half_diagonal_mm


def field_of(rows, cols, sensor_hw: tuple[int, int], origin: tuple[int, int] = (0, 0)):
    """Normalised field (x right, y up; +-1 at the sensor edges) of points at (rows, cols) pixel coordinates of a
    window at `origin` of the sensor (pixel centres at +0.5)."""
    hs, ws = sensor_hw
    x = 2 * (np.asarray(cols, dtype=np.float64) + origin[1]) / ws - 1
    y = 1 - 2 * (np.asarray(rows, dtype=np.float64) + origin[0]) / hs
    return x, y


def pixel_fields(height: int, width: int, sensor_hw: tuple[int, int], origin: tuple[int, int] = (0, 0)):
    """Normalised field (x, y) of every pixel centre of an (height, width) window whose top-left pixel is
    `origin` = (row, col) of a full sensor of `sensor_hw` = (rows, cols) pixels. Returns two (H, W) arrays."""
    rows = np.arange(height, dtype=np.float64) + 0.5
    cols = np.arange(width, dtype=np.float64) + 0.5
    cc, rr = np.meshgrid(cols, rows, indexing="xy")
    return field_of(rr, cc, sensor_hw, origin)
