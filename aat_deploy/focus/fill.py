"""Edge-aware filling of unreliable depth, guided by the all-in-focus image (numpy + OpenCV).

Where a pixel has no texture its focus curve is flat and its estimate is noise; its neighbours across a
colour edge usually belong to another surface. Normalised convolution with the domain transform's recursive filter
(Gastal & Oliveira, "Domain Transform for Edge-Aware Image and Video Processing", SIGGRAPH 2011) spreads confident
estimates along the guide's smooth regions and stops at its edges:

    filled = RF(c * d) / RF(c)

with c the confidence, d the estimate (in diopters: blur, hence the estimate's error, is even in diopters) and RF
the recursive filter (spatial sigma `sigma_s_px`, range sigma `sigma_r` in the guide's units, `iterations`
separable passes). The result replaces d by `filled` in proportion to how unconfident a pixel is:
    out = a d + (1 - a) filled,   a = clip(c / c_full, 0, 1).

The filter runs at 1/`downscale` of the size (the depth map is smooth where filling matters; the guide keeps
edges) and its result is resized back; confident pixels keep their own full-resolution estimate.
"""

from __future__ import annotations

import cv2
import numpy as np


def _recursive_pass(f: np.ndarray, v: np.ndarray) -> None:
    """In place along axis 0: f (N, M) signals, v (N, M) feedback weights a^dt (v[i] links i-1 and i)."""
    n = f.shape[0]
    for i in range(1, n):
        f[i] += v[i] * (f[i - 1] - f[i])
    for i in range(n - 2, -1, -1):
        f[i] += v[i + 1] * (f[i + 1] - f[i])


def domain_transform_nc(signals: np.ndarray, guide: np.ndarray, sigma_s_px: float, sigma_r: float,
                        iterations: int = 3) -> np.ndarray:
    """Recursive-filter each of `signals` (K, H, W) guided by `guide` (C, H, W) (or (H, W)); returns (K, H, W).

    The domain transform's derivative is 1 + sigma_s / sigma_r * sum_c |d guide_c|, per axis."""
    g = guide if guide.ndim == 3 else guide[None]
    ratio = sigma_s_px / max(sigma_r, 1e-6)
    dx = 1.0 + ratio * np.abs(np.diff(g, axis=2)).sum(0)  # (H, W-1): between columns j-1 and j
    dy = 1.0 + ratio * np.abs(np.diff(g, axis=1)).sum(0)  # (H-1, W)
    out = np.array(signals, np.float64, copy=True)
    k, h, w = out.shape
    for it in range(iterations):
        sigma_h = sigma_s_px * np.sqrt(3.0) * 2.0 ** (iterations - it - 1) / np.sqrt(4.0 ** iterations - 1)
        a = np.exp(-np.sqrt(2.0) / sigma_h)
        # horizontal: iterate over columns (axis 0 after transposing to (W, K*H))
        vx = np.ones((w, h), np.float64)
        vx[1:] = (a ** dx).T
        fx = np.ascontiguousarray(out.transpose(2, 0, 1).reshape(w, k * h))
        _recursive_pass(fx, np.tile(vx, (1, k)))
        out = fx.reshape(w, k, h).transpose(1, 2, 0)
        vy = np.ones((h, w), np.float64)
        vy[1:] = a ** dy
        fy = np.ascontiguousarray(out.transpose(1, 0, 2).reshape(h, k * w))
        _recursive_pass(fy, np.tile(vy, (1, k)))
        out = fy.reshape(h, k, w).transpose(1, 0, 2)
    return np.ascontiguousarray(out)


def fill_depth(diopters: np.ndarray, confidence: np.ndarray, guide: np.ndarray, sigma_s_px: float = 40.0,
               sigma_r: float = 0.1, c_full: float = 0.5, downscale: int = 2, iterations: int = 3) -> np.ndarray:
    """diopters (H, W), confidence (H, W) in [0, 1], guide (3, H, W) all-in-focus (display units, about [0, 1])
    -> (H, W) float32 diopters with unconfident pixels filled from confident ones along the guide."""
    return fill_with_support(diopters, confidence, guide, sigma_s_px, sigma_r, c_full, downscale, iterations)[0]


def fill_with_support(diopters: np.ndarray, confidence: np.ndarray, guide: np.ndarray, sigma_s_px: float = 40.0,
                      sigma_r: float = 0.1, c_full: float = 0.5, downscale: int = 2, iterations: int = 3
                      ) -> tuple[np.ndarray, np.ndarray]:
    """`fill_depth`, and the fill's support (H, W) float32 in [0, 1]: RF(c), the confidence averaged over the
    pixel's edge-aware neighbourhood (how much confident evidence the fill drew on; 0 where none reached)."""
    h, w = diopters.shape
    ds = max(1, int(downscale))
    sw, sh = max(1, w // ds), max(1, h // ds)

    def small(img):
        return cv2.resize(np.ascontiguousarray(img, np.float32), (sw, sh), interpolation=cv2.INTER_AREA)

    c = confidence.astype(np.float32)
    num_den = np.stack([small(c * diopters), small(c)])
    g = np.stack([small(ch) for ch in guide]) if guide.ndim == 3 else small(guide)[None]
    f = domain_transform_nc(num_den, g, sigma_s_px / ds, sigma_r, iterations)
    own = small(diopters)
    filled = np.where(f[1] > 1e-6, f[0] / np.maximum(f[1], 1e-12), own).astype(np.float32)  # no confident pixel
    support = np.clip(f[1], 0.0, 1.0).astype(np.float32)
    if (sw, sh) != (w, h):
        filled = cv2.resize(filled, (w, h), interpolation=cv2.INTER_LINEAR)
        support = cv2.resize(support, (w, h), interpolation=cv2.INTER_LINEAR)
    a = np.clip(c / c_full, 0.0, 1.0)
    return (a * diopters + (1 - a) * filled).astype(np.float32), support
