"""Focus measures: how sharp each frame is around each pixel (numpy + OpenCV, no torch).

A focus measure turns one grey frame (H, W) into a sharpness map (H, W) >= 0: a high-pass response squared (or
rectified), averaged over a window. Compared across the frames of a stack at one pixel it peaks in the frame that
has that pixel in focus. The measures here are the ones the literature ranks high (Pertuz, Puig, Garcia,
"Analysis of focus measure operators for shape-from-focus", Pattern Recognition 2013):

- `lape`   energy of the 4-neighbour Laplacian (the 30-line baseline of issue 19);
- `sml`    sum-modified-Laplacian (Nayar & Nakagawa 1994): |d2/dx2| + |d2/dy2| with step `step` px, windowed;
- `mlap2`  the squared modified Laplacian (Pertuz's LAP2 ranked among the best), windowed;
- `tenengrad`  squared Sobel gradient magnitude, windowed;
- `multiscale` `mlap2` on an image pyramid (levels 0, 1, 2), each level divided by its mean over the stack so
  that every level weighs alike, summed at full size: coarse levels still tell frames apart where the fine
  level sees only blur (far from every frame's focus);
- `narrowband` the local energy of one narrow band of spatial frequency (a quadrature Gabor pair at
  NARROWBAND_CYCLES_PX, its envelope 1 / that in px) along four orientations, windowed, each orientation divided
  **at each pixel** by its own largest value over the stack, and summed. Off axis an aberrated lens is sharpest
  at different focus for different orientations (sagittal / tangential) and for fine and coarse detail; a
  broad-band measure weighs these by the texture's own energy, so its peak moves with the texture (a phone
  lens at field radius 0.75: by 0.27 D SD between textures, `benchmarks/probes/measure_texture.py`). One band
  with orientations weighed alike peaks where the lens's MTF at that band is highest, whatever the texture. Its
  values say nothing about texture strength (every textured pixel peaks at 4): a measure for locating peaks,
  not for the confidence of a depth map. Use it without the pre-filter (a 1 px one tilts its band toward coarse
  detail, and the texture dependence returns). On the phone's noisy chart sweeps, 1.1 D apart, it did not beat
  `mlap2` (BENCHMARKS.md, "Calibrating a camera"), so nothing uses it by default.

Windows are Gaussian with standard deviation `window_px / 4` (a window of about `window_px` pixels).
`prefilter_px` > 0 blurs each grey frame first (Gaussian, that standard deviation in px): the measures are
high-pass, so without it sensor noise (whose spectrum is flat up to the pixel pitch) dominates them wherever the
frames are out of focus, and the per-pixel argmax picks noise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)  # Rec. 709 / sRGB primaries (linear)


def grey(stack: np.ndarray) -> np.ndarray:
    """(S, 3, H, W) linear RGB -> (S, H, W) float32 luminance; (S, H, W) passes through."""
    x = np.asarray(stack, np.float32)
    if x.ndim == 3:
        return x
    if x.ndim != 4 or x.shape[1] != 3:
        raise ValueError(f"stack must be (S, 3, H, W) or (S, H, W), got {x.shape}")
    return np.einsum("schw,c->shw", x, LUMA, optimize=True).astype(np.float32)


def _window(img: np.ndarray, window_px: float) -> np.ndarray:
    """Gaussian mean over about window_px pixels (a box of the same size measured worse on held-out stacks)."""
    sigma = max(float(window_px) / 4.0, 0.3)
    return cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)


def second_diffs(g: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray]:
    k = np.zeros((1, 2 * step + 1), np.float32)
    k[0, 0], k[0, step], k[0, -1] = 1.0, -2.0, 1.0
    dxx = cv2.filter2D(g, cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT)
    dyy = cv2.filter2D(g, cv2.CV_32F, k.T, borderType=cv2.BORDER_REFLECT)
    return dxx, dyy


def lape(g: np.ndarray, window_px: float = 9, step: int = 1) -> np.ndarray:
    lap = cv2.Laplacian(g, cv2.CV_32F, ksize=1, borderType=cv2.BORDER_REFLECT)
    return _window(lap * lap, window_px)


def sml(g: np.ndarray, window_px: float = 9, step: int = 1) -> np.ndarray:
    dxx, dyy = second_diffs(g, step)
    return _window(np.abs(dxx) + np.abs(dyy), window_px)


def mlap2(g: np.ndarray, window_px: float = 9, step: int = 1) -> np.ndarray:
    dxx, dyy = second_diffs(g, step)
    ml = np.abs(dxx) + np.abs(dyy)
    return _window(ml * ml, window_px)


def tenengrad(g: np.ndarray, window_px: float = 9, step: int = 1) -> np.ndarray:
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REFLECT)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REFLECT)
    return _window(gx * gx + gy * gy, window_px)


def prefilter(g: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur of each grey frame (S, H, W) with standard deviation sigma_px (px); 0 returns g."""
    if not sigma_px:
        return g
    if sigma_px < 0:
        raise ValueError(f"prefilter_px must be >= 0, got {sigma_px}")
    return np.stack([cv2.GaussianBlur(f, (0, 0), float(sigma_px), borderType=cv2.BORDER_REFLECT) for f in g])


def _each_frame(measure: Callable) -> Callable:
    """A measure of one frame (H, W) as a measure of a grey stack (S, H, W)."""
    def volume(g: np.ndarray, window_px: float, step: int, levels: int) -> np.ndarray:
        return np.stack([measure(f, window_px, step) for f in g])
    return volume


def multiscale(g: np.ndarray, window_px: float = 9, step: int = 1, levels: int = 3) -> np.ndarray:
    """`mlap2` on pyramid levels 0..levels-1 of a grey stack (S, H, W), each level over its mean over the stack,
    summed at full size -> (S, H, W) float32."""
    s, h, w = g.shape
    out = np.zeros((s, h, w), np.float32)
    pyr = [np.ascontiguousarray(f) for f in g]
    for lev in range(levels):
        vol = np.stack([mlap2(f, window_px, step) for f in pyr])
        mean = float(vol.mean())
        if mean > 0:
            vol /= mean
        out += vol if lev == 0 else np.stack([cv2.resize(v, (w, h), interpolation=cv2.INTER_LINEAR) for v in vol])
        if lev + 1 < levels:
            if min(pyr[0].shape) < 16:
                break
            pyr = [cv2.pyrDown(f, borderType=cv2.BORDER_REFLECT) for f in pyr]
    return out


NARROWBAND_CYCLES_PX = 0.35  # `narrowband`'s band: fine detail, below the 0.5 cycles/px Nyquist limit
NARROWBAND_ORIENTATIONS = 4
NARROWBAND_FLOOR = 1e-10  # energy (grey levels 0-1, squared) under which a pixel has no texture in the band


def gabor_pair(cycles_px: float, theta: float) -> tuple[np.ndarray, np.ndarray]:
    """(even, odd) Gabor kernels at cycles_px along direction theta (rad), isotropic Gaussian envelope of
    standard deviation 1 / cycles_px px (a band about +-cycles_px / 2 pi wide); the even one without DC."""
    sigma = 1.0 / cycles_px
    k = 2 * int(np.ceil(3 * sigma)) + 1
    even = cv2.getGaborKernel((k, k), sigma, theta, 1.0 / cycles_px, 1.0, 0.0, ktype=cv2.CV_32F)
    odd = cv2.getGaborKernel((k, k), sigma, theta, 1.0 / cycles_px, 1.0, np.pi / 2, ktype=cv2.CV_32F)
    return even - even.mean(), odd


def narrowband(g: np.ndarray, window_px: float = 9, step: int = 1, levels: int = 1) -> np.ndarray:
    """Grey stack (S, H, W) -> (S, H, W) float32: per orientation the Gabor energy at NARROWBAND_CYCLES_PX,
    windowed, over its maximum across the stack at that pixel; summed over NARROWBAND_ORIENTATIONS. A pixel
    whose largest energy is under 1e-6 of the stack's largest, or under NARROWBAND_FLOOR, is divided by that
    instead: a pixel without texture adds little (a flat stack ~0) rather than a normalised curve of its own."""
    s, h, w = g.shape
    out = np.zeros((s, h, w), np.float32)
    for i in range(NARROWBAND_ORIENTATIONS):
        even, odd = gabor_pair(NARROWBAND_CYCLES_PX, np.pi * i / NARROWBAND_ORIENTATIONS)
        comp = np.stack([_window(cv2.filter2D(f, cv2.CV_32F, even, borderType=cv2.BORDER_REFLECT) ** 2
                                 + cv2.filter2D(f, cv2.CV_32F, odd, borderType=cv2.BORDER_REFLECT) ** 2, window_px)
                         for f in g])
        top = comp.max(0)
        out += comp / np.maximum(top, max(1e-6 * float(top.max()), NARROWBAND_FLOOR))[None]
    return out


@dataclass(frozen=True)
class FocusMeasure:
    """volume(grey stack (S, H, W), window_px, step, levels) -> (S, H, W) float32 >= 0; tail_exponent: how the
    response falls off with defocus in log, relative to a squared one (the `ratio` estimator's gamma)."""

    volume: Callable
    tail_exponent: float = 1.0


# The focus measures by name. A new measure is one function and one entry; FocusConfig's check, the `ratio`
# estimator's exponent and the benchmarks' comparisons take them from here.
MEASURES: dict[str, FocusMeasure] = {
    "lape": FocusMeasure(_each_frame(lape)),
    "sml": FocusMeasure(_each_frame(sml), tail_exponent=0.5),  # rectified, not squared: falls off half as fast
    "mlap2": FocusMeasure(_each_frame(mlap2)),
    "tenengrad": FocusMeasure(_each_frame(tenengrad)),
    "multiscale": FocusMeasure(multiscale),
    "narrowband": FocusMeasure(narrowband),
}


def focus_volume(stack: np.ndarray, measure: str = "mlap2", window_px: float = 9, step: int = 1,
                 levels: int = 3, prefilter_px: float = 0.0) -> np.ndarray:
    """Focus measure of every frame: stack (S, 3, H, W) or grey (S, H, W) -> (S, H, W) float32 >= 0.

    `levels` is used by `multiscale` only (pyramid levels 0..levels-1)."""
    if measure not in MEASURES:
        raise ValueError(f"unknown focus measure {measure!r} (one of {', '.join(MEASURES)})")
    return MEASURES[measure].volume(prefilter(grey(stack), prefilter_px), window_px, step, levels)
