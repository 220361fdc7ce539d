"""Sequential real-ray tracing through a Lens, vectorised over rays with torch (float64 or float32).

Conventions: positions in mm, z from the first vertex, +z towards the sensor; directions are unit vectors.
A ray is lost (valid = False) when it misses a surface, lands outside a semi-diameter (vignetting),
is totally internally reflected, or an asphere intersection does not converge. Lost rays keep being
propagated with harmless numbers so shapes stay fixed; always mask with `valid`.

Intersection: analytic for spheres and planes; Newton's method on t for conics and even aspheres, started
from the vertex plane, stopped when every |dt| < `NEWTON_TOL_MM` (float64: 1e-12 mm, float32: 1e-6 mm)
or after `NEWTON_MAX_ITERS` (rays not converged by then are lost).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from aat_deploy.lens.schema import Lens, Surface

NEWTON_MAX_ITERS = 30
NEWTON_TOL_MM = {torch.float64: 1e-12, torch.float32: 1e-6}


@dataclass
class Rays:
    """A bundle of rays: origins o (..., 3) mm, unit directions d (..., 3), valid mask (...)."""

    o: torch.Tensor
    d: torch.Tensor
    valid: torch.Tensor

    def __post_init__(self):
        if self.valid is None:
            self.valid = torch.ones(self.o.shape[:-1], dtype=torch.bool, device=self.o.device)


@dataclass
class TraceResult:
    """Rays at the end plane; `hits` holds the (..., 3) intercept at every surface when recorded."""

    rays: Rays
    hits: list[torch.Tensor] | None = None

    @property
    def xy(self) -> torch.Tensor:
        return self.rays.o[..., :2]


def _sag_and_slope(s: Surface, r2: torch.Tensor):
    """Sag z(r2) and dz/d(r2) of a conic + even asphere; also a mask of where the conic is defined."""
    c, k = s.curvature_per_mm, s.conic
    arg = 1.0 - (1.0 + k) * c * c * r2
    ok = arg > 0
    root = torch.sqrt(torch.clamp(arg, min=1e-30))
    z = c * r2 / (1.0 + root)
    dz = c / (2.0 * root)
    p = torch.ones_like(r2)
    for i, a in enumerate(s.asphere_from_r2, start=1):
        if a:
            dz = dz + i * a * p  # d/d(r2) of a r2^i = i a r2^(i-1)
        p = p * r2
        if a:
            z = z + a * p
    return z, dz, ok


def _intersect(s: Surface, zv: float, px, py, pz, dx, dy, dz, tol: float, fixed_iters: int | None = None):
    """Distance t along each ray (components px.., dx..) to the surface with vertex at z = zv, and a mask.

    fixed_iters: run exactly this many Newton steps with no data-dependent exit (for torch.compile); rays
    whose last step still exceeds `tol` are lost.
    """
    pz = pz - zv
    c = s.curvature_per_mm
    if s.kind == "ideal" or (s.is_spherical and c == 0.0):
        t = -pz / dz
        return t, torch.isfinite(t)
    if s.is_spherical:
        # c|p + t d|^2 - 2 (pz + t dz) = 0; the root continuous with the vertex-plane intersection.
        b = c * (px * dx + py * dy + pz * dz) - dz
        cc = c * (px * px + py * py + pz * pz) - 2.0 * pz
        disc = b * b - c * cc
        root = torch.sqrt(torch.clamp(disc, min=0.0))
        t = cc / (-b + torch.where(b < 0, root, -root))
        return t, (disc >= 0) & torch.isfinite(t)
    # Conic / asphere: Newton on f(t) = z(t) - sag(r(t)^2), from the vertex plane.
    t = -pz / dz
    ok = torch.isfinite(t)
    t = torch.where(ok, t, torch.zeros_like(t))

    def newton_step(t):
        x, y = px + t * dx, py + t * dy
        sag, dsag, _ = _sag_and_slope(s, x * x + y * y)
        return (pz + t * dz - sag) / (dz - dsag * 2.0 * (x * dx + y * dy))

    if fixed_iters is not None:
        step = t
        for _ in range(fixed_iters):
            step = newton_step(t)
            t = t - step
        converged = step.abs() < tol
    else:
        converged = torch.zeros_like(ok)
        for _ in range(NEWTON_MAX_ITERS):
            step = newton_step(t)
            t = t - torch.where(converged, torch.zeros_like(step), step)
            converged = converged | (step.abs() < tol)
            if bool(converged.all()):
                break
    x, y = px + t * dx, py + t * dy
    _, _, defined = _sag_and_slope(s, x * x + y * y)
    return t, ok & converged & defined & torch.isfinite(t)


def _refract(s: Surface, x, y, dx, dy, dz, eta: float):
    """Vector Snell's law at (x, y) on surface s; the normal is oriented along +z (d.n > 0 for our rays).
    Returns the new direction components and a mask (False = total internal reflection)."""
    _, slope, _ = _sag_and_slope(s, x * x + y * y)
    nx, ny = -2.0 * x * slope, -2.0 * y * slope
    inv = torch.rsqrt(nx * nx + ny * ny + 1.0)
    nx, ny, nz = nx * inv, ny * inv, inv
    cos_i = dx * nx + dy * ny + dz * nz
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    cos_t = torch.sqrt(torch.clamp(1.0 - sin2_t, min=0.0))
    k = cos_t - eta * cos_i
    return eta * dx + k * nx, eta * dy + k * ny, eta * dz + k * nz, sin2_t <= 1.0


def trace(
    lens: Lens,
    rays: Rays,
    wavelength_nm: float | None = None,
    sensor_z_mm: float | None = None,
    record: bool = False,
    to_sensor: bool = True,
    fixed_iters: int | None = None,
) -> TraceResult:
    """Trace `rays` (in object space, before the first surface) through every surface to the sensor plane.

    sensor_z_mm: sensor plane z (default: the prescription's nominal sensor position).
    record: also return the intercept at every surface (for layouts and cross-checks).
    fixed_iters: a fixed Newton step count for aspheres (branch-free, compilable); None = iterate to `tol`.
    """
    w = wavelength_nm or lens.design_wavelength_nm
    zs = lens.nominal_sensor_z_mm if sensor_z_mm is None else sensor_z_mm
    x, y, z, dx, dy, dz, valid, hits = trace_components(
        lens, lens.indices(w), *rays.o.unbind(-1), *rays.d.unbind(-1), rays.valid,
        zs if to_sensor else None, NEWTON_TOL_MM.get(rays.o.dtype, 1e-6), fixed_iters, record,
    )
    return TraceResult(Rays(torch.stack([x, y, z], -1), torch.stack([dx, dy, dz], -1), valid), hits)


def trace_components(lens: Lens, indices, x, y, z, dx, dy, dz, valid, sensor_z_mm, tol, fixed_iters=None,
                     record=False):
    """The tracing loop on separate x, y, z, dx, dy, dz tensors (fuses well; torch.compile-friendly with
    `fixed_iters` set and record=False). `indices`: refractive index before surface 0 then after each."""
    hits = [] if record else None
    for i, (s, zv) in enumerate(zip(lens.surfaces, lens.vertex_z_mm)):
        t, ok = _intersect(s, zv, x, y, z, dx, dy, dz, tol, fixed_iters)
        valid = valid & ok & (t > -1e-9)
        t = torch.where(valid, t, torch.zeros_like(t))
        x, y, z = x + t * dx, y + t * dy, z + t * dz
        valid = valid & (x * x + y * y <= s.semi_diameter_mm**2)
        if record:
            hits.append(torch.stack([x, y, z], -1))
        if s.kind == "ideal":
            # Perfect paraxial lens: slopes change by -h/f, which images every object plane without aberration.
            tx = dx / dz - x / s.focal_length_mm
            ty = dy / dz - y / s.focal_length_mm
            inv = torch.rsqrt(tx * tx + ty * ty + 1.0)
            dx, dy, dz = tx * inv, ty * inv, inv
            continue
        n1, n2 = indices[i], indices[i + 1]
        if n1 == n2 and s.curvature_per_mm == 0 and s.is_spherical:
            continue  # a flat surface between equal media (e.g. the stop) does not bend rays
        dx, dy, dz, ok = _refract(s, x, y, dx, dy, dz, n1 / n2)
        valid = valid & ok
    if sensor_z_mm is not None:
        t = (sensor_z_mm - z) / dz
        x, y, z = x + t * dx, y + t * dy, z + t * dz
    return x, y, z, dx, dy, dz, valid, hits


# ------------------------------------------------------------------------------------------------
# Ray generation
# ------------------------------------------------------------------------------------------------
def start_plane_z_mm(lens: Lens) -> float:
    """A plane in front of the whole first surface where object-space rays are started."""
    s0 = lens.surfaces[0]
    return min(0.0, s0.sag(s0.semi_diameter_mm**2)) - 1.0


def rays_through_pupil(
    lens: Lens,
    pupil_xy: torch.Tensor,
    object_point_mm: torch.Tensor | None = None,
    field_angle_rad: tuple[float, float] = (0.0, 0.0),
    pupil_radius_mm: float | None = None,
    pupil_z_mm: float | None = None,
) -> Rays:
    """Rays aimed at points of the (paraxial) entrance pupil, started just in front of the lens.

    pupil_xy: (..., 2) normalised pupil coordinates (unit disk = the pupil edge).
    object_point_mm: (..., 3) finite object point(s) broadcastable with pupil_xy; None = object at infinity
        with chief-ray angle `field_angle_rad` = (angle in x-z plane, angle in y-z plane).
    pupil_radius_mm / pupil_z_mm: default to the paraxial entrance pupil.
    """
    from aat_deploy.optics.paraxial import paraxial_data

    if pupil_radius_mm is None or pupil_z_mm is None:
        px = paraxial_data(lens)
        pupil_radius_mm = px.entrance_pupil_mm / 2.0 if pupil_radius_mm is None else pupil_radius_mm
        pupil_z_mm = px.entrance_pupil_z_mm if pupil_z_mm is None else pupil_z_mm
    dtype, dev = pupil_xy.dtype, pupil_xy.device
    target = torch.cat(
        [pupil_xy * pupil_radius_mm, torch.full_like(pupil_xy[..., :1], pupil_z_mm)], dim=-1
    )
    if object_point_mm is None:
        tx, ty = torch.tan(torch.tensor(field_angle_rad, dtype=torch.float64)).tolist()
        d = torch.tensor([tx, ty, 1.0], dtype=dtype, device=dev)
        d = (d / torch.linalg.vector_norm(d)).expand_as(target)
    else:
        d = target - object_point_mm.to(dtype)
        d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    z0 = start_plane_z_mm(lens)
    o = target + ((z0 - target[..., 2]) / d[..., 2]).unsqueeze(-1) * d
    return Rays(o, d, torch.ones(o.shape[:-1], dtype=torch.bool, device=dev))


def uniform_disk_grid(n_across: int, dtype=torch.float64) -> torch.Tensor:
    """Square grid of n_across x n_across points over [-1, 1]^2 kept inside the unit disk: (M, 2)."""
    g = torch.linspace(-1.0, 1.0, n_across, dtype=dtype)
    x, y = torch.meshgrid(g, g, indexing="xy")
    p = torch.stack([x.reshape(-1), y.reshape(-1)], dim=-1)
    return p[(p * p).sum(-1) <= 1.0 + 1e-12]


def stratified_disk(n: int, generator: torch.Generator | None = None, dtype=torch.float64) -> torch.Tensor:
    """n points in the unit disk, one jittered sample per cell of a polar grid of equal-area cells: (n, 2).

    Rings are equally spaced in radius with cell counts proportional to ring area (2i + 1), and r^2 is
    uniform within each ring, so the density is uniform; jitter removes grid aliasing.
    """
    n_rings = max(1, int(round((n / 3.14159) ** 0.5)))
    counts = torch.tensor([2 * i + 1 for i in range(n_rings)], dtype=torch.float64)
    counts = torch.floor(counts / counts.sum() * n).long()
    counts[-1] += n - int(counts.sum())
    ring = torch.repeat_interleave(torch.arange(n_rings), counts)
    start = torch.cumsum(counts, 0) - counts
    k = torch.arange(n) - start[ring]
    u = torch.rand(n, 2, generator=generator, dtype=torch.float64)
    r2 = (ring**2 + u[:, 0] * (2 * ring + 1)) / n_rings**2  # uniform in r^2 within [i, i+1] / n_rings
    phi = 2 * torch.pi * (k + u[:, 1]) / counts[ring]
    r = torch.sqrt(r2)
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi)], dim=-1).to(dtype)
