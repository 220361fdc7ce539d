"""Torch twin of `aat_deploy.normalise.normalise_stack` (docs/contracts.md): divide the whole stack by its
99.5th percentile (numpy's default linear interpolation), clip to [0, 1]. Tested equal to the numpy version."""

from __future__ import annotations

import torch
from torch import Tensor

PERCENTILE = 99.5


def _percentile_linear(flat: Tensor, q: float) -> Tensor:
    """Per-row percentile of (N, M) with numpy's 'linear' method; uses kthvalue (no size limit, unlike quantile)."""
    m = flat.shape[1]
    pos = (q / 100.0) * (m - 1)
    lo = int(pos)
    hi = min(lo + 1, m - 1)
    a = torch.kthvalue(flat, lo + 1, dim=1).values
    b = torch.kthvalue(flat, hi + 1, dim=1).values if hi != lo else a
    t = pos - lo
    a64, b64 = a.double(), b.double()
    d = b64 - a64  # numpy's symmetric lerp, in float64, then float32
    out = b64 - d * (1.0 - t) if t >= 0.5 else a64 + d * t
    return out.float()


def normalise_stack(stack: Tensor, batched: bool = False) -> Tensor:
    """stack (S, 3, H, W) linear RGB (any non-negative scale), or (B, S, 3, H, W) with batched=True (each stack
    normalised on its own) -> float32 of the same shape in [0, 1]."""
    x = stack.float()
    if not torch.isfinite(x).all():
        raise ValueError("normalise_stack: the stack contains NaN or inf")
    flat = x.reshape(x.shape[0], -1) if batched else x.reshape(1, -1)
    p = _percentile_linear(flat, PERCENTILE)
    p = torch.where(p > 0, p, torch.ones_like(p))  # an all-black stack stays 0
    shape = (-1,) + (1,) * (x.dim() - 1) if batched else ()
    return (x / p.reshape(shape)).clamp(0.0, 1.0)
