"""How close a digital twin comes to the real capture: in the images themselves and in the model's errors.

Image statistics are taken on normalised stacks (what the model sees):
- focus-measure curves: per region of a grid, per frame and per colour channel, the log of the mean squared
  Laplacian (9x9 local energy). Defocus, field curvature, tilt, focus-metadata errors and colour-dependent focus
  move these curves along the stack; noise raises their floor; vignetting lowers them towards the corners.
- geometry: per region and frame, the sub-pixel shift between the capture and the twin (phase correlation);
  focus breathing makes it grow with field radius and with the frame's focus distance.
- brightness: per region and frame, the log ratio of mean luminance, capture over twin, less its median (the
  stacks' exposures are normalised anyway): vignetting shows here even where noise hides it in the focus curves.
Model error pattern: the mean absolute depth error per bin (field radius x depth) on the capture vs on the twin."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from aat_deploy.diagnose.bins import MAP_GRID


@dataclass
class Distances:
    """Per-capture distances between a capture and a twin (smaller = closer)."""

    focus_curves: float  # mean |log FM difference|, natural-log units
    geometry_px: float  # median shift magnitude over regions and frames, pixels
    error_pattern_m: float  # pixel-weighted mean |binned MAE difference|, metres
    brightness: float = 0.0  # mean |log luminance ratio - its median| over regions and frames, natural-log units


def region_index(h: int, w: int, grid: tuple[int, int] = MAP_GRID) -> np.ndarray:
    rows, cols = grid
    return (np.minimum((np.arange(h) * rows) // h, rows - 1)[:, None] * cols
            + np.minimum((np.arange(w) * cols) // w, cols - 1)[None, :])


def focus_curves(stack: np.ndarray, grid: tuple[int, int] = MAP_GRID) -> np.ndarray:
    """stack (S, C, H, W) normalised -> (R, S, C) log region-mean focus measure."""
    s, c, h, w = stack.shape
    reg = region_index(h, w, grid).ravel()
    n_r = grid[0] * grid[1]
    out = np.empty((n_r, s, c))
    for i in range(s):
        for j in range(c):
            lap = cv2.Laplacian(np.ascontiguousarray(stack[i, j], np.float32), cv2.CV_32F, ksize=3)
            fm = cv2.blur(lap * lap, (9, 9)).ravel()
            out[:, i, j] = np.bincount(reg, weights=fm, minlength=n_r) / np.bincount(reg, minlength=n_r)
    return np.log(out + 1e-8)


def region_brightness(stack: np.ndarray, grid: tuple[int, int] = MAP_GRID) -> np.ndarray:
    """stack (S, C, H, W) -> (R, S) log region-mean luminance (channel mean)."""
    s, _, h, w = stack.shape
    reg = region_index(h, w, grid).ravel()
    n_r = grid[0] * grid[1]
    count = np.bincount(reg, minlength=n_r)
    lum = stack.mean(1).reshape(s, -1)
    return np.log(np.stack([np.bincount(reg, weights=lum[i], minlength=n_r) / count for i in range(s)], 1) + 1e-8)


def brightness_distance(a: np.ndarray, b: np.ndarray, grid: tuple[int, int] = MAP_GRID) -> float:
    """Mean |log(region luminance of a / of b) - median| over regions and frames: how differently two stacks are
    lit across the field (a global exposure difference counts nothing)."""
    d = region_brightness(a, grid) - region_brightness(b, grid)
    return float(np.mean(np.abs(d - np.median(d))))


def region_shifts(a: np.ndarray, b: np.ndarray, grid: tuple[int, int] = MAP_GRID) -> np.ndarray:
    """Shift (px) of stack b against stack a per region and frame: (R, S, 2) as (dx, dy)."""
    s, _, h, w = a.shape
    rows, cols = grid
    out = np.zeros((rows * cols, s, 2))
    win = None
    for i in range(s):
        # smoothed luminance: phase correlation whitens the spectrum, so noise would otherwise dominate
        la = cv2.GaussianBlur(a[i].mean(0).astype(np.float32), (0, 0), 1.5)
        lb = cv2.GaussianBlur(b[i].mean(0).astype(np.float32), (0, 0), 1.5)
        for r in range(rows):
            for q in range(cols):
                y0, y1 = r * h // rows, (r + 1) * h // rows
                x0, x1 = q * w // cols, (q + 1) * w // cols
                pa, pb = la[y0:y1, x0:x1], lb[y0:y1, x0:x1]
                if win is None or win.shape != pa.shape:
                    win = cv2.createHanningWindow((pa.shape[1], pa.shape[0]), cv2.CV_32F)
                (dx, dy), _ = cv2.phaseCorrelate(np.ascontiguousarray(pa), np.ascontiguousarray(pb), win)
                out[r * cols + q, i] = (dx, dy)
    return out


def error_pattern(err_m: np.ndarray, index: np.ndarray, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean error and pixel count per bin; err_m (H, W) NaN = no ground truth, index (H, W) -1 = skip."""
    ok = (index >= 0) & np.isfinite(err_m)
    k = np.bincount(index[ok], minlength=n_bins)
    s = np.bincount(index[ok], weights=err_m[ok], minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        return s / k, k


def image_distances(real_stack: np.ndarray, real_curves: np.ndarray, twin_stack: np.ndarray) -> Distances:
    """The image part of `distances` (error_pattern_m = 0): for the search at reduced resolution, where the model
    is not run."""
    d_fm = float(np.mean(np.abs(real_curves - focus_curves(twin_stack))))
    shifts = region_shifts(real_stack, twin_stack)
    d_geo = float(np.median(np.hypot(shifts[..., 0], shifts[..., 1])))  # median: robust to flat regions
    return Distances(d_fm, d_geo, 0.0, brightness_distance(real_stack, twin_stack))


def distances(real_stack: np.ndarray, real_curves: np.ndarray, twin_stack: np.ndarray, real_err: np.ndarray,
              twin_err: np.ndarray, pattern_index: np.ndarray, n_pattern: int) -> Distances:
    """real_stack/twin_stack (S, C, H, W) normalised; real_curves = focus_curves(real_stack) (cached);
    real_err/twin_err (H, W) absolute depth error (m), NaN = unknown; pattern_index (H, W) bins."""
    img = image_distances(real_stack, real_curves, twin_stack)
    mr, k = error_pattern(real_err, pattern_index, n_pattern)
    mt, _ = error_pattern(twin_err, pattern_index, n_pattern)
    ok = k > 0
    img.error_pattern_m = float(np.sum(k[ok] * np.abs(mr[ok] - mt[ok])) / max(k[ok].sum(), 1))
    return img
