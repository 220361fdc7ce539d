"""A lens that differs from its prescription (manufacturing tolerance): one air gap longer or shorter, or one
element (a cemented group moves as one) decentred. Traced through the real prescription, it changes the lens's
best-focus surface: field curvature (a gap) and an asymmetric, tilted focal surface (a decentre).

`focal_surface_change_mm` gives, for field points, how far the best-focus surface of the perturbed lens moves
(mm along the axis, + away from the lens) against the nominal lens's, with the camera focused on axis (the axis
term removed: autofocus puts the sensor where the centre is sharp). `sensitivity_table` tabulates it per unit
perturbation for every air gap and element, for the torch-free `lens_tolerance` effect
(`aat_deploy/render/effects/lens_tolerance.py`), which reads it from `tolerance_<key>.json` next to the lens's PSF
surrogate (`scripts/lens_tolerance_table.py`).

Best focus of a field point: the plane of minimum RMS spot about the centroid (the circle of least confusion),
of rays from the object point over a square grid filling the paraxial entrance pupil (symmetric, so mirrored
field points see mirrored rays).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from aat_deploy.lens.schema import Lens
from aat_deploy.render.effects.lens_tolerance import air_gaps, elements, optics_key
from training.optics.focus import best_focus_shift_mm, focus
from training.optics.trace import _intersect, _refract, rays_through_pupil, uniform_disk_grid
from training.psf.geometry import object_points_mm

TABLE_FORMAT = "aat-tolerance-v1"


def with_gap(lens: Lens, surface: int, delta_mm: float) -> Lens:
    """The lens with the thickness after `surface` changed by delta_mm (the rest of the lens moves with it)."""
    surfs = list(lens.surfaces)
    surfs[surface] = dataclasses.replace(surfs[surface], thickness_mm=surfs[surface].thickness_mm + delta_mm)
    return dataclasses.replace(lens, surfaces=tuple(surfs))


def trace_decentred(lens: Lens, x, y, z, dx, dy, dz, sensor_z_mm: float, offsets: dict[int, tuple[float, float]],
                    wavelength_nm: float | None = None):
    """`training.optics.trace.trace_components` with surfaces moved sideways: offsets {surface: (ox, oy)} mm.
    Returns x, y at the plane sensor_z_mm, the direction components and the valid mask."""
    indices = lens.indices(wavelength_nm or lens.design_wavelength_nm)
    valid = torch.ones_like(x, dtype=torch.bool)
    for i, (s, zv) in enumerate(zip(lens.surfaces, lens.vertex_z_mm)):
        ox, oy = offsets.get(i, (0.0, 0.0))
        lx, ly = x - ox, y - oy  # ray in the surface's own frame
        t, ok = _intersect(s, zv, lx, ly, z, dx, dy, dz, 1e-12)
        valid = valid & ok & (t > -1e-9)
        t = torch.where(valid, t, torch.zeros_like(t))
        lx, ly, z = lx + t * dx, ly + t * dy, z + t * dz
        valid = valid & (lx * lx + ly * ly <= s.semi_diameter_mm ** 2)
        n1, n2 = indices[i], indices[i + 1]
        if not (n1 == n2 and s.curvature_per_mm == 0 and s.is_spherical):
            dx, dy, dz, ok = _refract(s, lx, ly, dx, dy, dz, n1 / n2)
            valid = valid & ok
        x, y = lx + ox, ly + oy
    t = (sensor_z_mm - z) / dz
    return x + t * dx, y + t * dy, dx, dy, dz, valid


def best_focus_z_mm(lens: Lens, field_xy: np.ndarray, focus_m: float, sensor_z_mm: float,
                    offsets: dict | None = None, n_rays: int = 1024) -> np.ndarray:
    """(N,) z (mm from the first vertex) of the min-RMS image plane of object points at normalised field
    field_xy (N, 2) (x right, y up, upright image) and focus_m metres from the sensor plane at sensor_z_mm."""
    pupil = uniform_disk_grid(max(int(math.sqrt(4 * n_rays / math.pi)), 5))  # symmetric: +-x see the same rays
    out = []
    for fx_, fy_ in np.asarray(field_xy, np.float64):
        obj = object_points_mm(lens, np.array([fx_]), np.array([fy_]), np.array([focus_m]), sensor_z_mm)[0]
        rays = rays_through_pupil(lens, pupil, obj)
        x, y, dx, dy, dz, valid = trace_decentred(lens, *rays.o.unbind(-1), *rays.d.unbind(-1), sensor_z_mm,
                                                  offsets or {})
        xy = torch.stack([x, y], -1)
        slopes = torch.stack([dx / dz, dy / dz], -1)
        out.append(sensor_z_mm + best_focus_shift_mm(xy, slopes, valid) if int(valid.sum()) > 8 else math.nan)
    return np.array(out)


def focal_surface_change_mm(lens: Lens, field_xy: np.ndarray, focus_m: float, gap: int | None = None,
                            gap_mm: float = 0.0, element: int | None = None,
                            decentre_mm: tuple[float, float] = (0.0, 0.0), n_rays: int = 1024) -> np.ndarray:
    """(N,) how far the perturbed lens's best-focus surface moves (mm, + away from the lens) at field_xy against
    the nominal lens's, each relative to its own value on axis (the camera focuses on the centre)."""
    z_s = focus(lens, focus_m)
    pts = np.concatenate([np.zeros((1, 2)), np.asarray(field_xy, np.float64)])
    nominal = best_focus_z_mm(lens, pts, focus_m, z_s, n_rays=n_rays)
    pert, offsets = lens, {}
    if gap is not None:
        pert = with_gap(lens, gap, gap_mm)
    if element is not None:
        offsets = {i: tuple(map(float, decentre_mm)) for i in elements(lens)[element]}
    z_p = focus(pert, focus_m) if gap is not None else z_s
    changed = best_focus_z_mm(pert, pts, focus_m, z_p, offsets, n_rays)
    return (changed[1:] - changed[0]) - (nominal[1:] - nominal[0])


def sensitivity_table(lens: Lens, unit_mm: float = 0.05, focus_m=(0.5, 1.5, 20.0), nx: int = 7, ny: int = 5,
                      n_rays: int = 1024, progress=None) -> dict:
    """Focal-surface changes per unit_mm of every air gap and of every element's decentre along x and y, on an
    (ny, nx) grid of normalised field positions (x, y in [-1, 1]) at the focus distances `focus_m`: the
    `lens_tolerance` effect's table (JSON-ready)."""
    xs, ys = np.linspace(-1, 1, nx), np.linspace(-1, 1, ny)
    grid = np.stack(np.meshgrid(xs, ys, indexing="xy"), -1).reshape(-1, 2)
    say = progress or (lambda msg: None)
    perts = []
    for g in air_gaps(lens):
        say(f"air gap after surface {g}")
        maps = [focal_surface_change_mm(lens, grid, f, gap=g, gap_mm=unit_mm, n_rays=n_rays).reshape(ny, nx)
                for f in focus_m]
        perts.append({"kind": "gap", "surface": g, "dz_mm": np.array(maps).tolist()})
    for e, surfs in enumerate(elements(lens)):
        for axis, dec in (("x", (unit_mm, 0.0)), ("y", (0.0, unit_mm))):
            say(f"element {e} (surfaces {surfs[0]}-{surfs[-1]}) decentred along {axis}")
            maps = [focal_surface_change_mm(lens, grid, f, element=e, decentre_mm=dec, n_rays=n_rays).reshape(ny, nx)
                    for f in focus_m]
            perts.append({"kind": "decentre", "element": e, "surfaces": surfs, "axis": axis,
                          "dz_mm": np.array(maps).tolist()})
    return {"format": TABLE_FORMAT, "lens": lens.name, "optics_key": optics_key(lens), "unit_mm": unit_mm,
            "diopters": [1.0 / f for f in focus_m], "field_x": xs.tolist(), "field_y": ys.tolist(),
            "perturbations": perts}


_TRACED: dict = {}  # (optics key, kind, index, axis) -> traced map per unit


def traced_perturbation(lens: Lens, kind: str, idx: int, axis: str, amount: float):
    """The `lens_tolerance` effect's map of one perturbation when it has no table (the extension
    `tolerance_tracer`): traced on the table's default grid per unit_mm = 0.05, cached per lens. Returns
    (amount / unit, dz (F, ny, nx) mm per unit, diopters, field x, field y)."""
    unit = 0.05
    key = (optics_key(lens), kind, idx, axis)
    if key not in _TRACED:
        xs, ys, foci = np.linspace(-1, 1, 7), np.linspace(-1, 1, 5), (0.5, 1.5, 20.0)
        grid = np.stack(np.meshgrid(xs, ys, indexing="xy"), -1).reshape(-1, 2)
        kw = {"gap": idx, "gap_mm": unit} if kind == "gap" else \
            {"element": idx, "decentre_mm": (unit, 0.0) if axis == "x" else (0.0, unit)}
        dz = np.array([focal_surface_change_mm(lens, grid, f, **kw).reshape(5, 7) for f in foci])
        _TRACED[key] = (dz, [1.0 / f for f in foci], xs.tolist(), ys.tolist())
    dz, d, fx, fy = _TRACED[key]
    return amount / unit, dz, d, fx, fy
