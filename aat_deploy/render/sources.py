"""PSF sources for the torch-free renderer, with the interface of `training.render.sources`:

    source(x, y, depth_m, focus_m) -> (kernels (N, k, k) float32, scale (N,) float32)

in the storage of `aat_deploy.psf.kernel` (energy per cell, cells of `scale` pixels, centred on the chief ray),
plus `source.k`, `source.scale(depth_m, focus_m)` (cell size, pixels) and `source.blur_px(depth_m, focus_m)`
(thin-lens blur diameter, pixels). x, y: normalised field in [-1, 1] (x right, y up); distances in metres from
the sensor plane. Both sources take the lens's first-order data from the lens file (`aat_deploy.lens`, torch-free).

- `OnnxSource`: the exported surrogate (`aat_deploy.psf.surrogate.PSFSurrogate`); it also carries the lens's
  real-ray focus table and exit pupil in its metadata, which the focus effects need.
- `GaussianSource`: the thin-lens baseline (`gaussian_kernels`, the formula `training.psf.surrogates.GaussianPSF` exports).
- `UnitEnergy`: kernels normalised to unit energy, for numpy or torch kernels alike (the `aberrations` effect).
"""

from __future__ import annotations

import json

import numpy as np

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.focus_table import FocusTable, table_from_arrays
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.optics.thin_lens import blur_diameter_px, gaussian_kernels, thin_lens_blur_px
from aat_deploy.psf.kernel import KernelSpec
from aat_deploy.psf.surrogate import PSFSurrogate

# Metadata keys of an exported surrogate that carry the lens's focusing (`training.psf.export.metadata`).
TABLE_KEYS = ("aat.focus_table_diopters", "aat.focus_table_sensor_z_mm")
EXIT_PUPIL_KEY = "aat.exit_pupil_z_mm"


def normalise_energy(kernels):
    """(..., k, k) kernels divided by their sums over the last two axes (per channel); numpy or torch."""
    if isinstance(kernels, np.ndarray):
        return kernels / np.maximum(kernels.sum((-1, -2), keepdims=True), 1e-12)
    return kernels / kernels.sum((-1, -2), keepdim=True).clamp_min(1e-12)


class LensGeometry:
    """Window size, cell size and thin-lens blur of a source made for `lens` with kernel spec `spec`."""

    lens: Lens
    spec: KernelSpec

    @property
    def k(self) -> int:
        return self.spec.size

    def scale(self, depth_m, focus_m) -> np.ndarray:
        return self.spec.scale(self.lens, depth_m, focus_m)

    def blur_px(self, depth_m, focus_m) -> np.ndarray:
        return thin_lens_blur_px(self.lens, depth_m, focus_m)


class OnnxSource(LensGeometry):
    """An exported surrogate on onnxruntime. Depths and focus distances outside the model's ranges are clamped
    to them (the surrogate was not fitted there; near its far end blur changes little). The lens must be the
    one the surrogate was fitted for (checked by prescription hash, which includes the sensor)."""

    def __init__(self, path, lens: Lens, threads: int | None = None):
        self.model, self.lens = PSFSurrogate(path, threads=threads), lens
        self.path = self.model.path
        if self.model.lens_hash != lens.prescription_hash():
            raise ValueError(f"{path}: fitted for lens {self.model.meta.get('aat.lens_name')!r}, not {lens.name!r}")
        self.spec = KernelSpec(size=self.model.kernel_size, margin_px=float(self.model.meta["aat.margin_px"]))

    def __call__(self, x, y, depth_m, focus_m) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.model.depth_range_m
        # Focus too: a twin's focus can leave the range (a metadata bias past infinity, a tilted corner).
        flo, fhi = self.model.focus_range_m
        return self.model.query(x, y, np.clip(depth_m, lo, hi), np.clip(focus_m, flo, fhi))

    def focus_table(self) -> FocusTable | None:
        """Sensor z (mm) vs focus (diopters) of the lens, real-ray traced at export; None for a surrogate exported
        before these keys existed (stamp it: `aat-lens focus-map LENS --stamp PSF.onnx`)."""
        meta = self.model.meta
        if not all(k in meta for k in TABLE_KEYS):
            return None
        return table_from_arrays(*(json.loads(meta[k]) for k in TABLE_KEYS), source=str(self.path))

    def exit_pupil_z_mm(self) -> float:
        """Paraxial exit pupil (mm from the first vertex): from the metadata, else computed from the lens."""
        v = self.model.meta.get(EXIT_PUPIL_KEY)
        return float(v) if v is not None else paraxial_data(self.lens).exit_pupil_z_mm


class GaussianSource(LensGeometry):
    """The thin-lens baseline (`aat_deploy.optics.thin_lens.gaussian_kernels`, the formula the training side's
    `GaussianPSF` exports), evaluated in float32 as that surrogate is: near focus the blur is a small difference of
    image distances, so float32 and float64 kernels differ by ~1e-4 of their peak; float32 keeps the training
    simulator's numbers. Field-invariant; the same EFL, entrance pupil and pixels as the lens."""

    def __init__(self, lens: Lens, spec: KernelSpec | None = None):
        self.lens, self.spec = lens, spec or KernelSpec.for_lens(lens)
        p = paraxial_data(lens)
        self.efl_mm, self.epd_mm, self.pixel_mm = float(p.efl_mm), float(p.entrance_pupil_mm), lens.sensor.pixel_mm

    def __call__(self, x, y, depth_m, focus_m) -> tuple[np.ndarray, np.ndarray]:
        _, _, d, f = (np.asarray(a, dtype=np.float32).ravel() for a in np.broadcast_arrays(x, y, depth_m, focus_m))
        b = blur_diameter_px(d, f, self.efl_mm, self.epd_mm, self.pixel_mm)
        return gaussian_kernels(b, self.spec.size, self.spec.margin_px)


class UnitEnergy:
    """A source whose kernels are normalised to unit energy (per channel): light is redistributed, never lost.
    The simulator's default; the `vignetting` effect puts the lens's light fall-off back explicitly. Works on
    numpy and torch sources alike."""

    def __init__(self, source):
        self.source = source
        self.k, self.scale, self.blur_px = source.k, source.scale, source.blur_px

    def __call__(self, x, y, depth_m, focus_m):
        k, s = self.source(x, y, depth_m, focus_m)
        return normalise_energy(k), s
