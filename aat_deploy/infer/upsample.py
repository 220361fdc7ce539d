"""Depth and all-in-focus at the capture's native resolution from a result at the model's working size.

A DfF model runs at its sensor size (960 x 640 for the shipped ones); the frames are often much larger. Upsampling
the depth by interpolation alone blurs its edges over several native pixels. Here:
1. a native all-in-focus image is blended from the native frames, each pixel taking the two frames whose focus
   distances bracket its (interpolated) depth, linearly in diopters;
2. the depth is upsampled with the fast guided filter (He, Sun, "Fast Guided Filter", 2015; He, Sun, Tang,
   "Guided Image Filtering", TPAMI 2013): the filter's linear coefficients are fitted at the working size between
   the reduced guide (the all-in-focus image's grey) and the inverse depth, interpolated to native size and applied
   to the native guide, so depth edges follow the image's edges at native resolution;
3. the all-in-focus image is blended again with that depth.
Inverse depth (diopters) is filtered, since defocus is linear in it; the result stays inside the working-size
depth's range. Uncertainty is interpolated bilinearly.
"""

from __future__ import annotations

import cv2
import numpy as np

RADIUS_PX = 4      # guided filter window radius at the working size
EPS = 1e-3         # regularisation in guide units squared (grey sRGB in [0, 1]): edges of contrast >~ 0.03 kept


def _box(x: np.ndarray, r: int) -> np.ndarray:
    return cv2.boxFilter(x, -1, (2 * r + 1, 2 * r + 1), normalize=True, borderType=cv2.BORDER_REFLECT)


def guided_upsample(values_lo: np.ndarray, guide_hi: np.ndarray, radius: int = RADIUS_PX, eps: float = EPS
                    ) -> np.ndarray:
    """values_lo (h, w) float -> (H, W) following the edges of guide_hi (H, W) float (about [0, 1]).

    The fast guided filter with subsampling ratio H/h: coefficients a, b of values ~ a * guide + b fitted in
    (2 radius + 1)^2 windows at (h, w) against the guide reduced by area averaging, smoothed, bilinearly enlarged,
    then a * guide_hi + b. Non-finite values are not allowed."""
    hl, wl = values_lo.shape
    hh, wh = guide_hi.shape
    g_hi = guide_hi.astype(np.float32)
    g = cv2.resize(g_hi, (wl, hl), interpolation=cv2.INTER_AREA) if (hh, wh) != (hl, wl) else g_hi
    p = values_lo.astype(np.float32)
    mg, mp = _box(g, radius), _box(p, radius)
    cov = _box(g * p, radius) - mg * mp
    var = _box(g * g, radius) - mg * mg
    a = cov / (var + np.float32(eps))
    b = mp - a * mg
    a, b = _box(a, radius), _box(b, radius)
    if (hh, wh) != (hl, wl):
        a = cv2.resize(a, (wh, hh), interpolation=cv2.INTER_LINEAR)
        b = cv2.resize(b, (wh, hh), interpolation=cv2.INTER_LINEAR)
    return a * g_hi + b


def blend_by_depth(frames: list[np.ndarray], focus_m: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """All-in-focus (H, W, 3) from frames (each (H, W, 3), sorted by focus near to far) and a depth map (H, W) in
    metres: each pixel is the linear blend, in diopters, of the two frames whose focus brackets its depth (the
    nearest frame outside the stack's range)."""
    diop = 1.0 / np.asarray(focus_m, np.float64)          # descending (near to far)
    knots = diop[::-1]                                    # ascending, for np.interp
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.nan_to_num(1.0 / depth_m.astype(np.float64), nan=knots[0], posinf=knots[-1], neginf=knots[0])
    out = np.zeros(frames[0].shape, np.float32)
    for s, fr in enumerate(frames):
        onehot = np.zeros(len(knots))
        onehot[len(knots) - 1 - s] = 1.0
        wgt = np.interp(d, knots, onehot).astype(np.float32)
        if wgt.any():
            out += wgt[..., None] * fr
    return out


def grey(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear RGB -> (H, W) float32 grey in a perceptual scale (sqrt of the Rec.709 luminance):
    the guide's edges as a viewer sees them."""
    lum = rgb.astype(np.float32) @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    return np.sqrt(np.clip(lum, 0.0, 1.0))


def native_maps(depth_lo: np.ndarray, std_lo: np.ndarray | None, frames_hi: list[np.ndarray],
                focus_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(depth_m (H, W), aif (3, H, W), std_m (H, W) or None) at the frames' size from the working-size depth_m
    (h, w) and std_m; frames_hi: the native frames (H, W, 3), normalised like the stack, sorted near to far."""
    hh, wh = frames_hi[0].shape[:2]
    ok = np.isfinite(depth_lo) & (depth_lo > 0)
    inv_lo = np.where(ok, 1.0 / np.where(ok, depth_lo, 1.0), np.nan).astype(np.float32)
    fill = float(np.nanmedian(inv_lo)) if ok.any() else 1.0
    inv_lo = np.nan_to_num(inv_lo, nan=fill)
    lo, hi = float(inv_lo.min()), float(inv_lo.max())
    inv_lin = cv2.resize(inv_lo, (wh, hh), interpolation=cv2.INTER_LINEAR)
    aif0 = blend_by_depth(frames_hi, focus_m, 1.0 / np.maximum(inv_lin, 1e-6))
    inv_hi = np.clip(guided_upsample(inv_lo, grey(aif0)), lo, hi)
    depth_hi = (1.0 / np.maximum(inv_hi, 1e-9)).astype(np.float32)
    if not ok.all():  # unknown stays unknown (nearest)
        mask = cv2.resize(ok.astype(np.uint8), (wh, hh), interpolation=cv2.INTER_NEAREST).astype(bool)
        depth_hi[~mask] = np.nan
    aif = blend_by_depth(frames_hi, focus_m, depth_hi).transpose(2, 0, 1)
    std_hi = None if std_lo is None else cv2.resize(std_lo.astype(np.float32), (wh, hh),
                                                     interpolation=cv2.INTER_LINEAR)
    return depth_hi, np.ascontiguousarray(aif), std_hi
