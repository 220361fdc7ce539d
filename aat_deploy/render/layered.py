"""The fast layered renderer in numpy: the algorithm of `training.render.layered` (see its docstring), step for
step, so that twins rendered without torch equal the training simulator's frames (float32 rounding apart).

- depth: layers even in diopters with a blur step <= `layer_blur_px`; a pixel's light is split linearly in
  1/depth between its two layers (occlusion mode: the nearest layer, composited front to back);
- field: anchors every `cell_px` pixels; a pixel's light is split among its cell's four corner anchors with
  tent weights, each share spread with that anchor's PSF (true convolution, FFT per cell);
- layers with wide blur render on an m-times coarser grid (box average, kernel resampled, bilinear upsampling);
- light from beyond the frame comes in from an edge-replicated border.

The configuration (`LayeredConfig`), the layer placement and the kernel resampling helpers are defined here once
and imported by the torch renderer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["LayeredConfig", "cells_to_pixels", "fast_len", "layer_diopters", "pixel_kernel_size", "render_layered"]


@dataclass(frozen=True)
class LayeredConfig:
    """cell_px: anchor spacing (full-resolution pixels). layer_blur_px: blur-diameter step between depth layers.
    coarse_ratio: layers with PSF cell size s render at 1/floor(s / coarse_ratio) resolution.
    occlusion: hard layer assignment composited front to back (near layers hide what lies behind them)."""

    cell_px: int = 64
    layer_blur_px: float = 1.0
    max_layers: int = 128
    coarse_ratio: float = 2.0
    occlusion: bool = False

    def __post_init__(self):
        if self.cell_px < 4 or self.layer_blur_px <= 0 or self.max_layers < 1 or self.coarse_ratio < 1:
            raise ValueError(f"invalid LayeredConfig {self}")


def layer_diopters(inv_depth, blur_px_fn, focus_m: float, cfg: LayeredConfig) -> np.ndarray:
    """Layer positions (1/m), ascending, spanning the image's inverse depths with a blur step <= layer_blur_px.

    inv_depth: array (numpy or torch) of 1/depth (1/m). blur_px_fn(depth_m ndarray, focus_m) -> thin-lens blur
    diameter in pixels (for spacing only)."""
    lo, hi = float(inv_depth.min()), float(inv_depth.max())
    if hi - lo < 1e-9:
        return np.array([lo])
    probe = np.linspace(lo, hi, 65)
    blur = np.asarray(blur_px_fn(1.0 / probe, focus_m), dtype=np.float64)
    # Signed blur (negative in front of focus) so that the step counts blur *change* through the focal plane.
    signed = np.where(probe > 1.0 / focus_m, -blur, blur)
    travel = float(np.abs(np.diff(signed)).sum())
    n = int(np.clip(math.ceil(travel / cfg.layer_blur_px) + 1, 2, cfg.max_layers))
    return np.linspace(lo, hi, n)


def fast_len(n: int) -> int:
    """Smallest m >= n whose prime factors are 2, 3 and 5 (fast FFT sizes)."""
    m = n
    while True:
        k = m
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 1


def pixel_kernel_size(k: int, scale: float) -> int:
    """Odd pixel size that holds a k-cell kernel with cells of `scale` pixels (tent support included)."""
    half = math.ceil((k // 2 + 1) * scale - 1e-9)
    return 2 * half + 1


def cells_to_pixels(kernels: np.ndarray, scale: np.ndarray, size: int) -> np.ndarray:
    """Resample (N, k, k) cell kernels with cell size `scale` (N,) pixels to (N, size, size) pixel kernels: each
    cell's energy spread with the tent of half-width `scale` around its centre, renormalised per cell (energy is
    conserved; scale = 1 returns the kernel centred in the larger window). numpy twin of
    `training.render.exact.cells_to_pixels`."""
    n, k, _ = kernels.shape
    dt = kernels.dtype
    j = np.arange(size, dtype=dt) - size // 2  # pixel offsets
    i = np.arange(k, dtype=dt) - k // 2  # cell offsets
    s = np.asarray(scale, dtype=dt).reshape(n, 1, 1)
    a = np.maximum(1 - np.abs(j.reshape(1, -1, 1) - i.reshape(1, 1, -1) * s) / s, 0)  # (N, size, k)
    a = a / np.maximum(a.sum(1, keepdims=True), 1e-12)
    return a @ kernels @ a.transpose(0, 2, 1)


def _tent_weights(n: int, dtype) -> np.ndarray:
    """(2, n): weights of a cell's low and high anchors at its n pixel centres."""
    t = (np.arange(n, dtype=dtype) + 0.5) / n
    return np.stack([1 - t, t])


def _upsample(img: np.ndarray, m: int) -> np.ndarray:
    """(C, h, w) -> (C, h m, w m) bilinear, pixel centres aligned (torch's interpolate with align_corners=False:
    source coordinate (i + 0.5) / m - 0.5, clamped at 0, the last pixel repeated)."""

    def axis(n: int):
        src = np.maximum((np.arange(n * m) + 0.5) / m - 0.5, 0.0)
        i0 = np.floor(src).astype(np.intp)
        i1 = np.minimum(i0 + 1, n - 1)
        w1 = (src - i0).astype(img.dtype)
        return i0, i1, w1

    r0, r1, wr = axis(img.shape[1])
    img = img[:, r0] * (1 - wr)[:, None] + img[:, r1] * wr[:, None]
    c0, c1, wc = axis(img.shape[2])
    return img[:, :, c0] * (1 - wc) + img[:, :, c1] * wc


def _render_layer(img: np.ndarray, w: np.ndarray, m: int, anchors_field_fn, kernel_fn, cfg: LayeredConfig,
                  extra_channels: np.ndarray | None = None) -> np.ndarray:
    """Spread img * w (C, H, W) with the anchor PSFs of one layer; returns (C, H, W) (+ extra channels).

    m: integer downsampling factor. anchors_field_fn(rows_px, cols_px) -> field (x, y) arrays of anchor points
    given in padded full-resolution pixel coordinates. kernel_fn(x, y) -> (kernels (N, Ck, k, k) or (N, k, k),
    scale (N,)).
    """
    c, h, wd = img.shape
    dt = img.dtype
    src = img * w
    if extra_channels is not None:  # occlusion coverage, blurred with the channel-mean kernel
        src = np.concatenate([src, extra_channels * w], 0)
    ctot = src.shape[0]
    hc, wc = math.ceil(h / m), math.ceil(wd / m)
    if m > 1:
        src = np.pad(src, ((0, 0), (0, hc * m - h), (0, wc * m - wd)))
        src = src.reshape(ctot, hc, m, wc, m).mean((2, 4), dtype=dt)
        cover = np.pad(w, ((0, hc * m - h), (0, wc * m - wd))).reshape(hc, m, wc, m).max((1, 3))
    else:
        cover = w
    cc = max(4, round(cfg.cell_px / m))
    ny, nx = math.ceil(hc / cc), math.ceil(wc / cc)  # cells
    src = np.pad(src, ((0, 0), (0, ny * cc - hc), (0, nx * cc - wc)))
    cover = np.pad(cover, ((0, ny * cc - hc), (0, nx * cc - wc)))
    cells = src.reshape(ctot, ny, cc, nx, cc).transpose(1, 3, 0, 2, 4)  # (ny, nx, C, cc, cc)
    idx = np.argwhere(cover.reshape(ny, cc, nx, cc).max((1, 3)) > 0)  # (Na, 2) = active cells' row, col
    if len(idx) == 0:
        return np.zeros((ctot, h, wd), dtype=dt)
    # Corner anchors of the active cells, each queried once.
    corners = idx[:, None, :] + np.array([(0, 0), (0, 1), (1, 0), (1, 1)])[None]  # (Na, 4, 2)
    flat = corners[..., 0] * (nx + 1) + corners[..., 1]
    uniq, inv = np.unique(flat.reshape(-1), return_inverse=True)
    ar, ac = (uniq // (nx + 1)).astype(np.float64), (uniq % (nx + 1)).astype(np.float64)
    fx, fy = anchors_field_fn(ar * cc * m, ac * cc * m)
    kernels, scale = kernel_fn(fx, fy)
    kernels = np.asarray(kernels)
    if kernels.ndim == 3:
        kernels = kernels[:, None]  # (U, Ck, k, k)
    s = float(np.asarray(scale).reshape(-1)[0])  # one depth and focus per layer: one cell size
    size = pixel_kernel_size(kernels.shape[-1], s / m)
    u, ck, k, _ = kernels.shape
    px = cells_to_pixels(kernels.reshape(u * ck, k, k).astype(dt), np.full(u * ck, s / m, dtype=dt),
                         size).reshape(u, ck, size, size)
    if ck == 1:
        px = np.broadcast_to(px, (u, c, size, size))
    if extra_channels is not None:
        px = np.concatenate([px, px.mean(1, keepdims=True, dtype=dt)], 1)
    r = size // 2
    na = len(idx)
    # Full linear convolution of each cell (cc x cc) with its corner kernels by FFT: output block cc + 2r,
    # block index i + j for source pixel i and kernel tap j (tap r = no offset). The four corners' shares are
    # summed in the frequency domain, so there is one inverse transform per cell and channel.
    n_fft = fast_len(cc + 2 * r)
    t = _tent_weights(cc, dt)
    wgt = np.stack([t[a][:, None] * t[b][None, :] for a in (0, 1) for b in (0, 1)])  # (4, cc, cc)
    x = cells[idx[:, 0], idx[:, 1]][:, None] * wgt[None, :, None]  # (Na, 4, C, cc, cc)
    xf = np.fft.rfft2(x, s=(n_fft, n_fft))
    kf = np.fft.rfft2(px, s=(n_fft, n_fft))  # (U, C, n, n/2+1)
    yf = (xf * kf[inv].reshape(na, 4, ctot, n_fft, -1)).sum(1)
    y = np.fft.irfft2(yf, s=(n_fft, n_fft))[..., :cc + 2 * r, :cc + 2 * r].astype(dt, copy=False)
    # Overlap-add the cells' spread light (blocks of cc + 2r laid out with stride cc).
    canvas = np.zeros((ctot, ny * cc + 2 * r, nx * cc + 2 * r), dtype=dt)
    for (cy, cx), blk in zip(idx.tolist(), y):
        canvas[:, cy * cc:cy * cc + cc + 2 * r, cx * cc:cx * cc + cc + 2 * r] += blk
    out = canvas[:, r:r + hc, r:r + wc]
    if m > 1:
        out = _upsample(out, m)
    return out[:, :h, :wd]


def render_layered(image: np.ndarray, depth_m: np.ndarray, focus_m: float, source, field_fn,
                   cfg: LayeredConfig = LayeredConfig(), focus_at=None) -> np.ndarray:
    """One focal-stack frame. image (C, H, W) linear (float32 or float64); depth_m (H, W) metres from the sensor,
    all > 0.

    source: a PSF source (`aat_deploy.render.sources`): source(x, y, depth_m, focus_m) -> (kernels (N, k, k) or
        (N, Ck, k, k) with Ck = C, scale (N,)) as numpy, in the storage of `aat_deploy.psf.kernel`; source.k;
        source.scale(depth_m, focus_m) and source.blur_px(depth_m, focus_m) (pixels).
    field_fn(rows, cols) -> normalised field (x, y) of points given in this image's pixel coordinates
        (row, col; pixel centres at +0.5), accounting for the crop's place on the sensor.
    focus_at(x, y, focus_m) -> per-anchor focus distances (m), for effects that make focus vary over the field
        (sensor tilt); default: focus_m everywhere.
    Returns (C, H, W) in the image's dtype.
    """
    image, depth_m = np.asarray(image), np.asarray(depth_m)
    if image.ndim != 3 or depth_m.shape != image.shape[1:]:
        raise ValueError(f"image must be (C, H, W) and depth (H, W); got {image.shape}, {depth_m.shape}")
    if not np.isfinite(depth_m).all() or float(depth_m.min()) <= 0:
        raise ValueError("depth_m must be finite and > 0 everywhere (fill unknown depth before rendering)")
    c, h, w = image.shape
    dt = image.dtype.type
    inv = dt(1.0) / depth_m.astype(dt)
    layers = layer_diopters(inv, source.blur_px, focus_m, cfg)
    n = len(layers)
    scales = np.asarray(source.scale(1.0 / layers, np.full(n, focus_m)), dtype=np.float64).reshape(n)
    # Border: edge-replicate enough that the widest PSF present sees the scene beyond the frame.
    pad = max(pixel_kernel_size(source.k, float(s)) // 2 for s in scales) + 1
    img = np.pad(image, ((0, 0), (pad, pad), (pad, pad)), mode="edge")
    invp = np.pad(inv, pad, mode="edge")
    if n == 1:
        weights = [np.ones_like(invp)]
    else:
        t = (invp - dt(layers[0])) / dt(layers[1] - layers[0])
        if cfg.occlusion:
            near = np.clip(np.round(t), 0, n - 1)
            weights = [(near == i).astype(dt) for i in range(n)]
        else:
            weights = [np.maximum(1 - np.abs(t - dt(i)), dt(0)) for i in range(n)]

    def anchors_field(rows, cols):
        return field_fn(np.asarray(rows) - pad, np.asarray(cols) - pad)

    out = np.zeros_like(img)
    transmit = np.ones_like(img[:1])
    for i in range(n - 1, -1, -1):  # near (largest 1/d) first
        wi = weights[i]
        if not (wi > 0).any():
            continue
        m = max(1, int(scales[i] // cfg.coarse_ratio))
        d_i = 1.0 / float(layers[i])

        def kfn(x, y, d_i=d_i):
            f = np.full(len(x), focus_m) if focus_at is None else focus_at(x, y, focus_m)
            return source(x, y, np.full(len(x), d_i), f)

        if cfg.occlusion:
            o = _render_layer(img, wi, m, anchors_field, kfn, cfg, extra_channels=np.ones_like(img[:1]))
            out += transmit * o[:c]
            transmit = transmit * (1 - np.clip(o[c:], 0, 1))
        else:
            out += _render_layer(img, wi, m, anchors_field, kfn, cfg)
    return out[:, pad:pad + h, pad:pad + w]
