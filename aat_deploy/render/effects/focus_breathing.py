"""focus_breathing: the image magnification changes as the sensor moves to focus."""

from __future__ import annotations

import numpy as np

from aat_deploy.optics.focus_table import FocusTable
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.render.effects import Effect, SimContext, register, traced_focus_table


def breathing_scale(lens, focus_m, table: FocusTable | None = None, exit_pupil_z_mm: float | None = None) -> np.ndarray:
    """Image-size ratio for a frame focused at focus_m (m from the sensor) relative to focus at infinity
    (the geometry of the all-in-focus image and the depth map): chief rays leave the exit pupil at fixed
    angles, so image heights grow with the exit-pupil-to-sensor distance. table: the lens's focus table
    (default: traced); exit_pupil_z_mm: mm from the first vertex (default: paraxial from the lens)."""
    xp = paraxial_data(lens).exit_pupil_z_mm if exit_pupil_z_mm is None else exit_pupil_z_mm
    table = traced_focus_table(lens) if table is None else table
    z = np.asarray(table(np.asarray(focus_m, dtype=np.float64)))
    z_inf = float(table.sensor_z_mm[0])  # the table's farthest focus (100 m): infinity to 0.01 D
    return (z - xp) / (z_inf - xp)


def _bilinear_axis(src: np.ndarray, n: int):
    """Taps (i0, i1) and weight of i1 for sampling n pixels at index coordinates `src` (pixel centres at
    integers), clamped to the border (grid_sample's padding_mode='border')."""
    src = np.clip(src, 0, n - 1)
    i0 = np.floor(src).astype(np.intp)
    i1 = np.minimum(i0 + 1, n - 1)
    return i0, i1, src - i0


def scale_about_axis(frame: np.ndarray, scale: float, ctx: SimContext) -> np.ndarray:
    """Magnify frame (C, H, W) by `scale` about the optical axis (the sensor centre), for a crop at ctx.origin:
    out(q) = frame(axis + (q - axis) / scale), bilinear, edges replicated. Separable: rows, then columns."""
    return warp_about_axis(frame, scale, (0.0, 0.0), ctx)


def warp_about_axis(frame: np.ndarray, scale: float, shift_xy: tuple[float, float], ctx: SimContext) -> np.ndarray:
    """Magnify frame (C, H, W) by `scale` about the optical axis, then move it by shift_xy = (dx right, dy down)
    pixels: out(q) = frame(axis + (q - axis - shift) / scale), bilinear, edges replicated."""
    _, h, w = frame.shape
    hs, ws = ctx.sensor_hw
    cy, cx = hs / 2 - ctx.origin[0], ws / 2 - ctx.origin[1]  # axis in crop pixel coordinates
    dx, dy = float(shift_xy[0]), float(shift_xy[1])
    # source position of each output pixel centre (coordinates with pixel centres at +0.5), as an index
    r0, r1, wr = _bilinear_axis(cy + (np.arange(h) + 0.5 - cy - dy) / scale - 0.5, h)
    c0, c1, wc = _bilinear_axis(cx + (np.arange(w) + 0.5 - cx - dx) / scale - 0.5, w)
    wr, wc = wr.astype(frame.dtype)[:, None], wc.astype(frame.dtype)
    rows = frame[:, r0] * (1 - wr) + frame[:, r1] * wr
    return rows[:, :, c0] * (1 - wc) + rows[:, :, c1] * wc


@register
class FocusBreathing(Effect):
    name = "focus_breathing"
    description = ("image magnification changes with the focus distance (sensor moves; paraxial exit-pupil model); "
                   "coefficient scales the modelled change (1 = the lens's model; a lens that also moves groups "
                   "to focus breathes more or less)")
    order = 60
    defaults = {"coefficient": 1.0}

    def warp(self, frame: np.ndarray, focus_m: float, ctx: SimContext) -> np.ndarray:
        s = float(breathing_scale(ctx.lens, focus_m, ctx.focus_table(), ctx.exit_pupil_z_mm))
        k = float(self.params["coefficient"])
        return scale_about_axis(frame, s if k == 1.0 else 1.0 + k * (s - 1.0), ctx)
