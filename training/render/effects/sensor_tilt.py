"""sensor_tilt: the sensor is not perpendicular to the optical axis, so focus varies linearly over the field."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from aat_deploy.optics.focus_table import FocusTable
from training.psf.geometry import focus_table
from training.render.effects import Effect, SimContext, register


def tilted_focus_m(lens, x, y, focus_m: float, tilt_x_deg: float, tilt_y_deg: float,
                   table: FocusTable | None = None) -> np.ndarray:
    """Focus distance (m from the sensor) seen at normalised field (x, y) in [-1, 1] (x right, y up) when the
    sensor, focused at focus_m on axis, is rotated by tilt_x_deg about its vertical axis (the right edge moves
    towards the sensor-side, +z) and tilt_y_deg about its horizontal axis (the top edge moves +z).
    The sensor plane's local axial shift dz = x_mm tan(tilt_x) + y_mm tan(tilt_y) is turned into a focus distance
    with the lens's real-ray focus table (sensor position vs focus distance; default: traced)."""
    table = focus_table(lens) if table is None else table
    s = lens.sensor
    dz = (np.asarray(x, np.float64) * s.width_mm / 2 * math.tan(math.radians(tilt_x_deg))
          + np.asarray(y, np.float64) * s.height_mm / 2 * math.tan(math.radians(tilt_y_deg)))
    z = float(table(focus_m)) + dz
    z = np.clip(z, table.sensor_z_mm[0], table.sensor_z_mm[-1])  # table is ascending in z with diopters
    return 1.0 / np.interp(z, table.sensor_z_mm, table.diopters)


@register
class SensorTilt(Effect):
    name = "sensor_tilt"
    description = "sensor tilted against the optical axis (degrees about its vertical / horizontal axis): focus varies linearly over the field"
    order = 20
    defaults = {"tilt_x_deg": 0.5, "tilt_y_deg": 0.0}
    candidates = [{"tilt_x_deg": t, "tilt_y_deg": 0.0} for t in (-1.0, -0.5, 0.5, 1.0)] + \
                 [{"tilt_x_deg": 0.0, "tilt_y_deg": t} for t in (-1.0, -0.5, 0.5, 1.0)]

    def focus_at(self, ctx: SimContext) -> Callable:
        tx, ty = self.params["tilt_x_deg"], self.params["tilt_y_deg"]
        table = ctx.focus_table()
        return lambda x, y, focus_m: tilted_focus_m(ctx.lens, x, y, focus_m, tx, ty, table)
