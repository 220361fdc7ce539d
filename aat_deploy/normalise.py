"""Input normalisation of DfF stacks (docs/contracts.md), numpy only: the runtime never imports torch.

The whole stack (every frame and channel together, so relative exposure between frames is kept) is divided by
its 99.5th percentile (numpy's default linear interpolation) and clipped to [0, 1]. An all-black stack
(percentile <= 0) is left unscaled (clipped). The torch twin is `training.nets.normalise.normalise_stack`.
"""

from __future__ import annotations

import numpy as np

PERCENTILE = 99.5
DESCRIPTION = "stack / percentile(stack, 99.5) over all frames and channels (linear interpolation), clip [0, 1]"


def normalise_stack(stack: np.ndarray) -> np.ndarray:
    """stack (S, 3, H, W) (any layout: one stack) linear RGB, any non-negative scale -> float32 in [0, 1]."""
    x = np.asarray(stack, dtype=np.float32)
    return np.clip(x / normalise_scale(x), 0.0, 1.0).astype(np.float32)


def normalise_scale(stack: np.ndarray) -> np.float32:
    """The divisor normalise_stack uses (so frames at another size can be brought to the same units)."""
    x = np.asarray(stack, dtype=np.float32)
    if x.size == 0:
        raise ValueError("normalise_stack: empty stack")
    if not np.isfinite(x).all():
        raise ValueError("normalise_stack: the stack contains NaN or inf")
    p = np.float32(np.percentile(x, PERCENTILE))
    return p if p > 0 else np.float32(1.0)
