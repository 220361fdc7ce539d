"""Ray-traced PSFs: the ground truth every surrogate is fitted to and judged against.

For each object point (field x, y; depth) and focus distance:
1. the sensor sits where `focus()` puts it (from a focus table in diopters);
2. the chief ray (through the centre of the aperture stop) is found by Newton ray aiming and its sensor hit is
   the PSF's reference point (kernel centre);
3. `n_rays` rays from the point fill the entrance pupil: stratified samples over a disk of radius
   rho * R_EP (rho >= 1 covers pupil aberration; see `pupil_sampling_scale`), randomly rotated per PSF;
4. each surviving ray deposits energy 1 / n_in, n_in = the number of samples of the pattern inside the paraxial
   EP disk (its share of the on-axis pupil area, a ratio estimator: an unvignetted on-axis point gets exactly 1),
   bilinearly into the 4 nearest cells (`kernel.splat_bilinear`). Lost rays (vignetting) carry no energy:
   nothing is renormalised.

Everything is reported in upright image coordinates (sensor coordinates negated, y up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import torch

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.focus_table import FocusTable
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.psf.kernel import KernelSpec
from training.devices.select import on_cpu, resolve_device
from training.optics.trace import start_plane_z_mm, stratified_disk, trace_components, uniform_disk_grid
from training.psf.geometry import focus_table, object_points_mm
from training.psf.splat import splat_bilinear

DEFAULT_WAVELENGTH_NM = 589.0
FLOAT32_NEWTON_TOL_MM = 1e-4  # 0.1 um: far below a pixel, above float32 rounding at lens scale
FIXED_NEWTON_ITERS = 6


@dataclass
class PSFBatch:
    kernels: torch.Tensor  # (B, k, k) energy per cell
    scale: np.ndarray  # (B,) cell size in pixels
    energy: np.ndarray  # (B,) energy reaching the sensor (all rays), <= ~1
    center_mm: np.ndarray  # (B, 2) chief-ray hit, upright image coordinates (x right, y up), mm
    sensor_z_mm: np.ndarray  # (B,)

    @property
    def energy_in_window(self) -> np.ndarray:
        """Fraction of the arriving energy that lies inside the window."""
        inside = self.kernels.sum((-1, -2)).double().numpy()
        return np.where(self.energy > 0, inside / np.maximum(self.energy, 1e-12), 1.0)


def _stop_lens(lens: Lens) -> Lens:
    return replace(lens, surfaces=lens.surfaces[: lens.stop_index + 1])


def _rays_to_pupil(lens: Lens, obj: torch.Tensor, pupil_mm: torch.Tensor, z_ep: float):
    """Ray components (float64) from object points obj (B, 3) towards EP-plane points pupil_mm (B, N, 2)."""
    tx = pupil_mm[..., 0] - obj[:, None, 0]
    ty = pupil_mm[..., 1] - obj[:, None, 1]
    tz = (z_ep - obj[:, 2])[:, None].expand_as(tx)
    inv = torch.rsqrt(tx * tx + ty * ty + tz * tz)
    dx, dy, dz = tx * inv, ty * inv, tz * inv
    z0 = start_plane_z_mm(lens)
    t = (z0 - z_ep) / dz
    return pupil_mm[..., 0] + t * dx, pupil_mm[..., 1] + t * dy, torch.full_like(dx, z0), dx, dy, dz


def chief_ray_pupil(lens: Lens, obj: torch.Tensor, wavelength_nm: float, iters: int = 12) -> torch.Tensor:
    """EP-plane point (B, 2) mm that the chief ray from each object point passes: Newton ray aiming so the ray
    crosses the stop surface at its centre. The paraxial EP centre is the start."""
    p = paraxial_data(lens)
    sub, idx = _stop_lens(lens), lens.indices(wavelength_nm)
    b = obj.shape[0]
    aim = torch.zeros(b, 2, dtype=torch.float64)
    h = 1e-4  # mm, finite-difference step

    def stop_hit(a):
        comps = _rays_to_pupil(lens, obj, a[:, None, :], p.entrance_pupil_z_mm)
        x, y, *_ = trace_components(sub, idx, *[c[:, 0] for c in comps], torch.ones(b, dtype=torch.bool),
                                    None, 1e-12)
        return torch.stack([x, y], -1)

    # Chord method: the finite-difference Jacobian at the start is reused (the map is nearly linear), which
    # converges to 1e-10 mm in a few cheap steps.
    f0 = stop_hit(aim)
    jx = (stop_hit(aim + torch.tensor([h, 0.0], dtype=torch.float64)) - f0) / h
    jy = (stop_hit(aim + torch.tensor([0.0, h], dtype=torch.float64)) - f0) / h
    jinv = torch.linalg.inv(torch.stack([jx, jy], -1))  # (B, 2 [aim], 2 [f])
    for _ in range(iters):
        aim = aim - (jinv @ f0.unsqueeze(-1)).squeeze(-1)
        f0 = stop_hit(aim)
        if float(f0.abs().max()) < 1e-9:
            break
    return aim


@lru_cache(maxsize=16)
def pupil_sampling_scale(lens: Lens, wavelength_nm: float = DEFAULT_WAVELENGTH_NM) -> float:
    """rho: radius (in units of the paraxial EP radius) of the disk that holds every ray that gets through,
    probed over the field and a range of distances, plus 2 %. >= 1."""
    p = paraxial_data(lens)
    grid = uniform_disk_grid(81) * 1.6
    table = focus_table(lens)
    rmax = 1.0
    for r in (0.0, 0.5, 0.8, 1.0):
        for focus_m, depth_m in ((0.5, 0.5), (2.0, 20.0), (20.0, 0.5)):
            zs = float(table(focus_m))
            obj = object_points_mm(lens, r, r, depth_m, zs)  # along the diagonal: radius r
            comps = _rays_to_pupil(lens, obj, grid[None] * p.entrance_pupil_mm / 2, p.entrance_pupil_z_mm)
            *_, valid, _ = trace_components(lens, lens.indices(wavelength_nm), *[c[0] for c in comps],
                                            torch.ones(grid.shape[0], dtype=torch.bool), zs, 1e-12)
            if bool(valid.any()):
                rmax = max(rmax, float((grid[valid] ** 2).sum(-1).sqrt().max()) + 1.6 / 80)
    return 1.02 * rmax


class _Tracer:
    """Traces flat float32 ray batches to per-ray sensor planes; optionally torch.compile'd (fixed shapes)."""

    def __init__(self, lens: Lens, wavelength_nm: float, compiled: bool):
        self.lens, self.idx = lens, lens.indices(wavelength_nm)
        self.fn = self._run
        self.compiled = compiled
        if compiled:
            self.fn = torch.compile(self._run, dynamic=False, fullgraph=True)

    def _run(self, x, y, z, dx, dy, dz, sensor_z):
        valid = torch.ones_like(x, dtype=torch.bool)
        out = trace_components(self.lens, self.idx, x, y, z, dx, dy, dz, valid, sensor_z,
                               FLOAT32_NEWTON_TOL_MM, FIXED_NEWTON_ITERS)
        return out[0], out[1], out[6]

    def __call__(self, *comps):
        return self.fn(*comps)


def _chief_hit(lens: Lens, obj: torch.Tensor, wavelength_nm: float, sensor_z_mm: np.ndarray):
    """Sensor hit (x, y), each (B, 1) float32 mm, of the chief ray at `wavelength_nm` from object points (B, 3)."""
    p = paraxial_data(lens)
    aim = chief_ray_pupil(lens, obj, wavelength_nm)
    comps = _rays_to_pupil(lens, obj, aim[:, None, :], p.entrance_pupil_z_mm)
    flat = [c.reshape(-1).float() for c in comps]
    hx, hy, _ = _tracer(lens, wavelength_nm, False)(*flat, torch.from_numpy(sensor_z_mm).float())
    return hx[:, None], hy[:, None]


@lru_cache(maxsize=8)
def _tracer(lens: Lens, wavelength_nm: float, compiled: bool) -> _Tracer:
    return _Tracer(lens, wavelength_nm, compiled)


@on_cpu  # CPU-bound setup whatever the caller's default device; `device` says where the rays go
def raytrace_psfs(
    lens: Lens,
    x,
    y,
    depth_m,
    focus_m,
    spec: KernelSpec | None = None,
    n_rays: int = 2048,
    wavelength_nm: float = DEFAULT_WAVELENGTH_NM,
    seed: int = 0,
    table: FocusTable | None = None,
    compiled: bool = False,
    chunk: int = 128,
    oversample: int = 1,
    center_wavelength_nm: float | None = None,
    device: str | torch.device = "cpu",
) -> PSFBatch:
    """Ray-traced PSFs for arrays x, y (normalised field), depth_m, focus_m (m from the sensor), broadcast.

    compiled: torch.compile the tracer (about 30 s once per lens and shape, then ~5-10x faster); use it for
    datasets and benchmarks, not for a handful of PSFs.
    oversample: 2 splats on a half-cell grid of size 2k+1 (coarse cell i at fine index 2i+1) from which
        `kernel.downsample2` gives the k x k kernel exactly; surrogates that rotate kernels predict this grid.
    center_wavelength_nm: centre the kernels on the chief ray of this wavelength instead of their own, so that
        kernels of several wavelengths keep their lateral colour (the shift between their chief rays); `center_mm`
        is then that reference hit. None: each kernel is centred on its own chief ray.
    device: where the rays are traced and splatted (auto | cpu | cuda[:N] | mps; training.devices.select). Ray
        aiming and the pupil samples stay on the CPU in float64 (the same random rays on every device); the
        results come back on the CPU.
    """
    dev = resolve_device(device)
    spec = spec or KernelSpec.for_lens(lens)
    table = table or focus_table(lens)
    x, y, depth_m, focus_m = (np.asarray(a, dtype=np.float64).reshape(-1) for a in
                              np.broadcast_arrays(x, y, depth_m, focus_m))
    if oversample not in (1, 2):
        raise ValueError("oversample must be 1 or 2")
    n_psf = x.shape[0]
    k = spec.size if oversample == 1 else 2 * spec.size + 1
    p = paraxial_data(lens)
    rho = pupil_sampling_scale(lens, wavelength_nm)
    gen = torch.Generator().manual_seed(seed)
    tracer = _tracer(lens, wavelength_nm, compiled)
    recentre = center_wavelength_nm is not None and float(center_wavelength_nm) != float(wavelength_nm)
    scale = spec.scale(lens, depth_m, focus_m)
    sensor_z = np.asarray(table(focus_m))
    kernels = torch.zeros(n_psf, k, k)
    energy = np.zeros(n_psf)
    center = np.zeros((n_psf, 2))
    for s0 in range(0, n_psf, chunk):
        sl = slice(s0, min(s0 + chunk, n_psf))
        b = sl.stop - sl.start
        pad = chunk - b if compiled else 0  # fixed shapes for the compiled tracer
        idx = np.r_[np.arange(sl.start, sl.stop), np.full(pad, sl.start)]
        obj = object_points_mm(lens, x[idx], y[idx], depth_m[idx], sensor_z[idx])
        aim = chief_ray_pupil(lens, obj, wavelength_nm)
        # Pupil samples: one stratified pattern, rotated randomly per PSF to decorrelate their noise.
        base = stratified_disk(n_rays, gen) * (rho * p.entrance_pupil_mm / 2)
        n_in = int(((base * base).sum(-1) <= (p.entrance_pupil_mm / 2) ** 2).sum())
        ang = torch.rand(len(idx), generator=gen, dtype=torch.float64) * 2 * math.pi
        ca, sa = torch.cos(ang)[:, None], torch.sin(ang)[:, None]
        pup = torch.stack([ca * base[:, 0] - sa * base[:, 1], sa * base[:, 0] + ca * base[:, 1]], -1)
        pup = torch.cat([aim[:, None, :], pup], 1)  # ray 0 = chief ray
        comps = _rays_to_pupil(lens, obj, pup, p.entrance_pupil_z_mm)
        flat = [c.reshape(-1).float().to(dev) for c in comps]
        sz = torch.from_numpy(sensor_z[idx]).float()[:, None].expand(-1, n_rays + 1).reshape(-1)
        hx, hy, valid = tracer(*flat, sz.contiguous().to(dev))
        hx, hy, valid = (t.view(len(idx), n_rays + 1)[:b] for t in (hx, hy, valid))
        # Upright image coordinates relative to the chief ray, in cells.
        cx, cy = hx[:, :1], hy[:, :1]
        if recentre:
            cx, cy = (c.to(dev) for c in _chief_hit(lens, obj[:b], float(center_wavelength_nm), sensor_z[sl]))
        cell = torch.from_numpy(scale[sl] * lens.sensor.pixel_mm / oversample).float()[:, None].to(dev)
        col = (-(hx[:, 1:] - cx)) / cell + k // 2
        row = (hy[:, 1:] - cy) / cell + k // 2  # upright y up = sensor -y; rows grow downward
        w = valid[:, 1:].float() / n_in
        kernels[sl] = splat_bilinear(col, row, w, k).cpu()
        energy[sl] = w.sum(1).cpu().double().numpy()
        center[sl] = -torch.cat([cx, cy], 1).cpu().double().numpy()
    return PSFBatch(kernels, scale, energy, center, sensor_z)
