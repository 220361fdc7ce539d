"""The `chromatic` effect's PSFs by ray tracing at three wavelengths (torch): what the runtime's effect
(`aat_deploy.render.effects.chromatic`) uses when no per-wavelength surrogates sit next to the lens's, reached
through the extension `chromatic_tracer` declared in pyproject.toml."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from aat_deploy.optics.thin_lens import thin_lens_blur_px
from aat_deploy.psf.kernel import KernelSpec
from aat_deploy.render.effects import SimContext
from aat_deploy.render.effects.chromatic import REFERENCE_WAVELENGTH_NM
from training.devices.select import on_cpu
from training.psf.raytrace import raytrace_psfs


class ThreeWavelengths:
    """Source of (N, 3, k, k) kernels (R, G, B), all centred on the design wavelength's chief ray, ray-traced."""

    def __init__(self, ctx: SimContext, wavelengths_nm: list[float], n_rays: int, compiled: bool, k: int):
        self.lens, self.wavelengths, self.n_rays, self.compiled = ctx.lens, wavelengths_nm, n_rays, compiled
        self.spec = KernelSpec.for_lens(ctx.lens, size=k)
        self.table = ctx.focus_table()  # design wavelength: where the camera puts the sensor
        self.k = k

    def scale(self, depth_m, focus_m):
        return self.spec.scale(self.lens, depth_m, focus_m)

    def blur_px(self, depth_m, focus_m):
        return thin_lens_blur_px(self.lens, depth_m, focus_m)

    @on_cpu
    def __call__(self, x, y, depth_m, focus_m):
        ref = raytrace_psfs(self.lens, x, y, depth_m, focus_m, self.spec, n_rays=16, table=self.table,
                            wavelength_nm=REFERENCE_WAVELENGTH_NM)
        out = []
        for w in self.wavelengths:
            b = raytrace_psfs(self.lens, x, y, depth_m, focus_m, self.spec, n_rays=self.n_rays, wavelength_nm=w,
                              table=self.table, compiled=self.compiled)
            # Lateral colour: move the kernel by its chief ray's offset from the design wavelength's.
            shift_cells = (b.center_mm - ref.center_mm) / self.lens.sensor.pixel_mm / b.scale[:, None]
            out.append(shift_kernels(b.kernels, torch.from_numpy(shift_cells).float()))
        return torch.stack(out, 1), torch.from_numpy(np.asarray(ref.scale, dtype=np.float32))


def shift_kernels(kernels, shift_xy_cells):
    """Move (N, k, k) kernels by (dx right, dy up) cells, bilinear."""
    n, k, _ = kernels.shape
    g = torch.arange(k, dtype=torch.float32)
    cols = (g[None, :] - shift_xy_cells[:, :1])  # sample source column c - dx
    rows = (g[None, :] + shift_xy_cells[:, 1:])  # up is -row
    gx = (2 * cols + 1) / k - 1
    gy = (2 * rows + 1) / k - 1
    grid = torch.stack([gx[:, None, :].expand(n, k, k), gy[:, :, None].expand(n, k, k)], -1)
    return F.grid_sample(kernels[:, None].float(), grid, mode="bilinear", padding_mode="zeros",
                         align_corners=False)[:, 0]
