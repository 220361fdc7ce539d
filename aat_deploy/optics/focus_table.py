"""Where the sensor sits for a focus distance: a table of sensor positions over focus distances, even in diopters.

A camera focuses by moving the sensor (unit focusing, `training.optics.focus`); a real-ray best-focus search
costs ~50 ms, so renderers and the runtime look the sensor position up in a dense table interpolated in
diopters. The table comes from real rays (`training.psf.geometry.focus_table`, torch), from a PSF surrogate's
metadata (`table_from_arrays`, the real-ray table stored at export) or from paraxial optics
(`paraxial_focus_table`, the torch-free fallback). Distances in metres from the sensor plane, sensor z in mm from
the first vertex.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_focus_z_mm


def even_diopters(near_m: float, far_m: float, n: int) -> np.ndarray:
    """The project's one "even in diopters" schedule, shape (n,): n focus settings in diopters (1/m, from the sensor
    plane) evenly spaced from 1/near_m to 1/far_m, both included (defocus blur is linear in diopters). In diopters
    for callers that jitter or bin the settings; `diopter_grid` gives the same schedule in metres."""
    return np.linspace(1.0 / near_m, 1.0 / far_m, n)


def diopter_grid(near_m: float, far_m: float, n: int) -> np.ndarray:
    """n distances (m, from the sensor plane) evenly spaced in diopters from near_m to far_m (inclusive), shape
    (n,): `1 / even_diopters(near_m, far_m, n)`."""
    return 1.0 / even_diopters(near_m, far_m, n)


@dataclass(frozen=True)
class FocusTable:
    """Sensor z (mm from the first vertex) for any focus distance, interpolated in diopters.

    `training.optics.focus.focus()` is a real-ray best-focus search (~50 ms); a dense table in diopters makes
    per-sample focus distances in training free. Interpolation error is checked against direct `focus()` in the
    tests.
    """

    diopters: np.ndarray  # ascending
    sensor_z_mm: np.ndarray

    def __call__(self, focus_m):
        d = 1.0 / np.asarray(focus_m, dtype=np.float64)
        if np.any(d < self.diopters[0] - 1e-9) or np.any(d > self.diopters[-1] + 1e-9):
            raise ValueError(
                f"focus distance outside the table ({1 / self.diopters[-1]:.3f}..{1 / self.diopters[0]:.3f} m)"
            )
        return np.interp(d, self.diopters, self.sensor_z_mm)


def paraxial_focus_table(lens: Lens, near_m: float = 0.2, far_m: float = 100.0, n: int = 129,
                         wavelength_nm: float | None = None) -> FocusTable:
    """The focus table from paraxial optics (no ray tracing, no torch): the fallback when a real-ray table is not
    at hand. It misses the lens's spherical aberration (best focus sits a little off the paraxial image)."""
    dist = diopter_grid(near_m, far_m, n)[::-1]
    zs = [paraxial_focus_z_mm(lens, float(d), wavelength_nm) for d in dist]
    ok = np.isfinite(zs)
    last = len(zs) if ok.all() else int(np.argmin(ok))  # closer than the lens focuses: the table ends there
    if last < 2:
        raise ValueError(f"{lens.name}: no paraxial focus between {far_m} and {near_m} m")
    return FocusTable(1.0 / dist[:last], np.array(zs[:last]))


def table_from_arrays(diopters, sensor_z_mm, source: str = "") -> FocusTable:
    """A FocusTable from stored arrays (e.g. a PSF surrogate's metadata), checked: ascending diopters."""
    d, z = np.asarray(diopters, dtype=np.float64), np.asarray(sensor_z_mm, dtype=np.float64)
    if d.ndim != 1 or d.shape != z.shape or len(d) < 2 or np.any(np.diff(d) <= 0):
        raise ValueError(f"{source or 'focus table'}: needs two equal-length arrays, diopters ascending")
    return FocusTable(d, z)
