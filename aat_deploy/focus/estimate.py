"""From a focus volume to a per-pixel in-focus position (diopters) and a confidence, numpy only.

The focus curve of a pixel is its measure across the frames, m_s, plotted against where each frame is in focus
at that pixel, x_s (object diopters, 1/m from the sensor). The estimate is the curve's peak:

- `argmax`    x at the sharpest frame;
- `parabola`  the vertex of the parabola through the sharpest frame and its two neighbours (m against x);
- `gauss`     the same on log m: the vertex of a Gaussian through the three points (Nayar & Nakagawa's Gaussian
              interpolation), exact for a Gaussian focus curve;
- `ratio`     two points, the sharpest frame and its sharper neighbour, for a focus curve with power-law tails,
              m ~ |x - D|^-gamma (what a defocus blur growing linearly in diopters does to a high-pass measure of a
              natural texture far from focus): D divides the interval between them in the ratio (m_k / m_n)^(1/gamma).
              It needs no third frame, which on a coarse schedule often already sits on the measure's floor.

Positions are in diopters because defocus blur is linear in diopters (not metres); they may differ per frame only
(`x` of shape (S,), the nominal focus distances: the thin-lens mapping) or per frame and field radius (`x` of shape
(S, R) with each pixel's radius bin `rbin` (H, W): the aberration-aware mapping of `bestfocus.BestFocusMap`). The
three points need not be evenly spaced. At the first and last frame the three end frames are used and the peak is
kept between the end frame and its neighbour (never beyond the stack).

Confidence in [0, 1]: (m_max - m_min) / (m_max + tau), tau = `tau_rel` x the 99th percentile of m_max over the
image: near 1 for a textured pixel with a clear peak, near 0 where no frame is sharper than another (textureless).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ESTIMATORS = ("argmax", "parabola", "gauss", "ratio")


@dataclass
class Peak:
    """diopters (H, W) float32 in-focus object position; index (H, W) int sharpest frame; frac (H, W) float32
    fractional frame index of the peak (index + offset, for blending); confidence (H, W) float32 in [0, 1]."""

    diopters: np.ndarray
    index: np.ndarray
    frac: np.ndarray
    confidence: np.ndarray


def positions_at(x: np.ndarray, k: np.ndarray, rbin: np.ndarray | None) -> np.ndarray:
    """Frame positions at frame index k (H, W): x (S,) or x (S, R) with rbin (H, W)."""
    if x.ndim == 1:
        return x[k]
    s = x.shape[0]
    return np.take(np.ascontiguousarray(x.T).ravel(), rbin * s + k)  # a flat take: several times faster


def _vertex(x0, x1, x2, y0, y1, y2):
    """Abscissa of the vertex of the parabola through three points (any spacing); x1 where it is degenerate."""
    a, b = x1 - x0, x1 - x2
    fa, fb = y1 - y2, y1 - y0
    den = a * fa - b * fb
    num = a * a * fa - b * b * fb
    with np.errstate(divide="ignore", invalid="ignore"):
        v = x1 - 0.5 * num / den
    return np.where(np.abs(den) > 1e-20, v, x1)


def _ratio_peak(volume, x, rbin, k, m_max, gamma):
    """Two-point estimate between the sharpest frame k and its sharper neighbour n, for focus curves
    m(x) ~ |x - D|^-gamma: (m_k / m_n)^(1/gamma) = |x_n - D| / |x_k - D|, D between them, nearer to x_k."""
    s = volume.shape[0]
    kl, kr = np.clip(k - 1, 0, s - 1), np.clip(k + 1, 0, s - 1)
    ml = np.take_along_axis(volume, kl[None], 0)[0]
    mr = np.take_along_axis(volume, kr[None], 0)[0]
    right = ((mr >= ml) & (k < s - 1)) | (k == 0)
    n = np.where(right, kr, kl)
    mn = np.where(right, mr, ml)
    rho = (m_max / np.maximum(mn, 1e-30 + 1e-9 * m_max)) ** np.float32(1.0 / gamma)
    xk, xn = positions_at(x, k, rbin), positions_at(x, n, rbin)
    return (xn + rho * xk) / (1 + rho), ((n + rho * k) / (1 + rho)).astype(np.float32)


def estimate_peak(volume: np.ndarray, x: np.ndarray, rbin: np.ndarray | None = None, estimator: str = "gauss",
                  tau_rel: float = 1e-3, gamma: float = 2.0) -> Peak:
    """volume (S, H, W) focus measure; x (S,) or (S, R) frame positions in diopters (see module doc)."""
    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator {estimator!r} (one of {', '.join(ESTIMATORS)})")
    s = volume.shape[0]
    x = np.asarray(x, np.float32)
    if x.shape[0] != s or (x.ndim == 2 and rbin is None):
        raise ValueError(f"positions {x.shape} do not fit a volume of {s} frames")
    k = np.argmax(volume, axis=0)
    m_max = np.take_along_axis(volume, k[None], 0)[0]
    m_min = volume.min(0)
    x1 = positions_at(x, k, rbin)
    frac = k.astype(np.float32)
    if estimator == "ratio" and s >= 2:
        x1, frac = _ratio_peak(volume, x, rbin, k, m_max, gamma)
    elif estimator != "argmax" and s >= 3:
        # Three points around the peak; at the first/last frame the three end frames, with the vertex kept
        # between the end frame and its neighbour (the curve rises towards the end: the peak is on that side).
        kc = np.clip(k, 1, s - 2)
        kl, kr = kc - 1, kc + 1
        y0 = np.take_along_axis(volume, kl[None], 0)[0]
        y1 = np.take_along_axis(volume, kc[None], 0)[0]
        y2 = np.take_along_axis(volume, kr[None], 0)[0]
        if estimator == "gauss":
            eps = np.float32(1e-12) + 1e-6 * m_max
            y0, y1, y2 = np.log(y0 + eps), np.log(y1 + eps), np.log(y2 + eps)
        x0, xc, x2 = positions_at(x, kl, rbin), positions_at(x, kc, rbin), positions_at(x, kr, rbin)
        v = _vertex(x0, xc, x2, y0, y1, y2)
        vi = _vertex(kl.astype(np.float32), kc.astype(np.float32), kr.astype(np.float32), y0, y1, y2)
        # the interval the peak can be in: between the sharpest frame's neighbours, or at an end between the end
        # frame and its neighbour
        left = np.where(k == s - 1, kc, kl)
        right = np.where(k == 0, kc, kr)
        xa, xb = positions_at(x, left, rbin), positions_at(x, right, rbin)
        # At an end the three points may bend the wrong way (the neighbours on a blur floor): no peak, keep the end.
        concave = ((y1 - y0) * (x2 - xc) + (y1 - y2) * (xc - x0)) * (x2 - x0) > 0  # y1 above the chord
        fit = (k == kc) | concave
        x1 = np.where(fit, np.clip(v, np.minimum(xa, xb), np.maximum(xa, xb)), positions_at(x, k, rbin))
        frac = np.where(fit, np.clip(vi, left, right), k).astype(np.float32)
    return Peak(x1.astype(np.float32), k, frac, contrast(m_max, m_min, tau_rel))


def contrast(m_max: np.ndarray, m_min: np.ndarray, tau_rel: float) -> np.ndarray:
    """The focus curve's contrast (m_max - m_min) / (m_max + tau) in [0, 1], tau = tau_rel x the image's 99th
    percentile of m_max (a measure far below the image's sharpest texture counts for little): (H, W) float32."""
    q = float(np.percentile(m_max, 99)) if m_max.size else 0.0
    tau = np.float32(max(tau_rel * q, 1e-30))
    return np.clip(((m_max - m_min) / (m_max + tau)).astype(np.float32), 0, 1)
