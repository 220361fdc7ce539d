"""How a PSF is stored: a k x k window whose cell size grows with the defocus blur.

Near focus a cell is one sensor pixel (the paper's representation). Far from focus the blur is far larger than
any fixed window (about 35 px per diopter for the RF50 at 37.5 um pixels), so instead of truncating it the
window's cells grow: cell = s pixels with
    s = max(1, (b + margin_px) / (k - 1)),
b the thin-lens blur-disk diameter (px) at that depth and focus, margin_px an allowance for aberrations
(field curvature, coma) that the thin lens does not have. s depends only on (depth, focus) and the lens, so the
surrogate and the renderer compute it exactly; a kernel with s > 1 is resampled to pixels when rendering.

Values are energy per cell: a PSF sums to the fraction of the on-axis pupil's light that reaches the sensor
inside the window (vignetting and anything outside the window lower it; nothing is renormalised).
Array layout: kernel[row, col], row 0 at the top of the upright image, centre cell (k//2, k//2) on the
reference point (the chief ray's hit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aat_deploy.lens.schema import Lens
from training.psf.geometry import thin_lens_blur_px


@dataclass(frozen=True)
class KernelSpec:
    size: int = 11  # k, odd
    margin_px: float = 4.0  # aberration allowance added to the thin-lens blur (px)

    def __post_init__(self):
        if self.size % 2 != 1 or self.size < 3:
            raise ValueError(f"kernel size must be odd and >= 3, got {self.size}")

    def scale(self, lens: Lens, depth_m, focus_m) -> np.ndarray:
        """Cell size in pixels (>= 1) for each (depth, focus)."""
        b = thin_lens_blur_px(lens, depth_m, focus_m)
        return np.maximum(1.0, (b + self.margin_px) / (self.size - 1))

    @staticmethod
    def for_lens(lens: Lens, size: int = 11, margin_px: float = 4.0) -> "KernelSpec":
        """The spec used with `lens` (sizes are in its sensor pixels; `scale` takes the lens at call time)."""
        return KernelSpec(size=size, margin_px=margin_px)


def splat_bilinear(col: torch.Tensor, row: torch.Tensor, weight: torch.Tensor, k: int) -> torch.Tensor:
    """Bilinear ("tent") splat of points into (B, k, k) windows, the paper's PSF equation.

    col, row: (B, N) continuous cell coordinates (cell centres at integers 0..k-1); weight: (B, N) energy of
    each ray (0 for lost rays). A point spreads over its 4 nearest cells with weights (1-|dx|)(1-|dy|); the
    parts falling outside the window are dropped (they are energy outside the window).
    """
    import torch  # lazily: KernelSpec serves the torch-free runtime too

    b = col.shape[0]
    c0, r0 = torch.floor(col), torch.floor(row)
    fc, fr = col - c0, row - r0
    c0, r0 = c0.long(), r0.long()
    out = torch.zeros(b, k * k, dtype=weight.dtype, device=weight.device)
    for dc, dr, w in ((0, 0, (1 - fc) * (1 - fr)), (1, 0, fc * (1 - fr)), (0, 1, (1 - fc) * fr), (1, 1, fc * fr)):
        cc, rr = c0 + dc, r0 + dr
        inside = (cc >= 0) & (cc < k) & (rr >= 0) & (rr < k)
        idx = torch.where(inside, rr * k + cc, torch.zeros_like(cc))
        out.scatter_add_(1, idx, torch.where(inside, w * weight, torch.zeros_like(w)))
    return out.view(b, k, k)


def downsample2(fine: torch.Tensor) -> torch.Tensor:
    """(..., 2k+1, 2k+1) half-cell tent splat -> (..., k, k) cell tent splat, exactly.

    A tent of half-width one cell equals the half-cell tent convolved with [1/2, 1, 1/2], so the coarse kernel is
    that convolution sampled at the odd fine indices.
    """
    import torch

    t = torch.tensor([0.5, 1.0, 0.5], dtype=fine.dtype, device=fine.device)
    w = (t[:, None] * t[None, :]).view(1, 1, 3, 3)
    shp = fine.shape
    out = torch.nn.functional.conv2d(fine.reshape(-1, 1, shp[-2], shp[-1]), w, stride=2)
    return out.view(*shp[:-2], out.shape[-2], out.shape[-1])
