"""The exact reference renderer: every source pixel spreads its light with its own PSF (true convolution).

    out(q) = sum_p I(p) P_p(q - p)

P_p is the PSF of the scene point seen at pixel p (its field position and depth), resampled from the PSF storage
(k x k cells of s pixels, `aat_deploy.psf.kernel`) to pixels. This is what a lens does: the blur belongs to the
emitting point, and the kernel is not flipped (the reference implementation's gather with the receiving pixel's
kernel computes a correlation, which mirrors asymmetric off-axis blur). Slow and memory-hungry by design: it is
the yardstick the fast renderer is measured against.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

# One kernel resampling for every renderer: the layered renderer's, over torch arrays (its torch backend).
from aat_deploy.render.layered import cells_to_pixels, pixel_kernel_size  # noqa: F401 (re-exported)
from training.render.layered import TORCH


def render_exact(image: torch.Tensor, kernels: torch.Tensor, rows_per_chunk: int = 32) -> torch.Tensor:
    """Scatter every pixel of `image` (C, H, W) with its own pixel kernel; kernels (H*W, K, K), K odd.

    The image is extended by edge replication so light from just outside the frame comes in (a flat field stays
    flat up to the border), then the frame is cut out again. Returns (C, H, W).
    """
    c, h, w = image.shape
    kk = kernels.shape[-1]
    r = kk // 2
    ker = kernels.view(h, w, kk, kk)
    # Replicate the border pixels' image and kernels.
    img = F.pad(image[None], (r, r, r, r), mode="replicate")[0]
    yi = torch.clamp(torch.arange(-r, h + r), 0, h - 1)
    xi = torch.clamp(torch.arange(-r, w + r), 0, w - 1)
    hp, wp = h + 2 * r, w + 2 * r
    out = torch.zeros(c, hp + 2 * r, wp + 2 * r, dtype=image.dtype)
    for y0 in range(0, hp, rows_per_chunk):
        y1 = min(y0 + rows_per_chunk, hp)
        kc = ker[yi[y0:y1]][:, xi]  # (rows, wp, K, K)
        contrib = img[:, y0:y1, :, None, None] * kc[None]  # (C, rows, wp, K, K)
        cols = contrib.permute(0, 3, 4, 1, 2).reshape(c, kk * kk, (y1 - y0) * wp)
        # fold adds patch element (a, b) of source (y, x) at (y + a, x + b) of the padded output: scatter.
        part = F.fold(cols, (y1 - y0 + 2 * r, wp + 2 * r), (kk, kk))
        out[:, y0:y1 + 2 * r, :] += part[:, 0]
    return out[:, 2 * r:2 * r + h, 2 * r:2 * r + w]


def render_frame_exact(image: torch.Tensor, depth_m: torch.Tensor, focus_m: float, psf_source, sensor_hw,
                       origin=(0, 0)) -> torch.Tensor:
    """One focal-stack frame the exact way: a PSF query per pixel (its field position and depth), resampled to
    pixels, scattered with true convolution. image (C, H, W) linear; depth_m (H, W) metres from the sensor."""
    from aat_deploy.optics.field import pixel_fields

    _, h, w = image.shape
    x, y = pixel_fields(h, w, sensor_hw, origin)
    kernels, scale = psf_source(x.ravel(), y.ravel(), depth_m.reshape(-1).numpy(), focus_m)
    size = pixel_kernel_size(kernels.shape[-1], float(scale.max()))
    px = torch.cat([cells_to_pixels(kernels[i:i + 4096].double(), scale[i:i + 4096], size, TORCH)
                    for i in range(0, kernels.shape[0], 4096)])
    return render_exact(image.double(), px).to(image.dtype)
