"""Twins and captures at reduced resolution (a sensor binned b x b), for the diagnosis's search: fitting an
effect's settings and screening effects costs a fraction of full-resolution rendering (4x fewer pixels and about
half the depth layers at b = 2), and only the effects that pass are rendered at full resolution.

- `bin_frames`, `bin_depth`: a capture's frames (box average of linear values, what a binned sensor records) and
  its ground truth (the mean of inverse depth over the block's known pixels) at 1/b resolution;
- `BinnedSource`: a full-sensor PSF source seen by the binned sensor: the same kernels with cells b times smaller
  in pixels; cells that would become smaller than a pixel are resampled onto 1-pixel cells (linear
  interpolation of each cell's position, energy kept);
- `binned_capture`, `TwinRenderer.binned`: a capture and a renderer at 1/b resolution.

Effects follow with `Effect.binned(b)`: noise keeps its statistics after binning (b^2 the full well, b the read
noise), pixel-unit settings scale, and the RAW development, which binning averages away, is left out (an
approximation for the search only; the final scoring is at full resolution). The binned development's noise is
not the binned independent noise (demosaicking correlates it): `noisefloor` carries a developed twin's noise in the
focus sweep by its expectation, scaled for that, where asked (`fitters.NOISE_FLOOR`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from aat_deploy.diagnose.inputs import CaptureData


def bin_frames(a: np.ndarray, b: int) -> np.ndarray:
    """(..., H, W) -> (..., H // b, W // b) block means (trailing rows/columns that do not fill a block dropped)."""
    if b == 1:
        return a
    h, w = a.shape[-2] // b * b, a.shape[-1] // b * b
    x = a[..., :h, :w]
    return x.reshape(*x.shape[:-2], h // b, b, w // b, b).mean((-3, -1), dtype=np.float64).astype(a.dtype)


def bin_depth(depth_m: np.ndarray, b: int) -> np.ndarray:
    """(H, W) metres (NaN or <= 0 = unknown) -> (H // b, W // b): 1 / the mean inverse depth of the block's known
    pixels (the renderer splits light linearly in inverse depth); NaN where the block has none."""
    if b == 1:
        return depth_m
    ok = np.isfinite(depth_m) & (depth_m > 0)
    inv = np.where(ok, 1.0 / np.where(ok, depth_m, 1.0), 0.0)
    s, n = bin_frames(inv, b) * b * b, bin_frames(ok.astype(np.float64), b) * b * b
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0.5, n / s, np.nan).astype(np.float32)


def binned_capture(cap: CaptureData, b: int) -> CaptureData:
    """The capture as a b x b binned sensor would have recorded it (frames, ground truth, all-in-focus)."""
    if b == 1:
        return cap
    aif = None if cap.aif_linear is None else bin_frames(cap.aif_linear, b)
    return dataclasses.replace(cap, frames=bin_frames(cap.frames, b), gt_m=bin_depth(cap.gt_m, b), aif_linear=aif)


def subpixel_matrix(k: int, scale: float) -> np.ndarray:
    """(k, k) matrix taking a k-cell kernel axis with cells of `scale` < 1 pixels to k cells of 1 pixel: each cell's
    energy goes to the two pixel cells around its centre (linear weights), so energy is kept."""
    i = np.arange(k) - k // 2
    j = np.arange(k) - k // 2
    a = np.maximum(1.0 - np.abs(j[:, None] - i[None, :] * scale), 0.0)  # (pixel j, cell i)
    return a / np.maximum(a.sum(0, keepdims=True), 1e-12)


class BinnedSource:
    """A PSF source of the full sensor (`aat_deploy.render.sources` interface) for a sensor binned b x b: kernel
    cells of scale / b pixels, never below 1 (finer cells are resampled onto 1-pixel cells). Works on numpy
    sources; the thin-lens Gaussian is rebuilt for the binned lens instead (it knows its pixels)."""

    def __init__(self, source, b: int):
        self.source, self.b, self.k = source, int(b), source.k
        self.path = getattr(source, "path", None)

    def scale(self, depth_m, focus_m) -> np.ndarray:
        return np.maximum(np.asarray(self.source.scale(depth_m, focus_m), np.float64) / self.b, 1.0)

    def blur_px(self, depth_m, focus_m) -> np.ndarray:
        return np.asarray(self.source.blur_px(depth_m, focus_m), np.float64) / self.b

    def focus_table(self):
        return self.source.focus_table()

    def exit_pupil_z_mm(self):
        return self.source.exit_pupil_z_mm()

    def __call__(self, x, y, depth_m, focus_m):
        kernels, scale = self.source(x, y, depth_m, focus_m)
        kernels = np.asarray(kernels)
        s = np.asarray(scale, np.float64) / self.b
        fine = s < 1.0
        if fine.any():
            kernels = kernels.copy()
            for v in np.unique(s[fine]):
                m = subpixel_matrix(kernels.shape[-1], float(v)).astype(kernels.dtype)
                sel = s == v
                kernels[sel] = m @ kernels[sel] @ m.T
        return kernels, np.maximum(s, 1.0).astype(np.float32)
