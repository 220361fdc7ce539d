"""Best focus across the field: for a frame focused at F, which object distance is sharpest at field radius r.

A frame focused at F has its sensor where an on-axis point F metres away is in best focus (`training.optics.focus`:
the smallest RMS spot about the centroid). At a field radius r the same sensor is in best focus for another
object distance D(r, F): the one whose image there has its smallest RMS spot exactly on that sensor plane. That is
what depth from focus needs: a pixel at radius r is sharpest in the frame whose sensor sits at its image's best
focus. Off axis the min-RMS plane lies between the sagittal and tangential foci (the circle of least confusion
under astigmatism).

The field point for radius r is on the sensor diagonal, x = y = r in the normalised image coordinates of
`training.psf.geometry` (a rotationally symmetric lens: any direction gives the same), at the object direction that
convention names, traced with the PSF tracer's pupil sampling (stratified over rho x the entrance pupil, which
holds every ray that gets through; vignetted rays drop out). D is found by the secant method in diopters, where
the image-side best-focus shift is nearly linear (longitudinal magnification).

`best_focus_map(lens)` tabulates D over r and F into the runtime's `aat_deploy.focus.bestfocus.BestFocusMap`.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from aat_deploy.focus.bestfocus import BestFocusMap
from aat_deploy.lens.schema import Lens
from aat_deploy.optics.focus_table import FocusTable
from aat_deploy.optics.paraxial import paraxial_data
from training.optics.focus import best_focus_shift_mm
from training.optics.trace import Rays, start_plane_z_mm, stratified_disk, trace
from training.psf.geometry import focus_table, object_points_mm

N_RAYS = 2048
TOL_MM = 1e-5  # image-side: 10 nm, far below the depth of focus


def _pupil(lens: Lens, n_rays: int) -> tuple[torch.Tensor, float]:
    from training.psf.raytrace import pupil_sampling_scale

    rho = pupil_sampling_scale(lens, lens.design_wavelength_nm)
    return stratified_disk(n_rays, torch.Generator().manual_seed(0)), rho * paraxial_data(lens).entrance_pupil_mm / 2


def image_shift_mm(lens: Lens, r: float, object_m: float, sensor_z_mm: float, pupil=None, n_rays: int = N_RAYS,
                   wavelength_nm: float | None = None, direction=None) -> float:
    """Axial distance (mm, + = away from the lens) from the sensor plane at `sensor_z_mm` to the min-RMS image
    plane of the point at normalised field radius r (on the diagonal) `object_m` metres from that sensor.
    direction: a unit vector (x, y) on the sensor: the plane where the rays' spread along it alone is least
    instead (along the radial direction: the tangential focus; across it: the sagittal focus). NaN if every ray
    is vignetted."""
    pupil_xy, pupil_r = pupil or _pupil(lens, n_rays)
    obj = object_points_mm(lens, r, r, object_m, sensor_z_mm)[0]
    # Rays from the object point through the pupil; a negative distance is a virtual object beyond infinity
    # (converging rays aimed at a point behind the lens), which best focus off axis can need (field curvature).
    z_ep = paraxial_data(lens).entrance_pupil_z_mm
    target = torch.cat([pupil_xy * pupil_r, torch.full_like(pupil_xy[:, :1], z_ep)], -1)
    d = target - obj
    d = d * torch.sign(d[:, 2:3])
    d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    o = target + ((start_plane_z_mm(lens) - z_ep) / d[:, 2:3]) * d
    res = trace(lens, Rays(o, d, torch.ones(o.shape[0], dtype=torch.bool)), wavelength_nm, sensor_z_mm=sensor_z_mm)
    valid = res.rays.valid
    if int(valid.sum()) < 8:
        return float("nan")
    d = res.rays.d
    xy, slopes = res.rays.o[:, :2], d[:, :2] / d[:, 2:3]
    if direction is not None:
        u = torch.as_tensor(np.asarray(direction, np.float64), dtype=xy.dtype).reshape(2, 1)
        xy, slopes = xy @ u, slopes @ u
    return best_focus_shift_mm(xy, slopes, valid)


def in_focus_diopters(lens: Lens, r: float, sensor_z_mm: float, start_diopters: float, pupil=None,
                      wavelength_nm: float | None = None, max_iter: int = 30) -> float:
    """Object diopters (1/m from the sensor) whose image at radius r has its min-RMS plane on the sensor at
    `sensor_z_mm`; the secant method from `start_diopters`. Negative = beyond infinity (no real object is in best
    focus there: the lens's field curvature at a far focus). NaN where the field is vignetted."""
    pupil = pupil or _pupil(lens, N_RAYS)

    def g(dpt: float) -> float:
        dpt = dpt if abs(dpt) > 1e-9 else 1e-9  # infinity: as good as 1000 km
        return image_shift_mm(lens, r, 1.0 / dpt, sensor_z_mm, pupil, wavelength_nm=wavelength_nm)

    d0, d1 = start_diopters, start_diopters + 0.02
    g0, g1 = g(d0), g(d1)
    for _ in range(max_iter):
        if not (math.isfinite(g0) and math.isfinite(g1)) or g1 == g0:
            return float("nan")
        d2 = d1 - g1 * (d1 - d0) / (g1 - g0)
        d0, g0 = d1, g1
        d1, g1 = d2, g(d2)
        if abs(g1) < TOL_MM:
            return d1
    return float("nan")


def best_focus_map(lens: Lens, radii=None, focus_diopters=None, table: FocusTable | None = None,
                   wavelength_nm: float | None = None, progress: bool = False) -> BestFocusMap:
    """The traced map over `radii` (default 13 radii even in r^2 over [0, 1]) and frame focus settings
    `focus_diopters` (default 33 even in diopters over the lens's focus table, 0.2-100 m or its nearest focus).
    Vignetted points (NaN) take the value of the nearest traced radius."""
    table = table or focus_table(lens, wavelength_nm=wavelength_nm)
    radii = np.sqrt(np.linspace(0, 1, 13)) if radii is None else np.asarray(radii, np.float64)
    if focus_diopters is None:
        focus_diopters = np.linspace(table.diopters[0], table.diopters[-1], 33)
    fd = np.asarray(focus_diopters, np.float64)
    pupil = _pupil(lens, N_RAYS)
    out = np.full((radii.size, fd.size), np.nan)
    it = range(fd.size)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="best-focus map (focus settings)", unit="focus")
    for j in it:
        zs = float(table(1.0 / fd[j]))
        start = fd[j]
        for i, r in enumerate(radii):
            out[i, j] = in_focus_diopters(lens, float(r), zs, start, pupil, wavelength_nm)
            if math.isfinite(out[i, j]):
                start = out[i, j]
    for j in range(fd.size):  # vignetted radii: the nearest traced one
        col = out[:, j]
        ok = np.isfinite(col)
        if not ok.any():
            raise RuntimeError(f"{lens.name}: no traceable field point at focus {1 / fd[j]:.3g} m")
        col[~ok] = np.interp(radii[~ok], radii[ok], col[ok])
    s = lens.sensor
    notes = {"definition": "object diopters whose image at field radius r has its smallest RMS spot (about the "
                           "centroid) on the sensor of a frame focused (on axis, same definition) at focus_diopters",
             "rays": N_RAYS, "wavelength_nm": float(wavelength_nm or lens.design_wavelength_nm),
             "field": "diagonal, x = y = r (training.psf.geometry normalised image coordinates)",
             "made_by": "training.optics.field_focus.best_focus_map"}
    return BestFocusMap(radii, fd, out, (s.width_mm, s.height_mm), lens_name=lens.name,
                        lens_hash=lens.prescription_hash(), notes=notes)


def coarse_best_focus_map(lens: Lens, progress: bool = False) -> BestFocusMap:
    """A quick, uncalibrated map for a lens that has none stored: 7 radii x 9 focus settings (about a tenth of
    `aat-lens focus-map`'s time). The runtime reaches it as the extension `best_focus_tracer`
    (`aat_deploy.extensions`) when the train extra is installed."""
    t = focus_table(lens)
    return best_focus_map(lens, radii=np.sqrt(np.linspace(0, 1, 7)),
                          focus_diopters=np.linspace(t.diopters[0], t.diopters[-1], 9), table=t, progress=progress)
