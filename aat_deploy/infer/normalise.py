"""Input normalisation of DfF stacks (docs/contracts.md), numpy only: the one definition for the runtime, the
training data and the held-out test sets.

The whole stack (every frame and channel together, so relative exposure between frames is kept) is divided by
its 99.5th percentile (numpy's default linear interpolation) and clipped to [0, 1]. An all-black stack
(percentile <= 0) is left unscaled (clipped). Images in the stack's units (its all-in-focus image, frames at
another size) are brought to the same scale with `scaled(x, normalise_scale(stack))`.
"""

from __future__ import annotations

import numpy as np

PERCENTILE = 99.5
DESCRIPTION = "stack / percentile(stack, 99.5) over all frames and channels (linear interpolation), clip [0, 1]"


def normalise_stack(stack: np.ndarray) -> np.ndarray:
    """stack (S, 3, H, W) (any layout: one stack) linear RGB, any non-negative scale -> float32 in [0, 1]."""
    x = np.asarray(stack, dtype=np.float32)
    return scaled(x, normalise_scale(x))


def normalise_scale(stack: np.ndarray) -> np.float32:
    """The divisor normalise_stack uses (so frames at another size can be brought to the same units)."""
    x = np.asarray(stack, dtype=np.float32)
    if x.size == 0:
        raise ValueError("normalise_stack: empty stack")
    if not np.isfinite(x).all():
        raise ValueError("normalise_stack: the stack contains NaN or inf")
    p = np.float32(np.percentile(x, PERCENTILE))
    return p if p > 0 else np.float32(1.0)


def scaled(x: np.ndarray, scale) -> np.ndarray:
    """x divided by a stack's `normalise_scale` and clipped to [0, 1], as float32 (computed in x's precision)."""
    return np.clip(x / scale, 0.0, 1.0).astype(np.float32)
