"""The shared DfF head: per-pixel focus probabilities over the stack turned into depth, all-in-focus and spread.

p = softmax over S of the logits; depth_m = sum_s p_s focus_m[s]; aif = sum_s p_s frame_s;
std_m = sqrt(sum_s p_s (focus_m[s] - depth_m)^2). Focus distances enter the network only here, so the output
depth lies in [min focus, max focus] and has the unit of `focus_m` (metres from the sensor plane).
"""

from __future__ import annotations

import torch
from torch import Tensor


def focus_head(logits: Tensor, stack: Tensor | None, focus_m: Tensor) -> tuple[Tensor, Tensor | None, Tensor]:
    """Depth, all-in-focus image and uncertainty from per-frame logits.

    logits: (B, S, H, W); stack: (B, S, 3, H, W) or None (then aif is None); focus_m: (B, S).
    Returns depth_m (B, H, W), aif (B, 3, H, W) or None, std_m (B, H, W).
    """
    if logits.dim() != 4 or focus_m.dim() != 2:
        raise ValueError(f"focus_head: logits (B, S, H, W) and focus_m (B, S) expected, got "
                         f"{tuple(logits.shape)} and {tuple(focus_m.shape)}")
    p = torch.softmax(logits, dim=1)
    f = focus_m.to(p.dtype)[:, :, None, None]
    depth = (p * f).sum(1)
    var = (p * (f - depth[:, None]) ** 2).sum(1)
    std = torch.sqrt(var.clamp_min(0.0) + 1e-12)  # + 1e-12: finite gradient at a one-hot p (adds < 1e-6 m)
    aif = (p[:, :, None] * stack).sum(1) if stack is not None else None
    return depth, aif, std
