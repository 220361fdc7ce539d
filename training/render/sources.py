"""Where a renderer gets its PSFs: the ray tracer, a surrogate network, or the thin-lens Gaussian.

Every source maps arrays (x, y, depth_m, focus_m) to (kernels (N, k, k), scale (N,)) in the common storage of
`training.psf.kernel`, so renderers never care which one they use, and tells its window size `k`, cell size
`scale(depth_m, focus_m)` and thin-lens blur `blur_px(depth_m, focus_m)` (numpy, pixels). Same focal length,
F-number and sensor in all three: the only difference is the aberrations.
"""

from __future__ import annotations

import numpy as np
import torch

from training.lens.schema import Lens
from training.psf.geometry import thin_lens_blur_px
from training.psf.kernel import KernelSpec
from training.psf.raytrace import DEFAULT_WAVELENGTH_NM, raytrace_psfs
from training.psf.surrogates import GaussianPSF, PSFModel


class _LensGeometry:
    lens: Lens
    spec: KernelSpec

    @property
    def k(self) -> int:
        return self.spec.size

    def scale(self, depth_m, focus_m) -> np.ndarray:
        return self.spec.scale(self.lens, depth_m, focus_m)

    def blur_px(self, depth_m, focus_m) -> np.ndarray:
        return thin_lens_blur_px(self.lens, depth_m, focus_m)


class RayTracedPSF(_LensGeometry):
    """PSFs traced on demand (`training.psf.raytrace`), at one wavelength."""

    def __init__(self, lens: Lens, spec: KernelSpec | None = None, n_rays: int = 2048, compiled: bool = False,
                 wavelength_nm: float = DEFAULT_WAVELENGTH_NM, seed: int = 0):
        self.lens, self.spec, self.n_rays, self.compiled = lens, spec or KernelSpec.for_lens(lens), n_rays, compiled
        self.wavelength_nm, self.seed = wavelength_nm, seed

    def __call__(self, x, y, depth_m, focus_m):
        b = raytrace_psfs(self.lens, x, y, depth_m, focus_m, self.spec, n_rays=self.n_rays, compiled=self.compiled,
                          wavelength_nm=self.wavelength_nm, seed=self.seed)
        return b.kernels, torch.from_numpy(np.asarray(b.scale, dtype=np.float32))


class ModelPSF(_LensGeometry):
    """A torch PSF model (RotPSF, PaperMLP, GaussianPSF, GridPSF)."""

    def __init__(self, model: PSFModel, lens: Lens, batch: int = 32768):
        self.model, self.lens, self.batch = model.eval(), lens, batch
        self.spec = KernelSpec(size=model.k, margin_px=model.margin_px)

    @torch.no_grad()
    def __call__(self, x, y, depth_m, focus_m):
        x, y, d, f = (np.asarray(a, dtype=np.float32).ravel() for a in np.broadcast_arrays(x, y, depth_m, focus_m))
        q = torch.from_numpy(np.stack([x, y, d, f], -1))
        ks = [self.model(q[i:i + self.batch]) for i in range(0, q.shape[0], self.batch)]
        return torch.cat(ks), self.model.scale(q[:, 2], q[:, 3])


def thin_lens_source(lens: Lens, spec: KernelSpec | None = None, near_m: float = 0.2, far_m: float = 100.0):
    """The baseline: a Gaussian of the thin-lens blur (same EFL, entrance pupil and pixels), field-invariant."""
    spec = spec or KernelSpec.for_lens(lens)
    return ModelPSF(GaussianPSF(lens, spec, near_m, far_m), lens)


def pixel_fields(height: int, width: int, sensor_hw: tuple[int, int], origin: tuple[int, int] = (0, 0)):
    """Normalised field (x, y) of every pixel centre of an (height, width) window whose top-left pixel is
    `origin` = (row, col) of a full sensor of `sensor_hw` = (rows, cols) pixels. Returns two (H, W) arrays."""
    rows = np.arange(height, dtype=np.float64) + 0.5
    cols = np.arange(width, dtype=np.float64) + 0.5
    cc, rr = np.meshgrid(cols, rows, indexing="xy")
    return field_of(rr, cc, sensor_hw, origin)


def field_of(rows, cols, sensor_hw: tuple[int, int], origin: tuple[int, int] = (0, 0)):
    """Normalised field (x right, y up; +-1 at the sensor edges) of points at (rows, cols) pixel coordinates of a
    window at `origin` of the sensor (pixel centres at +0.5)."""
    hs, ws = sensor_hw
    x = 2 * (np.asarray(cols, dtype=np.float64) + origin[1]) / ws - 1
    y = 1 - 2 * (np.asarray(rows, dtype=np.float64) + origin[0]) / hs
    return x, y


class OnnxPSF(_LensGeometry):
    """An exported surrogate (`aat_deploy.psf.PSFSurrogate`, onnxruntime): the same PSFs the runtime renders
    digital twins with. Depths outside the model's range are clamped to it (beyond ~100 m blur no longer
    changes). The lens must be the one the surrogate was fitted for (checked by prescription hash)."""

    def __init__(self, path, lens: Lens, threads: int | None = None):
        from aat_deploy.psf import PSFSurrogate

        self.model, self.lens = PSFSurrogate(path, threads=threads), lens
        if self.model.lens_hash != lens.prescription_hash():
            raise ValueError(f"{path}: fitted for lens {self.model.meta.get('aat.lens_name')!r}, not {lens.name!r}")
        self.spec = KernelSpec(size=self.model.kernel_size, margin_px=float(self.model.meta["aat.margin_px"]))

    def __call__(self, x, y, depth_m, focus_m):
        lo, hi = self.model.depth_range_m
        k, s = self.model.query(x, y, np.clip(depth_m, lo, hi), focus_m)
        return torch.from_numpy(k), torch.from_numpy(s)


class UnitEnergy:
    """A source whose kernels are normalised to unit energy (per channel): light is redistributed, never lost.
    The simulator's default; the `vignetting` effect puts the lens's light fall-off back explicitly."""

    def __init__(self, source):
        self.source = source
        self.k, self.scale, self.blur_px = source.k, source.scale, source.blur_px

    def __call__(self, x, y, depth_m, focus_m):
        k, s = self.source(x, y, depth_m, focus_m)
        return k / k.sum((-1, -2), keepdim=True).clamp_min(1e-12), s
