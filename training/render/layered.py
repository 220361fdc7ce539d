"""The fast renderer: depth layers x field cells, each a small batched convolution.

The exact renderer (`exact.py`) spreads every pixel with its own PSF. Here the PSF is made piecewise smooth:

- depth: layers evenly spaced in diopters, close enough that the thin-lens blur changes by `layer_blur_px`
  between neighbours; a pixel's light is split between its two neighbouring layers linearly in 1/depth
  (occlusion mode: the nearest layer only, so that layers can occlude one another);
- field: anchors on a regular grid of `cell_px` cells; inside a cell a pixel's light is split among the cell's
  four corner anchors with bilinear (tent) weights and each share is spread with that anchor's PSF.

So every source pixel is spread with a bilinear blend of anchor PSFs at a blend of layer depths: still a true
convolution (the emitter's PSF, by FFT per cell; no correlation), and energy is conserved because
the weights sum to one. Light from just outside the frame comes in from an edge-replicated border.

Layers whose blur is large are rendered on a coarser grid: the layer image is box-averaged by an integer m, the
kernel resampled to m-pixel cells and the result upsampled bilinearly (m = floor(scale / coarse_ratio), so the
extra blur this adds is a small fraction of the layer's own blur). Cost per layer is then about the same for
all layers, and only cells a layer actually touches are convolved.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

# The configuration, layer placement and FFT sizes are shared with the numpy port (torch-free twins).
from aat_deploy.render.layered import LayeredConfig, fast_len, layer_diopters
from training.render.exact import cells_to_pixels, pixel_kernel_size

__all__ = ["LayeredConfig", "layer_diopters", "render_layered"]


def _tent_weights(n: int, dtype) -> torch.Tensor:
    """(2, n): weights of a cell's low and high anchors at its n pixel centres."""
    t = (torch.arange(n, dtype=dtype) + 0.5) / n
    return torch.stack([1 - t, t])


def _render_layer(img: torch.Tensor, w: torch.Tensor, m: int, anchors_field_fn, kernel_fn, cfg: LayeredConfig,
                  extra_channels: torch.Tensor | None = None) -> torch.Tensor:
    """Spread img * w (C, H, W) with the anchor PSFs of one layer; returns (C, H, W) (+ extra channels).

    m: integer downsampling factor. anchors_field_fn(rows_px, cols_px) -> field (x, y) arrays of anchor points
    given in padded full-resolution pixel coordinates. kernel_fn(x, y) -> (kernels (N, Ck, k, k), scale (N,)).
    """
    c, h, wd = img.shape
    src = img * w
    if extra_channels is not None:  # occlusion coverage, blurred with the channel-mean kernel
        src = torch.cat([src, extra_channels * w], 0)
    ctot = src.shape[0]
    hc, wc = math.ceil(h / m), math.ceil(wd / m)
    if m > 1:
        src = F.pad(src, (0, wc * m - wd, 0, hc * m - h))
        src = F.avg_pool2d(src[None], m)[0]
        cover = F.max_pool2d(F.pad(w, (0, wc * m - wd, 0, hc * m - h))[None, None], m)[0, 0]
    else:
        cover = w
    cc = max(4, round(cfg.cell_px / m))
    ny, nx = math.ceil(hc / cc), math.ceil(wc / cc)  # cells
    src = F.pad(src, (0, nx * cc - wc, 0, ny * cc - hc))
    cover = F.pad(cover, (0, nx * cc - wc, 0, ny * cc - hc))
    cells = src.view(ctot, ny, cc, nx, cc).permute(1, 3, 0, 2, 4)  # (ny, nx, C, cc, cc)
    active = cover.view(ny, cc, nx, cc).amax((1, 3)) > 0  # (ny, nx)
    idx = active.nonzero()  # (Na, 2) = cell row, col
    if idx.shape[0] == 0:
        return torch.zeros(ctot, h, wd, dtype=img.dtype)
    # Corner anchors of the active cells, each queried once.
    corners = torch.stack([idx + torch.tensor(d) for d in ((0, 0), (0, 1), (1, 0), (1, 1))], 1)  # (Na, 4, 2)
    flat = corners[..., 0] * (nx + 1) + corners[..., 1]
    uniq, inv = torch.unique(flat.reshape(-1), return_inverse=True)
    ar, ac = (uniq // (nx + 1)).double(), (uniq % (nx + 1)).double()
    fx, fy = anchors_field_fn(ar.numpy() * cc * m, ac.numpy() * cc * m)
    kernels, scale = kernel_fn(fx, fy)
    if kernels.ndim == 3:
        kernels = kernels[:, None]  # (U, Ck, k, k)
    s = float(scale.reshape(-1)[0])  # one depth and focus per layer: one cell size
    size = pixel_kernel_size(kernels.shape[-1], s / m)
    u, ck, k, _ = kernels.shape
    px = cells_to_pixels(kernels.reshape(u * ck, k, k).to(img.dtype), torch.full((u * ck,), s / m, dtype=img.dtype),
                         size).view(u, ck, size, size)
    if ck == 1:
        px = px.expand(u, c, size, size)
    if extra_channels is not None:
        px = torch.cat([px, px.mean(1, keepdim=True)], 1)
    r = size // 2
    na = idx.shape[0]
    # Full linear convolution of each cell (cc x cc) with its corner kernels by FFT: output block cc + 2r,
    # block index i + j for source pixel i and kernel tap j (tap r = no offset). The four corners' shares are
    # summed in the frequency domain, so there is one inverse transform per cell and channel.
    n_fft = fast_len(cc + 2 * r)
    ty, tx = _tent_weights(cc, img.dtype), _tent_weights(cc, img.dtype)
    wgt = torch.stack([ty[a][:, None] * tx[b][None, :] for a in (0, 1) for b in (0, 1)])  # (4, cc, cc)
    x = cells[idx[:, 0], idx[:, 1]][:, None] * wgt[None, :, None]  # (Na, 4, C, cc, cc)
    xf = torch.fft.rfft2(x, s=(n_fft, n_fft))
    kf = torch.fft.rfft2(px, s=(n_fft, n_fft))  # (U, C, n, n/2+1)
    yf = (xf * kf[inv].view(na, 4, ctot, n_fft, -1)).sum(1)
    y = torch.fft.irfft2(yf, s=(n_fft, n_fft))[..., :cc + 2 * r, :cc + 2 * r]  # (Na, C, cc+2r, cc+2r)
    # Overlap-add the cells' spread light (blocks of cc + 2r laid out with stride cc).
    canvas = torch.zeros(ctot, ny * cc + 2 * r, nx * cc + 2 * r, dtype=img.dtype)
    if na <= 64:
        for (cy, cx), blk in zip(idx.tolist(), y):
            canvas[:, cy * cc:cy * cc + cc + 2 * r, cx * cc:cx * cc + cc + 2 * r] += blk
    else:  # fold sums overlapping blocks in one call
        blocks = torch.zeros(ny * nx, ctot * (cc + 2 * r) ** 2, dtype=img.dtype)
        blocks[idx[:, 0] * nx + idx[:, 1]] = y.reshape(na, -1)
        canvas = F.fold(blocks.T[None], tuple(canvas.shape[1:]), cc + 2 * r, stride=cc)[0]
    out = canvas[:, r:r + hc, r:r + wc]
    if m > 1:
        out = F.interpolate(out[None], scale_factor=m, mode="bilinear", align_corners=False)[0]
    return out[:, :h, :wd]


def render_layered(image: torch.Tensor, depth_m: torch.Tensor, focus_m: float, source, field_fn,
                   cfg: LayeredConfig = LayeredConfig(), focus_at=None) -> torch.Tensor:
    """One focal-stack frame. image (C, H, W) linear; depth_m (H, W) metres from the sensor, all > 0.

    source: a PSF source (`training.render.sources`): source(x, y, depth_m, focus_m) -> (kernels (N, k, k) or
        (N, Ck, k, k) with Ck = C, scale (N,)) in the storage of `aat_deploy.psf.kernel`; source.k;
        source.scale(depth_m, focus_m) and source.blur_px(depth_m, focus_m) as numpy.
    field_fn(rows, cols) -> normalised field (x, y) of points given in this image's pixel coordinates
        (row, col; pixel centres at +0.5), accounting for the crop's place on the sensor.
    focus_at(x, y, focus_m) -> per-anchor focus distances (m), for effects that make focus vary over the field
        (sensor tilt); default: focus_m everywhere.
    Returns (C, H, W).
    """
    if image.ndim != 3 or depth_m.shape != image.shape[1:]:
        raise ValueError(f"image must be (C, H, W) and depth (H, W); got {tuple(image.shape)}, {tuple(depth_m.shape)}")
    if not bool(torch.isfinite(depth_m).all()) or float(depth_m.min()) <= 0:
        raise ValueError("depth_m must be finite and > 0 everywhere (fill unknown depth before rendering)")
    c, h, w = image.shape
    inv = 1.0 / depth_m.to(image.dtype)
    layers = layer_diopters(inv, source.blur_px, focus_m, cfg)
    n = len(layers)
    scales = np.asarray(source.scale(1.0 / layers, np.full(n, focus_m)), dtype=np.float64).reshape(n)
    # Border: edge-replicate enough that the widest PSF present sees the scene beyond the frame.
    pad = max(pixel_kernel_size(source.k, float(s)) // 2 for s in scales) + 1
    img = F.pad(image[None], (pad, pad, pad, pad), mode="replicate")[0]
    invp = F.pad(inv[None, None], (pad, pad, pad, pad), mode="replicate")[0, 0]
    if n == 1:
        weights = [torch.ones_like(invp)]
    else:
        t = (invp - float(layers[0])) / float(layers[1] - layers[0])
        if cfg.occlusion:
            near = torch.round(t).clamp(0, n - 1)
            weights = [(near == i).to(img.dtype) for i in range(n)]
        else:
            weights = [torch.clamp(1 - (t - i).abs(), min=0) for i in range(n)]

    def anchors_field(rows, cols):
        return field_fn(np.asarray(rows) - pad, np.asarray(cols) - pad)

    out = torch.zeros_like(img)
    transmit = torch.ones_like(img[:1])
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
            o = _render_layer(img, wi, m, anchors_field, kfn, cfg, extra_channels=torch.ones_like(img[:1]))
            out += transmit * o[:c]
            transmit = transmit * (1 - o[c:].clamp(0, 1))
        else:
            out += _render_layer(img, wi, m, anchors_field, kfn, cfg)
    return out[:, pad:pad + h, pad:pad + w]
