"""Where a PSF's object point is, and where the sensor sits for a focus distance.

Field coordinates (x, y) in [-1, 1] are normalised positions on the upright image (x right, y up; +-1 = the
sensor edges). They name an object-space **direction** seen from the entrance pupil:
    tan(theta_x) = x * W/2 / EFL,  tan(theta_y) = y * H/2 / EFL
so that an ideal lens focused at infinity images it exactly at (x * W/2, y * H/2). The object point is on that
ray at `depth_m` metres from the sensor plane (the same sensor-referenced distance as focus distances).
A real lens lands the point elsewhere by its distortion and focus breathing; PSFs are centred on the real
chief ray's hit (see `training.psf.raytrace`), and the landing offset is a separate, optional geometric effect.

Depths and focus distances are sampled and encoded in diopters (1/m), never linearly in metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_data, paraxial_focus_z_mm

# torch (the real-ray focus search, object points as tensors) is imported where it is needed: the focus table,
# field geometry and thin-lens blur serve the torch-free runtime too (`aat_deploy.twin`).


def diopter_grid(near_m: float, far_m: float, n: int) -> np.ndarray:
    """n distances (m) evenly spaced in diopters from near to far (inclusive)."""
    return 1.0 / np.linspace(1.0 / near_m, 1.0 / far_m, n)


@dataclass(frozen=True)
class FocusTable:
    """Sensor z (mm from the first vertex) for any focus distance, interpolated in diopters.

    `focus()` is a real-ray best-focus search (~50 ms); a dense table in diopters makes per-sample focus
    distances in training free. Interpolation error is checked against direct `focus()` in the tests.
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


@lru_cache(maxsize=16)
def _focus_table(lens: Lens, near_m: float, far_m: float, n: int, wavelength_nm: float) -> FocusTable:
    from training.optics.focus import focus  # real rays: torch

    dist = diopter_grid(near_m, far_m, n)[::-1]  # far first = ascending diopters
    zs: list[float] = []
    for d in dist:
        try:
            zs.append(focus(lens, float(d), wavelength_nm))
        except RuntimeError:
            if len(zs) < 2:
                raise
            break  # closer than the lens can focus (no sensor position images it): the table ends here
    return FocusTable(1.0 / dist[:len(zs)], np.array(zs))


def focus_table(lens: Lens, near_m: float = 0.2, far_m: float = 100.0, n: int = 129,
                wavelength_nm: float | None = None) -> FocusTable:
    """Focus table from near_m to far_m (metres from the sensor), n samples even in diopters. A lens that cannot
    focus as close as near_m (e.g. a 50 mm lens below about 4 x EFL) gets a table ending at its nearest focus.

    Default wavelength: the lens's design wavelength. A camera focuses once; PSFs traced at other wavelengths
    keep this sensor position, so their chromatic focus shift shows up as defocus."""
    return _focus_table(lens, near_m, far_m, n, wavelength_nm or lens.design_wavelength_nm)


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


def field_to_tan(lens: Lens, x, y):
    """tan(theta) of the object direction for normalised field (x, y): arrays broadcast together."""
    efl = paraxial_data(lens).efl_mm
    return (np.asarray(x) * lens.sensor.width_mm / 2 / efl, np.asarray(y) * lens.sensor.height_mm / 2 / efl)


def field_radius(lens: Lens, x, y):
    """Normalised image radius in [0, 1] (1 = the sensor corner) of field (x, y)."""
    w, h = lens.sensor.width_mm, lens.sensor.height_mm
    return np.hypot(np.asarray(x) * w / 2, np.asarray(y) * h / 2) / lens.sensor.half_diagonal_mm


def object_points_mm(lens: Lens, x, y, depth_m, sensor_z_mm) -> torch.Tensor:
    """(B, 3) object points in lens coordinates (float64) for field (x, y) at depth (m from the sensor).

    The lens inverts the image: this point lands near (-x W/2, -y H/2) on the sensor. PSFs are reported in
    upright image coordinates (sensor coordinates negated), where it appears at (+x, +y).
    """
    tx, ty = field_to_tan(lens, x, y)
    zo = np.asarray(sensor_z_mm) - 1000.0 * np.asarray(depth_m)
    z_ep = paraxial_data(lens).entrance_pupil_z_mm
    dist = z_ep - zo  # along the axis from the object plane to the entrance pupil
    pts = np.stack(np.broadcast_arrays(tx * dist, ty * dist, zo), -1).reshape(-1, 3)
    import torch

    return torch.from_numpy(np.ascontiguousarray(pts, dtype=np.float64))


def thin_lens_blur_px(lens: Lens, depth_m, focus_m) -> np.ndarray:
    """Geometric blur-disk diameter in pixels of a thin lens with this lens's EFL and entrance pupil.

    Object and focus distances are from the sensor; the thin lens sits at the image-side distance v_f from
    the sensor that focuses `focus_m`. Used to size PSF windows and for the Gaussian baseline.
    """
    p = paraxial_data(lens)
    f, epd = p.efl_mm, p.entrance_pupil_mm
    D = 1000.0 * np.asarray(focus_m, dtype=np.float64)
    # Lens-to-sensor distance v for a sensor-referenced focus distance D: u + v = D, 1/u + 1/v = 1/f.
    v_f = 2 * D * f / (D + np.sqrt(np.maximum(D * D - 4 * D * f, 0.0)))  # the smaller root, stably
    u = 1000.0 * np.asarray(depth_m, dtype=np.float64) - v_f
    v_o = 1.0 / (1.0 / f - 1.0 / np.maximum(u, f * 1.0001))
    return epd * np.abs(v_f - v_o) / v_o / lens.sensor.pixel_mm


__all__ = [
    "FocusTable", "diopter_grid", "field_radius", "field_to_tan", "focus_table", "object_points_mm",
    "paraxial_focus_table", "table_from_arrays", "thin_lens_blur_px",
]
