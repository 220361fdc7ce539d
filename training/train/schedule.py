"""Learning-rate schedule: optional linear warm-up, then a cosine from lr to lr_min over exactly the configured
number of optimizer steps (set every step from the global step, so resuming continues it exactly)."""

from __future__ import annotations

import math


def lr_at(step: int, steps: int, lr: float, lr_min: float = 0.0, warmup_steps: int = 0) -> float:
    """Learning rate for optimizer step `step` (0-based) of `steps`."""
    if warmup_steps > 0 and step < warmup_steps:
        return lr * (step + 1) / warmup_steps
    span = max(1, steps - 1 - warmup_steps)
    t = min(1.0, (step - warmup_steps) / span)
    return lr_min + (lr - lr_min) * 0.5 * (1.0 + math.cos(math.pi * t))
