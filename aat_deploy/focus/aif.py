"""All-in-focus image and the spread of the focus weights, blended from the frames by how sharp each one is.

- `weights`: p_s proportional to (m_s / m_max)^power per pixel (m the focus measure): the sharpest frames dominate,
  two frames with the peak between them are mixed, textureless pixels (flat m) average all frames (there every
  frame looks the same, and averaging lowers noise).
- `peak`: linear interpolation between the two frames around the fitted peak (fractional frame index).

`weights` is also what the spread (std) is computed over, as the DfF models' std_m is over their softmax.
"""

from __future__ import annotations

import numpy as np

AIF_MODES = ("weights", "peak")


def focus_weights(volume: np.ndarray, power: float = 4.0) -> np.ndarray:
    """(S, H, W) focus measure -> (S, H, W) float32 weights summing to 1 over frames."""
    m_max = volume.max(0, keepdims=True)
    w = (volume / np.maximum(m_max, 1e-30)) ** np.float32(power)
    w = np.where(m_max > 0, w, 1.0).astype(np.float32)
    return w / w.sum(0, keepdims=True)


def blend(stack: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """stack (S, C, H, W), weights (S, H, W) -> (C, H, W) float32."""
    return np.einsum("schw,shw->chw", stack, weights, optimize=True).astype(np.float32)


def blend_at(stack: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """Linear interpolation between frames floor(frac) and floor(frac) + 1 per pixel: (C, H, W) float32."""
    s = stack.shape[0]
    lo = np.clip(np.floor(frac).astype(np.int64), 0, s - 1)
    hi = np.clip(lo + 1, 0, s - 1)
    t = (frac - lo).astype(np.float32)[None]
    a = np.take_along_axis(stack, lo[None, None].repeat(stack.shape[1], 1), 0)[0]
    b = np.take_along_axis(stack, hi[None, None].repeat(stack.shape[1], 1), 0)[0]
    return ((1 - t) * a + t * b).astype(np.float32)


def spread_m(weights: np.ndarray, frame_m: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """sqrt(sum_s p_s (d_s - depth)^2) in metres; frame_m (S,) or (S, H, W) the frames' in-focus distances."""
    f = frame_m if frame_m.ndim == 3 else frame_m[:, None, None]
    return np.sqrt(np.sum(weights * (f - depth_m[None]) ** 2, 0)).astype(np.float32)
