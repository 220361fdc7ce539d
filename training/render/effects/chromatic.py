"""chromatic: colour by tracing three wavelengths (longitudinal and lateral colour, per-channel aberrations)."""

from __future__ import annotations

import numpy as np

from aat_deploy.twin.sources import UnitEnergy
from training.psf.geometry import thin_lens_blur_px
from training.psf.kernel import KernelSpec
from training.render.effects import Effect, SimContext, register

# The ray tracer and torch are imported where the kernels are made: the registry must import without torch.


@register
class Chromatic(Effect):
    name = "chromatic"
    description = ("per-channel PSFs traced at three wavelengths with the sensor focused at the design "
                   "wavelength: longitudinal colour as defocus, lateral colour as a shift of each channel's "
                   "kernel by its chief ray's offset (implies the lens's aberrations)")
    order = 10
    needs_torch = "it ray-traces the PSFs at three wavelengths (the surrogate knows one)"
    defaults = {"wavelengths_nm": [610.0, 540.0, 465.0], "n_rays": 1024, "compiled": False}

    def wrap_source(self, source, ctx: SimContext):
        return UnitEnergy(_ThreeWavelengths(ctx, [float(w) for w in self.params["wavelengths_nm"]], int(self.params["n_rays"]),
                                 bool(self.params["compiled"]), k=source.k))


class _ThreeWavelengths:
    """Source of (N, 3, k, k) kernels (R, G, B), all centred on the design wavelength's chief ray."""

    def __init__(self, ctx: SimContext, wavelengths_nm: list[float], n_rays: int, compiled: bool, k: int):
        self.lens, self.wavelengths, self.n_rays, self.compiled = ctx.lens, wavelengths_nm, n_rays, compiled
        self.spec = KernelSpec.for_lens(ctx.lens, size=k)
        self.table = ctx.focus_table()  # design wavelength: where the camera puts the sensor
        self.k = k

    def scale(self, depth_m, focus_m):
        return self.spec.scale(self.lens, depth_m, focus_m)

    def blur_px(self, depth_m, focus_m):
        return thin_lens_blur_px(self.lens, depth_m, focus_m)

    def __call__(self, x, y, depth_m, focus_m):
        import torch

        from training.psf.raytrace import raytrace_psfs

        ref = raytrace_psfs(self.lens, x, y, depth_m, focus_m, self.spec, n_rays=16, table=self.table)
        out = []
        for w in self.wavelengths:
            b = raytrace_psfs(self.lens, x, y, depth_m, focus_m, self.spec, n_rays=self.n_rays, wavelength_nm=w,
                              table=self.table, compiled=self.compiled)
            # Lateral colour: move the kernel by its chief ray's offset from the design wavelength's.
            shift_cells = (b.center_mm - ref.center_mm) / self.lens.sensor.pixel_mm / b.scale[:, None]
            out.append(_shift(b.kernels, torch.from_numpy(shift_cells).float()))
        return torch.stack(out, 1), torch.from_numpy(np.asarray(ref.scale, dtype=np.float32))


def _shift(kernels: torch.Tensor, shift_xy_cells: torch.Tensor) -> torch.Tensor:
    """Move (N, k, k) kernels by (dx right, dy up) cells, bilinear."""
    import torch
    import torch.nn.functional as F

    n, k, _ = kernels.shape
    g = torch.arange(k, dtype=torch.float32)
    cols = (g[None, :] - shift_xy_cells[:, :1])  # sample source column c - dx
    rows = (g[None, :] + shift_xy_cells[:, 1:])  # up is -row
    gx = (2 * cols + 1) / k - 1
    gy = (2 * rows + 1) / k - 1
    grid = torch.stack([gx[:, None, :].expand(n, k, k), gy[:, :, None].expand(n, k, k)], -1)
    return F.grid_sample(kernels[:, None].float(), grid, mode="bilinear", padding_mode="zeros",
                         align_corners=False)[:, 0]
