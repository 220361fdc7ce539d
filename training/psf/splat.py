"""Splatting ray hits into PSF windows (torch): the paper's bilinear splat and the exact half-cell to cell
reduction. The window's layout and cell sizes: `aat_deploy.psf.kernel`."""

from __future__ import annotations

import torch


def splat_bilinear(col: torch.Tensor, row: torch.Tensor, weight: torch.Tensor, k: int) -> torch.Tensor:
    """Bilinear ("tent") splat of points into (B, k, k) windows, the paper's PSF equation.

    col, row: (B, N) continuous cell coordinates (cell centres at integers 0..k-1); weight: (B, N) energy of
    each ray (0 for lost rays). A point spreads over its 4 nearest cells with weights (1-|dx|)(1-|dy|); the
    parts falling outside the window are dropped (they are energy outside the window).
    """
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
    t = torch.tensor([0.5, 1.0, 0.5], dtype=fine.dtype, device=fine.device)
    w = (t[:, None] * t[None, :]).view(1, 1, 3, 3)
    shp = fine.shape
    out = torch.nn.functional.conv2d(fine.reshape(-1, 1, shp[-2], shp[-1]), w, stride=2)
    return out.view(*shp[:-2], out.shape[-2], out.shape[-1])
