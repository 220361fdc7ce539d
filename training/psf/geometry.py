"""Where a PSF's object point is, and where the sensor sits for a focus distance (real rays).

Field coordinates and the object directions they name: `aat_deploy.optics.field`. The focus table's type and its
torch-free sources (paraxial, a surrogate's metadata): `aat_deploy.optics.focus_table`. Depths and focus distances
are sampled and encoded in diopters (1/m), never linearly in metres.

The runtime reaches `focus_table` through the declared extension `real_ray_focus_table` (`aat_deploy.extensions`),
so this module imports torch outright: where torch is missing, the extension is reported missing.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.field import field_to_tan
from aat_deploy.optics.focus_table import FocusTable, diopter_grid
from aat_deploy.optics.paraxial import paraxial_data
from training.optics.focus import focus

DEFAULT_NEAR_M = 0.2  # m: the focus table's nearest distance unless a surrogate's range reaches nearer


@lru_cache(maxsize=16)
def _focus_table(lens: Lens, near_m: float, far_m: float, n: int, wavelength_nm: float) -> FocusTable:
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


def focus_table(lens: Lens, near_m: float = DEFAULT_NEAR_M, far_m: float = 100.0, n: int = 129,
                wavelength_nm: float | None = None) -> FocusTable:
    """Real-ray focus table from near_m to far_m (metres from the sensor), n samples even in diopters. A lens that
    cannot focus as close as near_m (e.g. a 50 mm lens below about 4 x EFL) gets a table ending at its nearest
    focus.

    Default wavelength: the lens's design wavelength. A camera focuses once; PSFs traced at other wavelengths
    keep this sensor position, so their chromatic focus shift shows up as defocus."""
    return _focus_table(lens, near_m, far_m, n, wavelength_nm or lens.design_wavelength_nm)


def focus_table_reaching(lens: Lens, near_m: float, wavelength_nm: float | None = None, n: int = 129) -> FocusTable:
    """The real-ray focus table reaching `near_m` (metres from the sensor) when that is nearer than the default
    table's DEFAULT_NEAR_M (a phone lens's working range), else the default table: every range of 0.2 m or farther
    keeps the table it always had."""
    return focus_table(lens, near_m=min(DEFAULT_NEAR_M, float(near_m)), n=n, wavelength_nm=wavelength_nm)


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
    return torch.from_numpy(np.ascontiguousarray(pts, dtype=np.float64))
