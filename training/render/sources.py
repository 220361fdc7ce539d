"""Where a renderer gets its PSFs: the ray tracer, a surrogate network, or the thin-lens Gaussian.

Every source maps arrays (x, y, depth_m, focus_m) to (kernels (N, k, k), scale (N,)) in the common storage of
`training.psf.kernel`, so renderers never care which one they use. Same focal length, F-number and sensor in all
three: the only difference is the aberrations.
"""

from __future__ import annotations

import numpy as np
import torch

from training.lens.schema import Lens
from training.psf.kernel import KernelSpec
from training.psf.raytrace import raytrace_psfs
from training.psf.surrogates import PSFModel


class RayTracedPSF:
    def __init__(self, lens: Lens, spec: KernelSpec | None = None, n_rays: int = 2048, compiled: bool = False):
        self.lens, self.spec, self.n_rays, self.compiled = lens, spec or KernelSpec.for_lens(lens), n_rays, compiled

    def __call__(self, x, y, depth_m, focus_m):
        b = raytrace_psfs(self.lens, x, y, depth_m, focus_m, self.spec, n_rays=self.n_rays, compiled=self.compiled)
        return b.kernels, torch.from_numpy(np.asarray(b.scale, dtype=np.float32))


class ModelPSF:
    """A torch PSF model (RotPSF, PaperMLP, GaussianPSF, GridPSF)."""

    def __init__(self, model: PSFModel, batch: int = 32768):
        self.model, self.batch = model.eval(), batch

    @torch.no_grad()
    def __call__(self, x, y, depth_m, focus_m):
        x, y, d, f = (np.asarray(a, dtype=np.float32).ravel() for a in np.broadcast_arrays(x, y, depth_m, focus_m))
        q = torch.from_numpy(np.stack([x, y, d, f], -1))
        ks = [self.model(q[i:i + self.batch]) for i in range(0, q.shape[0], self.batch)]
        return torch.cat(ks), self.model.scale(q[:, 2], q[:, 3])


def pixel_fields(height: int, width: int, sensor_hw: tuple[int, int], origin: tuple[int, int] = (0, 0)):
    """Normalised field (x, y) of every pixel centre of an (height, width) window whose top-left pixel is
    `origin` = (row, col) of a full sensor of `sensor_hw` = (rows, cols) pixels. Returns two (H, W) arrays."""
    hs, ws = sensor_hw
    rows = np.arange(height) + origin[0] + 0.5
    cols = np.arange(width) + origin[1] + 0.5
    x = 2 * cols / ws - 1
    y = 1 - 2 * rows / hs
    return np.meshgrid(x, y, indexing="xy")
