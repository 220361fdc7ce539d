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

from training.lens.schema import Lens, Surface

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


def _intersect(s: Surface, zv: float, o: torch.Tensor, d: torch.Tensor, tol: float):
    """Distance t along each ray to the surface with vertex at z = zv, and a validity mask."""
    px, py, pz = o[..., 0], o[..., 1], o[..., 2] - zv
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    c = s.curvature_per_mm
    if s.kind == "ideal" or (s.is_spherical and c == 0.0):
        t = -pz / dz
        return t, torch.isfinite(t)
    if s.is_spherical:
        # c|p + t d|^2 - 2 (pz + t dz) = 0; the root continuous with the vertex-plane intersection.
        b = c * (px * dx + py * dy + pz * dz) - dz
        cc = c * (px * px + py * py + pz * pz) - 2.0 * pz
        disc = b * b - c * cc
        ok = disc >= 0
        den = -b + torch.sqrt(torch.clamp(disc, min=0.0)) * torch.where(b < 0, 1.0, -1.0)
        t = cc / den
        return t, ok & torch.isfinite(t)
    # Conic / asphere: Newton on f(t) = z(t) - sag(r(t)^2), from the vertex plane.
    t = -pz / dz
    ok = torch.isfinite(t)
    t = torch.where(ok, t, torch.zeros_like(t))
    converged = torch.zeros_like(ok)
    for _ in range(NEWTON_MAX_ITERS):
        x, y, z = px + t * dx, py + t * dy, pz + t * dz
        r2 = x * x + y * y
        sag, dsag, defined = _sag_and_slope(s, r2)
        f = z - sag
        fp = dz - dsag * 2.0 * (x * dx + y * dy)
        step = f / fp
        t = t - torch.where(converged, torch.zeros_like(step), step)
        converged = converged | (step.abs() < tol)
        if bool(converged.all()):
            break
    x, y = px + t * dx, py + t * dy
    _, _, defined = _sag_and_slope(s, x * x + y * y)
    return t, ok & converged & defined & torch.isfinite(t)


def _normal(s: Surface, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Unit surface normal (pointing towards +z) at (x, y) on the surface."""
    _, dz, _ = _sag_and_slope(s, x * x + y * y)
    nx, ny = -2.0 * x * dz, -2.0 * y * dz
    n = torch.stack([nx, ny, torch.ones_like(nx)], dim=-1)
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True)


def _refract(d: torch.Tensor, n: torch.Tensor, eta: float):
    """Vector Snell's law; n is the unit normal oriented along the ray (d.n > 0). Returns (d', ok)."""
    cos_i = (d * n).sum(-1, keepdim=True)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    ok = (sin2_t <= 1.0).squeeze(-1)  # otherwise total internal reflection
    cos_t = torch.sqrt(torch.clamp(1.0 - sin2_t, min=0.0))
    out = eta * d + (cos_t - eta * cos_i) * n
    return out, ok


def trace(
    lens: Lens,
    rays: Rays,
    wavelength_nm: float | None = None,
    sensor_z_mm: float | None = None,
    record: bool = False,
    to_sensor: bool = True,
) -> TraceResult:
    """Trace `rays` (in object space, before the first surface) through every surface to the sensor plane.

    sensor_z_mm: sensor plane z (default: the prescription's nominal sensor position).
    record: also return the intercept at every surface (for layouts and cross-checks).
    """
    w = wavelength_nm or lens.design_wavelength_nm
    idx = lens.indices(w)
    dtype = rays.o.dtype
    tol = NEWTON_TOL_MM.get(dtype, 1e-6)
    o, d, valid = rays.o, rays.d, rays.valid.clone()
    hits = [] if record else None
    for i, (s, zv) in enumerate(zip(lens.surfaces, lens.vertex_z_mm)):
        t, ok = _intersect(s, zv, o, d, tol)
        valid = valid & ok & (t > -1e-9)
        t = torch.where(valid, t, torch.zeros_like(t))
        o = o + t.unsqueeze(-1) * d
        r2 = o[..., 0] ** 2 + o[..., 1] ** 2
        valid = valid & (r2 <= s.semi_diameter_mm**2)
        if record:
            hits.append(o)
        if s.kind == "ideal":
            # Perfect paraxial lens: slopes change by -h/f, which images every object plane without aberration.
            tx = d[..., 0] / d[..., 2] - o[..., 0] / s.focal_length_mm
            ty = d[..., 1] / d[..., 2] - o[..., 1] / s.focal_length_mm
            nd = torch.stack([tx, ty, torch.ones_like(tx)], dim=-1)
            d = nd / torch.linalg.vector_norm(nd, dim=-1, keepdim=True)
            continue
        n1, n2 = idx[i], idx[i + 1]
        if n1 == n2 and s.curvature_per_mm == 0 and s.is_spherical:
            continue  # a flat surface between equal media (e.g. the stop) does not bend rays
        normal = _normal(s, o[..., 0], o[..., 1])
        d, ok = _refract(d, normal, n1 / n2)
        valid = valid & ok
    if to_sensor:
        zs = lens.nominal_sensor_z_mm if sensor_z_mm is None else sensor_z_mm
        t = (zs - o[..., 2]) / d[..., 2]
        o = o + t.unsqueeze(-1) * d
    return TraceResult(Rays(o, d, valid), hits)


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
    from training.optics.paraxial import paraxial_data

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
