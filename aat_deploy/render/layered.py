"""The fast renderer: depth layers x field cells, each a small batched convolution, over numpy or torch arrays.

The exact renderer (`training.render.exact`) spreads every pixel with its own PSF. Here the PSF is made piecewise
smooth:

- depth: layers evenly spaced in diopters, close enough that the thin-lens blur changes by `layer_blur_px`
  between neighbours; a pixel's light is split between its two neighbouring layers linearly in 1/depth
  (occlusion mode: the nearest layer only, composited front to back, so that layers occlude one another);
- field: anchors on a regular grid of `cell_px` cells; inside a cell a pixel's light is split among the cell's
  four corner anchors with bilinear (tent) weights and each share is spread with that anchor's PSF.

So every source pixel is spread with a bilinear blend of anchor PSFs at a blend of layer depths: still a true
convolution (the emitter's PSF, by FFT per cell; no correlation), and energy is conserved because the weights
sum to one. Light from just outside the frame comes in from an edge-replicated border.

Layers whose blur is large are rendered on a coarser grid: the layer image is box-averaged by an integer m, the
kernel resampled to m-pixel cells and the result upsampled bilinearly (m = floor(scale / coarse_ratio), so the
extra blur this adds is a small fraction of the layer's own blur). Cost per layer is then about the same for
all layers, and only cells a layer actually touches are convolved.

One algorithm, two array backends: the operations numpy and torch spell differently (padding, pooling, unique,
the kernel resampling product, overlap-add, upsampling) are the methods of a `LayeredBackend`; `NUMPY` is here,
the torch one (`training.render.layered.TORCH`) registers itself when the training package is imported, so this
module never imports torch. Each backend keeps its own library's arithmetic: the torch simulator's training
stacks and the torch-free twins are what they were before the two renderers became one (they agree with each
other to float32 rounding: tests/deploy/diagnose/test_twin.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType

import numpy as np
import scipy.fft

from aat_deploy.backend import is_torch

__all__ = ["LayeredBackend", "LayeredConfig", "NUMPY", "backend_of", "cells_to_pixels", "fast_len", "layer_diopters",
           "pixel_kernel_size", "register_backend", "render_layered"]


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


class LayeredBackend:
    """The array operations of the layered renderer, numpy's spelling (the torch backend overrides them). `xp` is
    the namespace for what both libraries spell alike (arange, stack, clip, abs, round, zeros, ...); `fft` the FFT
    module (rfft2, irfft2)."""

    xp: ModuleType = np
    # numpy arrays' FFTs: scipy's pocketfft, which vectorises the batch of small blocks (a 960 x 640 stack renders
    # 1.4 x faster than with numpy.fft; the two agree to float32 rounding: tests/deploy/render/test_layered_fft.py)
    fft: ModuleType = scipy.fft

    def asarray(self, x):
        return np.asarray(x)

    def astype(self, x, dtype):
        return x.astype(dtype, copy=False)

    def to_numpy(self, x) -> np.ndarray:
        return np.asarray(x)

    def concat(self, arrays, axis: int):
        return np.concatenate(arrays, axis)

    def permute(self, x, axes):
        return x.transpose(axes)

    def broadcast_to(self, x, shape):
        return np.broadcast_to(x, shape)

    def sum_keep(self, x, axis: int):
        return x.sum(axis, keepdims=True)

    def mean_keep(self, x, axis: int):
        return x.mean(axis, keepdims=True, dtype=x.dtype)

    def pad_end(self, x, rows: int, cols: int):
        """Zeros after the last row and column of (..., H, W)."""
        return np.pad(x, ((0, 0),) * (x.ndim - 2) + ((0, rows), (0, cols)))

    def pad_edge(self, x, pad: int):
        """(..., H, W) with `pad` edge-replicated pixels on every side."""
        return np.pad(x, ((0, 0),) * (x.ndim - 2) + ((pad, pad), (pad, pad)), mode="edge")

    def box_mean(self, x, m: int):
        """(C, H, W) -> (C, H / m, W / m) block means."""
        c, h, w = x.shape
        return x.reshape(c, h // m, m, w // m, m).mean((2, 4), dtype=x.dtype)

    def box_max(self, x, m: int):
        """(H, W) -> (H / m, W / m) block maxima."""
        h, w = x.shape
        return x.reshape(h // m, m, w // m, m).max((1, 3))

    def nonzero(self, mask):
        """(N, ndim) indices of the true entries, in row-major order."""
        return np.argwhere(mask)

    def unique_inverse(self, x):
        return np.unique(x, return_inverse=True)

    def sandwich(self, a, kernels):
        """a @ kernels @ a^T per batch item: (N, P, K) x (N, K, K) -> (N, P, P)."""
        return a @ kernels @ a.transpose(0, 2, 1)

    def overlap_add(self, blocks, idx, ny: int, nx: int, cc: int, r: int):
        """Sum (Na, C, cc + 2r, cc + 2r) blocks laid out with stride cc at cells idx (Na, 2) into one canvas."""
        canvas = self.xp.zeros((blocks.shape[1], ny * cc + 2 * r, nx * cc + 2 * r), dtype=blocks.dtype)
        for (cy, cx), blk in zip(idx.tolist(), blocks):
            canvas[:, cy * cc:cy * cc + cc + 2 * r, cx * cc:cx * cc + cc + 2 * r] += blk
        return canvas

    def upsample(self, img, m: int):
        """(C, h, w) -> (C, h m, w m) bilinear, pixel centres aligned (torch's interpolate with
        align_corners=False: source coordinate (i + 0.5) / m - 0.5, clamped at 0, the last pixel repeated)."""

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


NUMPY = LayeredBackend()
_BACKENDS: dict[str, LayeredBackend] = {"numpy": NUMPY}


def register_backend(name: str, backend: LayeredBackend) -> None:
    """Make `backend` the one for arrays of library `name` (the training package registers torch's)."""
    _BACKENDS[name] = backend


def backend_of(x) -> LayeredBackend:
    """The backend for array x: numpy's, or torch's when x is a torch tensor (registered by the training package)."""
    if not is_torch(x):
        return NUMPY
    if "torch" not in _BACKENDS:
        raise RuntimeError("torch arrays need the torch backend of the layered renderer: import "
                           "training.render.layered first")
    return _BACKENDS["torch"]


def cells_to_pixels(kernels, scale, size: int, backend: LayeredBackend | None = None):
    """Resample (N, k, k) cell kernels with cell size `scale` (N,) pixels to (N, size, size) pixel kernels.

    Each cell's energy is spread over pixels with the tent of half-width `scale` around the cell centre (the
    inverse of the bilinear splat that made it) and renormalised per cell, so energy is conserved exactly and
    scale = 1 returns the kernel unchanged (centred in the larger window). numpy or torch arrays."""
    be = backend or backend_of(kernels)
    xp = be.xp
    n, k, _ = kernels.shape
    dt = kernels.dtype
    j = xp.arange(size, dtype=dt) - size // 2  # pixel offsets
    i = xp.arange(k, dtype=dt) - k // 2  # cell offsets
    s = be.astype(be.asarray(scale), dt).reshape(n, 1, 1)
    a = xp.clip(1 - xp.abs(j.reshape(1, -1, 1) - i.reshape(1, 1, -1) * s) / s, 0, None)  # (N, size, k)
    a = a / xp.clip(be.sum_keep(a, 1), 1e-12, None)
    return be.sandwich(a, kernels)


def _tent_weights(xp, n: int, dtype):
    """(2, n): weights of a cell's low and high anchors at its n pixel centres."""
    t = (xp.arange(n, dtype=dtype) + 0.5) / n
    return xp.stack([1 - t, t])


_CORNERS = np.array([(0, 0), (0, 1), (1, 0), (1, 1)])


def _render_layer(be: LayeredBackend, img, w, m: int, anchors_field_fn, kernel_fn, cfg: LayeredConfig,
                  extra_channels=None):
    """Spread img * w (C, H, W) with the anchor PSFs of one layer; returns (C, H, W) (+ extra channels).

    m: integer downsampling factor. anchors_field_fn(rows_px, cols_px) -> field (x, y) arrays of anchor points
    given in padded full-resolution pixel coordinates. kernel_fn(x, y) -> (kernels (N, Ck, k, k) or (N, k, k),
    scale (N,)).
    """
    xp = be.xp
    c, h, wd = img.shape
    dt = img.dtype
    src = img * w
    if extra_channels is not None:  # occlusion coverage, blurred with the channel-mean kernel
        src = be.concat([src, extra_channels * w], 0)
    ctot = src.shape[0]
    hc, wc = math.ceil(h / m), math.ceil(wd / m)
    if m > 1:
        src = be.box_mean(be.pad_end(src, hc * m - h, wc * m - wd), m)
        cover = be.box_max(be.pad_end(w, hc * m - h, wc * m - wd), m)
    else:
        cover = w
    cc = max(4, round(cfg.cell_px / m))
    ny, nx = math.ceil(hc / cc), math.ceil(wc / cc)  # cells
    src = be.pad_end(src, ny * cc - hc, nx * cc - wc)
    cover = be.pad_end(cover, ny * cc - hc, nx * cc - wc)
    cells = be.permute(src.reshape(ctot, ny, cc, nx, cc), (1, 3, 0, 2, 4))  # (ny, nx, C, cc, cc)
    idx = be.nonzero(be.box_max(cover, cc) > 0)  # (Na, 2) = active cells' row, col
    if len(idx) == 0:
        return xp.zeros((ctot, h, wd), dtype=dt)
    # Corner anchors of the active cells, each queried once.
    corners = idx[:, None, :] + be.asarray(_CORNERS)[None]  # (Na, 4, 2)
    flat = corners[..., 0] * (nx + 1) + corners[..., 1]
    uniq, inv = be.unique_inverse(flat.reshape(-1))
    u_np = be.to_numpy(uniq)
    ar, ac = (u_np // (nx + 1)).astype(np.float64), (u_np % (nx + 1)).astype(np.float64)
    fx, fy = anchors_field_fn(ar * cc * m, ac * cc * m)
    kernels, scale = kernel_fn(fx, fy)
    kernels = be.asarray(kernels)
    if kernels.ndim == 3:
        kernels = kernels[:, None]  # (U, Ck, k, k)
    u, ck, k, _ = kernels.shape
    # each anchor's own cell size: one depth per layer, but the focus varies over the field with a tilted sensor
    # or a decentred element (focus_at), and so does the cell size (the first anchor's for all of them drew the
    # other anchors' PSFs too wide or too narrow)
    sc = be.astype(be.asarray(scale), dt).reshape(u, 1) / m
    size = pixel_kernel_size(k, float(sc.max()))
    px = cells_to_pixels(be.astype(kernels.reshape(u * ck, k, k), dt), be.broadcast_to(sc, (u, ck)).reshape(-1),
                         size, be).reshape(u, ck, size, size)
    if ck == 1:
        px = be.broadcast_to(px, (u, c, size, size))
    if extra_channels is not None:
        px = be.concat([px, be.mean_keep(px, 1)], 1)
    r = size // 2
    na = len(idx)
    # Full linear convolution of each cell (cc x cc) with its corner kernels by FFT: output block cc + 2r,
    # block index i + j for source pixel i and kernel tap j (tap r = no offset). The four corners' shares are
    # summed in the frequency domain, so there is one inverse transform per cell and channel.
    n_fft = fast_len(cc + 2 * r)
    t = _tent_weights(xp, cc, dt)
    wgt = xp.stack([t[a][:, None] * t[b][None, :] for a in (0, 1) for b in (0, 1)])  # (4, cc, cc)
    x = cells[idx[:, 0], idx[:, 1]][:, None] * wgt[None, :, None]  # (Na, 4, C, cc, cc)
    xf = be.fft.rfft2(x, s=(n_fft, n_fft))
    kf = be.fft.rfft2(px, s=(n_fft, n_fft))  # (U, C, n, n/2+1)
    yf = (xf * kf[inv].reshape(na, 4, ctot, n_fft, -1)).sum(1)
    y = be.astype(be.fft.irfft2(yf, s=(n_fft, n_fft))[..., :cc + 2 * r, :cc + 2 * r], dt)  # (Na, C, cc+2r, cc+2r)
    # Overlap-add the cells' spread light (blocks of cc + 2r laid out with stride cc).
    out = be.overlap_add(y, idx, ny, nx, cc, r)[:, r:r + hc, r:r + wc]
    if m > 1:
        out = be.upsample(out, m)
    return out[:, :h, :wd]


def render_layered(image, depth_m, focus_m: float, source, field_fn, cfg: LayeredConfig = LayeredConfig(),
                   focus_at=None):
    """One focal-stack frame. image (C, H, W) linear (float32 or float64); depth_m (H, W) metres from the sensor,
    all > 0; numpy arrays, or torch tensors (then with the torch backend, `training.render.layered`).

    source: a PSF source (`aat_deploy.render.sources`, `training.render.sources`): source(x, y, depth_m, focus_m)
        -> (kernels (N, k, k) or (N, Ck, k, k) with Ck = C, scale (N,)) as arrays of the image's library, in the
        storage of `aat_deploy.psf.kernel`; source.k; source.scale(depth_m, focus_m) and
        source.blur_px(depth_m, focus_m) (pixels, numpy).
    field_fn(rows, cols) -> normalised field (x, y) of points given in this image's pixel coordinates
        (row, col; pixel centres at +0.5), accounting for the crop's place on the sensor.
    focus_at(x, y, focus_m) -> per-anchor focus distances (m), for effects that make focus vary over the field
        (sensor tilt); default: focus_m everywhere.
    Returns (C, H, W) in the image's dtype and library.
    """
    be = backend_of(image)
    xp = be.xp
    image, depth_m = be.asarray(image), be.asarray(depth_m)
    if image.ndim != 3 or tuple(depth_m.shape) != tuple(image.shape[1:]):
        raise ValueError(f"image must be (C, H, W) and depth (H, W); got {tuple(image.shape)}, {tuple(depth_m.shape)}")
    if not bool(xp.isfinite(depth_m).all()) or float(depth_m.min()) <= 0:
        raise ValueError("depth_m must be finite and > 0 everywhere (fill unknown depth before rendering)")
    c, h, w = image.shape
    dt = image.dtype
    inv = 1.0 / be.astype(depth_m, dt)
    layers = layer_diopters(inv, source.blur_px, focus_m, cfg)
    n = len(layers)
    scales = np.asarray(source.scale(1.0 / layers, np.full(n, focus_m)), dtype=np.float64).reshape(n)
    # Border: edge-replicate enough that the widest PSF present sees the scene beyond the frame.
    pad = max(pixel_kernel_size(source.k, float(s)) // 2 for s in scales) + 1
    img = be.pad_edge(image, pad)
    invp = be.pad_edge(inv, pad)
    if n == 1:
        weights = [xp.ones_like(invp)]
    else:
        t = (invp - float(layers[0])) / float(layers[1] - layers[0])
        if cfg.occlusion:
            near = xp.clip(xp.round(t), 0, n - 1)
            weights = [be.astype(near == i, dt) for i in range(n)]
        else:
            weights = [xp.clip(1 - xp.abs(t - i), 0, None) for i in range(n)]

    def anchors_field(rows, cols):
        return field_fn(np.asarray(rows) - pad, np.asarray(cols) - pad)

    out = xp.zeros_like(img)
    transmit = xp.ones_like(img[:1])
    for i in range(n - 1, -1, -1):  # near (largest 1/d) first
        wi = weights[i]
        if not bool((wi > 0).any()):
            continue
        m = max(1, int(scales[i] // cfg.coarse_ratio))
        d_i = 1.0 / float(layers[i])

        def kfn(x, y, d_i=d_i):
            f = np.full(len(x), focus_m) if focus_at is None else focus_at(x, y, focus_m)
            return source(x, y, np.full(len(x), d_i), f)

        if cfg.occlusion:
            o = _render_layer(be, img, wi, m, anchors_field, kfn, cfg, extra_channels=xp.ones_like(img[:1]))
            out += transmit * o[:c]
            transmit = transmit * (1 - xp.clip(o[c:], 0, 1))
        else:
            out += _render_layer(be, img, wi, m, anchors_field, kfn, cfg)
    return out[:, pad:pad + h, pad:pad + w]
