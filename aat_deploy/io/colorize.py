"""Colour previews of depth and uncertainty maps for people (a 16-bit PNG in mm looks black in any viewer).

Each preview is the map in a colour scale with a labelled colour bar on its right (the range in metres written
beside the map), as 8-bit RGB. Depth uses an inverse-depth (diopter) scale, so equal colour steps are equal steps
of defocus, near at the low end of the colour map as in the rerun recording; uncertainty a linear scale from 0.
Unknown pixels (NaN, inf, <= 0 depth) are grey. `colorize` is the same colour mapping without a bar, on a linear
scale (aat-eval's error maps); every colour picture of a map in aat_deploy is made here.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

DEPTH_COLORMAP = "turbo"        # names shared with rerun's colormaps (aat_deploy.infer.recording)
UNCERTAINTY_COLORMAP = "inferno"
_CV2_MAPS = {"turbo": cv2.COLORMAP_TURBO, "inferno": cv2.COLORMAP_INFERNO, "viridis": cv2.COLORMAP_VIRIDIS}
UNKNOWN_RGB = (128, 128, 128)
TICKS = 5


@dataclass(frozen=True)
class ColorScale:
    """How values became colours: the colour map, the value range (metres) and the scale ("inverse" or "linear")."""

    colormap: str
    lo_m: float
    hi_m: float
    scale: str

    def as_json(self) -> dict:
        return {"colormap": self.colormap, "range_m": [self.lo_m, self.hi_m], "scale": self.scale}


def depth_range(depth_m: np.ndarray, lo_pct: float = 0.5, hi_pct: float = 99.5) -> tuple[float, float]:
    """Robust (near, far) metres of the known pixels: percentiles of inverse depth, so a few stray pixels do not
    squeeze the scale. (1, 2) if no pixel is known; widened by 1 % if near == far."""
    d = depth_m[np.isfinite(depth_m) & (depth_m > 0)]
    if d.size == 0:
        return 1.0, 2.0
    inv = 1.0 / d.astype(np.float64)
    far, near = 1.0 / np.percentile(inv, lo_pct), 1.0 / np.percentile(inv, hi_pct)
    if not far > near:
        near, far = near * 0.99, far * 1.01
    return float(near), float(far)


def uncertainty_range(std_m: np.ndarray, hi_pct: float = 99.0) -> tuple[float, float]:
    """(0, the hi_pct percentile) metres of the finite values; (0, 1e-3) if none is above 0."""
    s = std_m[np.isfinite(std_m)]
    hi = float(np.percentile(s, hi_pct)) if s.size else 0.0
    return 0.0, hi if hi > 0 else 1e-3


def _apply(t: np.ndarray, known: np.ndarray, colormap: str) -> np.ndarray:
    """t (H, W) in [0, 1] -> RGB uint8 through the colour map; unknown pixels grey."""
    idx = np.rint(np.clip(np.nan_to_num(t), 0.0, 1.0) * 255).astype(np.uint8)
    rgb = cv2.applyColorMap(idx, _CV2_MAPS[colormap])[..., ::-1].copy()
    rgb[~known] = UNKNOWN_RGB
    return rgb


def _with_bar(img: np.ndarray, colormap: str, labels: list[tuple[float, str]], title: str) -> np.ndarray:
    """img (H, W, 3) with a vertical colour bar and labels on the right; labels are (t in [0, 1], text), t = 1 at
    the top."""
    h, w = img.shape[:2]
    font = cv2.FONT_HERSHEY_SIMPLEX
    fs = float(np.clip(h / 700.0, 0.3, 1.2))
    th = max(1, round(fs * 1.5))
    tw = max(cv2.getTextSize(s, font, fs, th)[0][0] for _, s in labels + [(0.0, title)])
    text_h = cv2.getTextSize("0", font, fs, th)[0][1]
    bar_w, gap = max(8, w // 40), max(4, w // 100)
    roomy = h >= 8 * text_h  # else no title, and the bar spans the whole height
    top, bottom = (3 * text_h, h - text_h - max(2, text_h // 2)) if roomy else (0, h)
    panel = np.full((h, bar_w + 3 * gap + tw, 3), 255, np.uint8)
    n = max(1, min(bottom - top, h - top))
    t = np.linspace(1.0, 0.0, n)[:, None].repeat(bar_w, 1)
    panel[top:top + n, gap:gap + bar_w] = _apply(t, np.ones_like(t, bool), colormap)
    ink = (0, 0, 0)
    for tv, s in labels:
        y = top + round((1.0 - tv) * (n - 1))
        cv2.line(panel, (gap + bar_w, y), (2 * gap + bar_w - 1, y), ink, 1)
        cv2.putText(panel, s, (2 * gap + bar_w, min(h - 1, y + text_h // 2)), font, fs, ink, th, cv2.LINE_AA)
    if roomy:
        cv2.putText(panel, title, (gap, max(text_h + 2, top - text_h)), font, fs, ink, th, cv2.LINE_AA)
    return np.concatenate([img, panel], 1)


def colorize(x: np.ndarray, lo: float, hi: float, colormap: str = DEPTH_COLORMAP) -> np.ndarray:
    """(H, W) values -> (H, W, 3) uint8 RGB on a linear scale lo..hi (the colour map's ends, values outside
    clipped), no bar; non-finite values grey. For maps that are not depth (errors, aat-eval's panels)."""
    known = np.isfinite(x)
    return _apply((np.where(known, x, lo) - lo) / max(hi - lo, 1e-12), known, colormap)


def depth_preview(depth_m: np.ndarray, near_m: float, far_m: float, colormap: str = DEPTH_COLORMAP,
                  unit: str = "m") -> tuple[np.ndarray, ColorScale]:
    """RGB uint8 (H, W + bar, 3): depth (H, W) metres on an inverse-depth scale from near_m (low end of the colour
    map) to far_m (high end), values outside clipped, with the bar labelled in metres (or `unit`, for a stack whose
    focus distances are in other units)."""
    known = np.isfinite(depth_m) & (depth_m > 0)
    inv_n, inv_f = 1.0 / near_m, 1.0 / far_m
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (inv_n - 1.0 / depth_m.astype(np.float64)) / (inv_n - inv_f)
    img = _apply(t, known, colormap)
    tv = np.linspace(0.0, 1.0, TICKS)
    labels = [(float(x), f"{1.0 / (inv_n - x * (inv_n - inv_f)):.3g} {unit}") for x in tv]
    return _with_bar(img, colormap, labels, "depth"), ColorScale(colormap, float(near_m), float(far_m), "inverse")


def uncertainty_preview(std_m: np.ndarray, hi_m: float, colormap: str = UNCERTAINTY_COLORMAP
                        ) -> tuple[np.ndarray, ColorScale]:
    """RGB uint8 (H, W + bar, 3): uncertainty (H, W) metres on a linear scale 0..hi_m, with the bar in metres."""
    img = linear_preview(std_m, 0.0, hi_m, "std", " m", colormap)
    return img, ColorScale(colormap, 0.0, float(hi_m), "linear")


def linear_preview(values: np.ndarray, lo: float, hi: float, title: str, unit: str = "",
                   colormap: str = UNCERTAINTY_COLORMAP) -> np.ndarray:
    """RGB uint8 (H, W + bar, 3): values (H, W) on a linear scale lo (low end of the colour map) .. hi, values
    outside clipped, NaN grey, with the bar labelled "<value><unit>" (a confidence, a frame index, a disparity)."""
    img = colorize(values.astype(np.float64), lo, hi, colormap)
    labels = [(float(x), f"{lo + x * (hi - lo):.3g}{unit}") for x in np.linspace(0.0, 1.0, TICKS)]
    return _with_bar(img, colormap, labels, title)
