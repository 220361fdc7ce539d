"""PSF models that stand in for ray tracing. All map (x, y, depth_m, focus_m) -> (B, k, k) kernels in the
representation of `aat_deploy.psf.kernel` (energy per cell, cell = `scale` pixels, centred on the chief ray).

- `GaussianPSF`: the thin-lens baseline. Circle of confusion from EFL, entrance pupil and distances; a Gaussian
  with the disk's second moment (sigma = CoC / 4) plus the splat's tent (1/6 cell^2), energy 1 over the plane
  (the tails outside the window are lost, not renormalised).
- `PaperMLP`: the paper's network: 4 inputs -> 5 hidden layers of 256 (ReLU) -> k^2 (sigmoid).
  Inputs are normalised, depth and focus in diopters.
- `RotPSF` (ours): uses the lens's rotational symmetry. An MLP maps (field radius, defocus in diopters, focus in
  diopters, log cell size) to the PSF of a point on the +y image axis on the half-cell grid (softmax shape x
  energy, mirror-symmetric about the meridional plane); the kernel is rotated into place (bicubic, on the
  half-cell grid) and reduced exactly to cells (`kernel.downsample2`). One 3-D function instead of a 4-D one.
- `GridPSF`: ray-traced PSFs on a (focus, depth, y, x) grid with multilinear interpolation (the paper's
  "low-rank"/interpolation baseline).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.optics.thin_lens import blur_diameter_px, gaussian_kernels
from aat_deploy.psf.kernel import KernelSpec
from training.psf.splat import downsample2


class PSFModel(nn.Module):
    """Common lens constants and the (depth, focus) -> cell size map, as torch ops (exportable)."""

    def __init__(self, lens: Lens, spec: KernelSpec, near_m: float, far_m: float):
        super().__init__()
        p = paraxial_data(lens)
        self.k = spec.size
        self.margin_px = float(spec.margin_px)
        self.efl_mm, self.epd_mm = float(p.efl_mm), float(p.entrance_pupil_mm)
        self.pixel_mm = float(lens.sensor.pixel_mm)
        self.half_w, self.half_h = lens.sensor.width_mm / 2, lens.sensor.height_mm / 2
        self.half_diag = lens.sensor.half_diagonal_mm
        self.near_m, self.far_m = float(near_m), float(far_m)
        self.d_lo, self.d_hi = 1.0 / far_m, 1.0 / near_m  # diopter range

    def blur_px(self, depth_m: torch.Tensor, focus_m: torch.Tensor) -> torch.Tensor:
        """Thin-lens blur-disk diameter (px): `aat_deploy.optics.thin_lens`, in torch ops (exported to ONNX)."""
        return blur_diameter_px(depth_m, focus_m, self.efl_mm, self.epd_mm, self.pixel_mm)

    def scale(self, depth_m: torch.Tensor, focus_m: torch.Tensor) -> torch.Tensor:
        return torch.clamp((self.blur_px(depth_m, focus_m) + self.margin_px) / (self.k - 1), min=1.0)

    def forward(self, q: torch.Tensor) -> torch.Tensor:  # pragma: no cover - interface
        """q: (B, 4) = x, y, depth_m, focus_m -> (B, k, k)."""
        raise NotImplementedError


class GaussianPSF(PSFModel):
    """The thin-lens baseline (`aat_deploy.optics.thin_lens.gaussian_kernels`, in torch ops: exported to ONNX)."""

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return gaussian_kernels(self.blur_px(q[:, 2], q[:, 3]), self.k, self.margin_px)[0]


def _mlp(n_in: int, width: int, depth: int, n_out: int, act) -> nn.Sequential:
    layers: list[nn.Module] = [nn.Linear(n_in, width), act()]
    for _ in range(depth - 1):
        layers += [nn.Linear(width, width), act()]
    layers.append(nn.Linear(width, n_out))
    return nn.Sequential(*layers)


class PaperMLP(PSFModel):
    """The paper's PSF network (x, y, z, focus) -> k^2, sigmoid; 295,545 parameters for k = 11."""

    def __init__(self, lens: Lens, spec: KernelSpec, near_m: float, far_m: float, width: int = 256,
                 hidden: int = 5):
        super().__init__(lens, spec, near_m, far_m)
        self.net = _mlp(4, width, hidden, self.k * self.k, nn.ReLU)

    def features(self, q: torch.Tensor) -> torch.Tensor:
        zd = (1.0 / q[:, 2] - self.d_lo) / (self.d_hi - self.d_lo)
        zf = (1.0 / q[:, 3] - self.d_lo) / (self.d_hi - self.d_lo)
        return torch.stack([q[:, 0], q[:, 1], zd, zf], -1)

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.net(self.features(q))).view(-1, self.k, self.k)


class RotPSF(PSFModel):
    """Rotationally symmetric PSF network (ours); see the module docstring."""

    def __init__(self, lens: Lens, spec: KernelSpec, near_m: float, far_m: float, width: int = 256,
                 hidden: int = 4, max_energy: float = 1.1):
        super().__init__(lens, spec, near_m, far_m)
        self.kf = 2 * self.k + 1
        self.half = self.k + 1  # columns 0..k of the fine grid; the rest is the mirror image
        self.max_energy = max_energy
        self.net = _mlp(4, width, hidden, self.kf * self.half + 1, nn.SiLU)
        g = torch.arange(self.kf, dtype=torch.float32) - self.k
        vv, uu = torch.meshgrid(g, g, indexing="ij")
        self.register_buffer("grid_u", uu, persistent=False)  # upright offsets, half-cells
        self.register_buffer("grid_v", -vv, persistent=False)

    def features(self, r, depth_m, focus_m) -> torch.Tensor:
        inv_d, inv_f = 1.0 / depth_m, 1.0 / focus_m
        span = self.d_hi - self.d_lo
        log_s = torch.log(self.scale(depth_m, focus_m))
        return torch.stack([2 * r - 1, (inv_d - inv_f) / span, 2 * (inv_f - self.d_lo) / span - 1, log_s], -1)

    def axis_shape_energy(self, r, depth_m, focus_m) -> tuple[torch.Tensor, torch.Tensor]:
        """Shape (B, 2k+1, 2k+1), summing to 1, and energy (B,) of a point on the +y image axis at radius r."""
        out = self.net(self.features(r, depth_m, focus_m))
        logits, e = out[:, :-1].view(-1, self.kf, self.half), out[:, -1]
        full = torch.cat([logits, torch.flip(logits[:, :, :-1], (2,))], 2)  # mirror about the centre column
        shape = torch.softmax(full.reshape(full.shape[0], -1), -1).view(-1, self.kf, self.kf)
        return shape, self.max_energy * torch.sigmoid(e)

    def axis_kernel(self, r, depth_m, focus_m) -> torch.Tensor:
        """(B, 2k+1, 2k+1) half-cell kernel of a point on the +y image axis at normalised radius r."""
        shape, energy = self.axis_shape_energy(r, depth_m, focus_m)
        return shape * energy[:, None, None]

    def rotate(self, fine: torch.Tensor, cos_phi: torch.Tensor, sin_phi: torch.Tensor) -> torch.Tensor:
        """Rotate axis kernels clockwise by phi (from +y towards +x), bicubic on the half-cell grid."""
        c, s = cos_phi[:, None, None], sin_phi[:, None, None]
        su = c * self.grid_u - s * self.grid_v
        sv = s * self.grid_u + c * self.grid_v
        half = (self.kf - 1) / 2
        grid = torch.stack([su / half, -sv / half], -1)  # normalised (col, row), align_corners=True
        out = F.grid_sample(fine[:, None], grid, mode="bicubic", padding_mode="zeros", align_corners=True)
        return out[:, 0]

    def field_polar(self, x, y):
        """(r, cos phi, sin phi): normalised radius and the direction's angle from +y towards +x.
        Written without atan2, whose ONNX form is 0/0 on the axis; there the angle is irrelevant (phi = 0)."""
        u, v = x * self.half_w, y * self.half_h
        rho = torch.sqrt(u * u + v * v)
        on_axis = rho < 1e-9
        safe = torch.where(on_axis, torch.ones_like(rho), rho)
        cos_phi = torch.where(on_axis, torch.ones_like(rho), v / safe)
        sin_phi = torch.where(on_axis, torch.zeros_like(rho), u / safe)
        return rho / self.half_diag, cos_phi, sin_phi

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        r, cos_phi, sin_phi = self.field_polar(q[:, 0], q[:, 1])
        fine = self.axis_kernel(r, q[:, 2], q[:, 3])
        return torch.clamp(downsample2(self.rotate(fine, cos_phi, sin_phi)), min=0.0)


class GridPSF(PSFModel):
    """Multilinear interpolation in a table of ray-traced PSFs over (1/focus, 1/depth, y, x)."""

    def __init__(self, lens: Lens, spec: KernelSpec, near_m: float, far_m: float, table: torch.Tensor):
        super().__init__(lens, spec, near_m, far_m)
        self.register_buffer("table", table)  # (NF, ND, NY, NX, k, k)
        self.nf, self.nd, self.ny, self.nx = table.shape[:4]

    @staticmethod
    def axes(near_m: float, far_m: float, nf: int, nd: int, ny: int, nx: int):
        """Grid node values: focus and depth even in diopters (near..far), y and x over [-1, 1]."""
        from aat_deploy.optics.focus_table import diopter_grid

        return (diopter_grid(near_m, far_m, nf), diopter_grid(near_m, far_m, nd),
                np.linspace(-1, 1, ny), np.linspace(-1, 1, nx))

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        span = self.d_hi - self.d_lo
        # Fractional indices; diopter axes run near -> far (descending 1/d).
        t = [(self.d_hi - 1.0 / q[:, 3]) / span * (self.nf - 1), (self.d_hi - 1.0 / q[:, 2]) / span * (self.nd - 1),
             (q[:, 1] + 1) / 2 * (self.ny - 1), (q[:, 0] + 1) / 2 * (self.nx - 1)]
        sizes = (self.nf, self.nd, self.ny, self.nx)
        i0 = [torch.clamp(torch.floor(ti), 0, n - 2).long() for ti, n in zip(t, sizes)]
        fr = [torch.clamp(ti - i, 0.0, 1.0) for ti, i in zip(t, i0)]
        out = 0.0
        for corner in range(16):
            bits = [(corner >> b) & 1 for b in range(4)]
            w = torch.ones_like(fr[0])
            for b_, f_ in zip(bits, fr):
                w = w * (f_ if b_ else 1 - f_)
            idx = [i + b_ for i, b_ in zip(i0, bits)]
            out = out + w[:, None, None] * self.table[idx[0], idx[1], idx[2], idx[3]]
        return out


def n_params(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


__all__ = ["GaussianPSF", "GridPSF", "PaperMLP", "PSFModel", "RotPSF", "n_params"]
