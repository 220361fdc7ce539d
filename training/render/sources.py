"""Where a renderer gets its PSFs: the ray tracer, a surrogate network, or the thin-lens Gaussian.

Every source maps arrays (x, y, depth_m, focus_m) to (kernels (N, k, k), scale (N,)), CPU tensors, in the
common storage of `aat_deploy.psf.kernel`, so renderers never care which one they use, and tells its window size
`k`, cell size `scale(depth_m, focus_m)` and thin-lens blur `blur_px(depth_m, focus_m)` (numpy, pixels). Same
focal length, F-number and sensor in all three: the only difference is the aberrations.
"""

from __future__ import annotations

import numpy as np
import torch

# Backend-neutral pieces live with the runtime's renderer (aat_deploy.render) and are shared from there.
from aat_deploy.lens.schema import Lens
from aat_deploy.psf.kernel import KernelSpec
from aat_deploy.render.sources import LensGeometry as _LensGeometry
from aat_deploy.render.sources import (
    OnnxSource,
    UnitEnergy,  # noqa: F401 (re-exported)
)
from training.devices.select import on_cpu
from training.psf.raytrace import DEFAULT_WAVELENGTH_NM, raytrace_psfs
from training.psf.surrogates import GaussianPSF, PSFModel


class RayTracedPSF(_LensGeometry):
    """PSFs traced on demand (`training.psf.raytrace`), at one wavelength."""

    def __init__(self, lens: Lens, spec: KernelSpec | None = None, n_rays: int = 2048, compiled: bool = False,
                 wavelength_nm: float = DEFAULT_WAVELENGTH_NM, seed: int = 0, device: str = "cpu"):
        self.lens, self.spec, self.n_rays, self.compiled = lens, spec or KernelSpec.for_lens(lens), n_rays, compiled
        self.wavelength_nm, self.seed, self.device = wavelength_nm, seed, device

    def __call__(self, x, y, depth_m, focus_m):
        b = raytrace_psfs(self.lens, x, y, depth_m, focus_m, self.spec, n_rays=self.n_rays, compiled=self.compiled,
                          wavelength_nm=self.wavelength_nm, seed=self.seed, device=self.device)
        return b.kernels, torch.from_numpy(np.asarray(b.scale, dtype=np.float32))


class ModelPSF(_LensGeometry):
    """A torch PSF model (RotPSF, PaperMLP, GaussianPSF, GridPSF)."""

    def __init__(self, model: PSFModel, lens: Lens, batch: int = 32768):
        self.model, self.lens, self.batch = model.eval(), lens, batch
        self.spec = KernelSpec(size=model.k, margin_px=model.margin_px)

    @torch.no_grad()
    @on_cpu
    def __call__(self, x, y, depth_m, focus_m):
        x, y, d, f = (np.asarray(a, dtype=np.float32).ravel() for a in np.broadcast_arrays(x, y, depth_m, focus_m))
        q = torch.from_numpy(np.stack([x, y, d, f], -1))
        ks = [self.model(q[i:i + self.batch]) for i in range(0, q.shape[0], self.batch)]
        return torch.cat(ks), self.model.scale(q[:, 2], q[:, 3])


def thin_lens_source(lens: Lens, spec: KernelSpec | None = None, near_m: float = 0.2, far_m: float = 100.0):
    """The baseline: a Gaussian of the thin-lens blur (same EFL, entrance pupil and pixels), field-invariant."""
    spec = spec or KernelSpec.for_lens(lens)
    return ModelPSF(GaussianPSF(lens, spec, near_m, far_m), lens)


class OnnxPSF(_LensGeometry):
    """An exported surrogate (`aat_deploy.psf.surrogate.PSFSurrogate`, onnxruntime): the same PSFs the runtime renders
    digital twins with, as torch tensors. Depths outside the model's range are clamped to it (beyond ~100 m
    blur no longer changes). The lens must be the one the surrogate was fitted for (checked by prescription hash).
    `.numpy` is the torch-free source underneath (`aat_deploy.render.sources.OnnxSource`)."""

    def __init__(self, path, lens: Lens, threads: int | None = None):
        self._wrap(OnnxSource(path, lens, threads=threads))

    @classmethod
    def from_source(cls, source: OnnxSource) -> OnnxPSF:
        """The same session as a torch-free `OnnxSource` (no second onnxruntime session)."""
        obj = cls.__new__(cls)
        obj._wrap(source)
        return obj

    def _wrap(self, source: OnnxSource) -> None:
        self.numpy = source
        self.model, self.lens, self.spec, self.path = source.model, source.lens, source.spec, source.path

    def __call__(self, x, y, depth_m, focus_m):
        k, s = self.numpy(x, y, depth_m, focus_m)
        return torch.from_numpy(k), torch.from_numpy(s)
