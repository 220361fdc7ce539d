"""focus_breathing: the image magnification changes as the sensor moves to focus."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from training.optics.paraxial import paraxial_data
from training.psf.geometry import focus_table
from training.render.effects import Effect, SimContext, register


def breathing_scale(lens, focus_m) -> np.ndarray:
    """Image-size ratio for a frame focused at focus_m (m from the sensor) relative to focus at infinity
    (the geometry of the all-in-focus image and the depth map): chief rays leave the exit pupil at fixed
    angles, so image heights grow with the exit-pupil-to-sensor distance."""
    p = paraxial_data(lens)
    table = focus_table(lens)
    z = np.asarray(table(np.asarray(focus_m, dtype=np.float64)))
    z_inf = float(table.sensor_z_mm[0])  # the table's farthest focus (100 m): infinity to 0.01 D
    return (z - p.exit_pupil_z_mm) / (z_inf - p.exit_pupil_z_mm)


def scale_about_axis(frame: torch.Tensor, scale: float, ctx: SimContext) -> torch.Tensor:
    """Magnify frame (C, H, W) by `scale` about the optical axis (the sensor centre), for a crop at ctx.origin:
    out(q) = frame(axis + (q - axis) / scale), bilinear, edges replicated."""
    _, h, w = frame.shape
    hs, ws = ctx.sensor_hw
    cy, cx = hs / 2 - ctx.origin[0], ws / 2 - ctx.origin[1]  # axis in crop pixel coordinates
    rows = torch.arange(h, dtype=torch.float64) + 0.5
    cols = torch.arange(w, dtype=torch.float64) + 0.5
    sr = cy + (rows - cy) / scale
    sc = cx + (cols - cx) / scale
    gy = (2 * sr / h - 1).view(h, 1).expand(h, w)
    gx = (2 * sc / w - 1).view(1, w).expand(h, w)
    grid = torch.stack([gx, gy], -1)[None].to(frame.dtype)
    return F.grid_sample(frame[None], grid, mode="bilinear", padding_mode="border", align_corners=False)[0]


@register
class FocusBreathing(Effect):
    name = "focus_breathing"
    description = "image magnification changes with the focus distance (sensor moves; paraxial exit-pupil model)"
    order = 60

    def warp(self, frame: torch.Tensor, focus_m: float, ctx: SimContext) -> torch.Tensor:
        return scale_about_axis(frame, float(breathing_scale(ctx.lens, focus_m)), ctx)
