"""How a PSF is stored: a k x k window whose cell size grows with the defocus blur.

Near focus a cell is one sensor pixel (the paper's representation). Far from focus the blur is far larger than
any fixed window (about 35 px per diopter for the RF50 at 37.5 um pixels), so instead of truncating it the
window's cells grow: cell = s pixels with
    s = max(1, (b + margin_px) / (k - 1)),
b the thin-lens blur-disk diameter (px) at that depth and focus, margin_px an allowance for aberrations
(field curvature, coma) that the thin lens does not have. s depends only on (depth, focus) and the lens, so the
surrogate and the renderer compute it exactly; a kernel with s > 1 is resampled to pixels when rendering.

Values are energy per cell: a PSF sums to the fraction of the on-axis pupil's light that reaches the sensor
inside the window (vignetting and anything outside the window lower it; nothing is renormalised).
Array layout: kernel[row, col], row 0 at the top of the upright image, centre cell (k//2, k//2) on the
reference point (the chief ray's hit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.thin_lens import thin_lens_blur_px


@dataclass(frozen=True)
class KernelSpec:
    size: int = 11  # k, odd
    margin_px: float = 4.0  # aberration allowance added to the thin-lens blur (px)

    def __post_init__(self):
        if self.size % 2 != 1 or self.size < 3:
            raise ValueError(f"kernel size must be odd and >= 3, got {self.size}")

    def scale(self, lens: Lens, depth_m, focus_m) -> np.ndarray:
        """Cell size in pixels (>= 1) for each (depth, focus)."""
        b = thin_lens_blur_px(lens, depth_m, focus_m)
        return np.maximum(1.0, (b + self.margin_px) / (self.size - 1))

    @staticmethod
    def for_lens(lens: Lens, size: int = 11, margin_px: float = 4.0) -> "KernelSpec":
        """The spec used with `lens` (sizes are in its sensor pixels; `scale` takes the lens at call time)."""
        return KernelSpec(size=size, margin_px=margin_px)

