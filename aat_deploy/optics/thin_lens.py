"""The thin-lens blur disk: how large a defocused point is for a lens of this focal length and entrance pupil.

The one definition of the formula for numpy (the runtime, PSF window sizes, the twins' Gaussian baseline) and
torch (the training side's Gaussian surrogate, exported to ONNX): `blur_diameter_px` computes in the inputs'
namespace and precision (`aat_deploy.backend`), and so does the thin-lens baseline's kernel, `gaussian_kernels`.
"""

from __future__ import annotations

import numpy as np

from aat_deploy.backend import arange_like, namespace
from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_data


def blur_diameter_px(depth_m, focus_m, efl_mm: float, epd_mm: float, pixel_mm: float):
    """Geometric blur-disk diameter (pixels) of a thin lens (focal length efl_mm, entrance pupil epd_mm) at
    depth_m, focused at focus_m, both metres from the sensor; numpy arrays or torch tensors of one precision
    (the result has it), broadcast together.

    The thin lens sits at the image-side distance v_f from the sensor that focuses focus_m (u + v = D,
    1/u + 1/v = 1/f, the smaller root, computed stably); objects nearer than f are held just beyond it."""
    xp = namespace(depth_m, focus_m)
    f = efl_mm
    big_d = 1000.0 * focus_m
    v_f = 2 * big_d * f / (big_d + xp.sqrt(xp.clip(big_d * big_d - 4 * big_d * f, 0.0, None)))
    u = xp.clip(1000.0 * depth_m - v_f, f * 1.0001, None)
    v_o = 1.0 / (1.0 / f - 1.0 / u)
    return epd_mm * xp.abs(v_f - v_o) / v_o / pixel_mm


def thin_lens_blur_px(lens: Lens, depth_m, focus_m) -> np.ndarray:
    """Blur-disk diameter (pixels, float64) of a thin lens with `lens`'s EFL and entrance pupil, on its sensor.
    Object and focus distances in metres from the sensor. Sizes PSF windows and the Gaussian baseline."""
    p = paraxial_data(lens)
    return blur_diameter_px(np.asarray(depth_m, dtype=np.float64), np.asarray(focus_m, dtype=np.float64),
                            p.efl_mm, p.entrance_pupil_mm, lens.sensor.pixel_mm)


def gaussian_kernels(blur_px, size: int, margin_px: float):
    """The thin-lens baseline's PSF kernels: a separable Gaussian with the blur disk's second moment
    (sigma = blur / 4) plus the splat's tent (1/6 cell^2), on scale-adaptive cells (`KernelSpec.scale`: a cell is
    s = max((blur + margin_px) / (size - 1), 1) pixels), normalised over the whole cell lattice, not the window:
    what falls outside the window is lost, as for every other PSF source; nothing is renormalised.

    blur_px: (B,) blur-disk diameters in pixels (numpy or torch, any precision; the result has it).
    Returns kernels (B, size, size) and the cell size s (B,) in pixels. Field-invariant by construction."""
    xp = namespace(blur_px)
    s = xp.clip((blur_px + margin_px) / (size - 1), 1.0, None)
    sigma2 = (blur_px / 4.0 / s) ** 2 + 1.0 / 6.0  # cells^2
    wide = arange_like(-size - 40, size + 41, blur_px)
    norm = xp.exp(-(wide[None, :] ** 2) / (2 * sigma2[:, None])).sum(1)[:, None]
    g = arange_like(0, size, blur_px) - size // 2
    e = xp.exp(-(g[None, :] ** 2) / (2 * sigma2[:, None])) / norm
    return e[:, :, None] * e[:, None, :], s
