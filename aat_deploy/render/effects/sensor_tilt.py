"""sensor_tilt: the sensor is not perpendicular to the optical axis, so focus varies linearly over the field."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from aat_deploy.optics.focus_table import FocusTable
from aat_deploy.render.effects import Effect, SimContext, register, traced_focus_table


def tilt_shift_mm(lens, x, y, tilt_x_deg: float, tilt_y_deg: float) -> np.ndarray:
    """Axial shift (mm, + away from the lens) of the sensor plane at normalised field (x, y) when it is rotated
    by tilt_x_deg about its vertical axis and tilt_y_deg about its horizontal axis: x_mm tan(tx) + y_mm tan(ty)."""
    s = lens.sensor
    return (np.asarray(x, np.float64) * s.width_mm / 2 * math.tan(math.radians(tilt_x_deg))
            + np.asarray(y, np.float64) * s.height_mm / 2 * math.tan(math.radians(tilt_y_deg)))


def tilted_focus_m(lens, x, y, focus_m: float, tilt_x_deg: float, tilt_y_deg: float,
                   table: FocusTable | None = None) -> np.ndarray:
    """Focus distance (m from the sensor) seen at normalised field (x, y) in [-1, 1] (x right, y up) when the
    sensor, focused at focus_m on axis, is rotated by tilt_x_deg about its vertical axis (the right edge moves
    towards the sensor-side, +z) and tilt_y_deg about its horizontal axis (the top edge moves +z).
    The sensor plane's local axial shift dz = x_mm tan(tilt_x) + y_mm tan(tilt_y) is turned into a focus distance
    with the lens's real-ray focus table (sensor position vs focus distance; default: traced)."""
    table = traced_focus_table(lens) if table is None else table
    z = float(table(focus_m)) + tilt_shift_mm(lens, x, y, tilt_x_deg, tilt_y_deg)
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

    def sensor_shift_mm(self, ctx: SimContext) -> Callable:
        tx, ty = float(self.params["tilt_x_deg"]), float(self.params["tilt_y_deg"])
        return lambda x, y, focus_m: tilt_shift_mm(ctx.lens, x, y, tx, ty)
