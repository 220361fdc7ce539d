"""Ray-traced PSFs against their definition and basic physics."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from conftest import LENSES, assert_close

from aat_deploy.lens.io import load_lens
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.optics.thin_lens import thin_lens_blur_px
from aat_deploy.psf.kernel import KernelSpec
from training.optics.focus import focus
from training.optics.trace import Rays, trace
from training.psf.geometry import focus_table, object_points_mm
from training.psf.raytrace import FLOAT32_NEWTON_TOL_MM, _rays_to_pupil, chief_ray_pupil, raytrace_psfs
from training.psf.splat import downsample2

RF50 = load_lens(LENSES / "canon_rf50mm_f1.8.json")
THIN = load_lens(LENSES / "ideal_thin_rf50.json")


def test_focus_table_matches_direct_focus():
    t = focus_table(RF50)
    for d in (0.35, 1.3, 7.0):
        assert float(t(d)) == pytest.approx(focus(RF50, d, RF50.design_wavelength_nm), abs=2e-4)  # 0.2 um


def test_chief_ray_passes_the_stop_centre():
    zs = float(focus_table(RF50)(2.0))
    obj = object_points_mm(RF50, np.array([0.3, -0.9, 1.0]), np.array([0.8, 0.1, -1.0]), 2.0, zs)
    aim = chief_ray_pupil(RF50, obj, 589.0)
    p = paraxial_data(RF50)
    comps = _rays_to_pupil(RF50, obj, aim[:, None, :], p.entrance_pupil_z_mm)
    o = torch.stack([c[:, 0] for c in comps[:3]], -1)
    d = torch.stack([c[:, 0] for c in comps[3:]], -1)
    res = trace(RF50, Rays(o, d, None), 589.0, record=True)
    stop_hit = res.hits[RF50.stop_index][:, :2]
    assert float(stop_hit.abs().max()) < 1e-8


@pytest.mark.numerics
def test_psf_matches_its_definition():
    """Kernel == bilinear splat (the paper's equation) of independently traced float64 rays."""
    spec = KernelSpec.for_lens(RF50)
    x, y, depth, foc = 0.6, -0.4, 1.3, 1.5
    b = raytrace_psfs(RF50, x, y, depth, foc, spec, n_rays=1024, seed=3)
    # Rebuild the same rays (same seed and pattern) and splat with numpy.
    gen = torch.Generator().manual_seed(3)
    from training.optics.trace import stratified_disk
    from training.psf.raytrace import pupil_sampling_scale

    p = paraxial_data(RF50)
    rho = pupil_sampling_scale(RF50, 589.0)
    base = stratified_disk(1024, gen) * (rho * p.entrance_pupil_mm / 2)
    n_in = int(((base**2).sum(-1) <= (p.entrance_pupil_mm / 2) ** 2).sum())
    ang = float(torch.rand(1, generator=gen, dtype=torch.float64)[0] * 2 * math.pi)
    rot = torch.tensor([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]], dtype=torch.float64)
    pup = base @ rot.T
    zs = b.sensor_z_mm[0]
    obj = object_points_mm(RF50, x, y, depth, zs)
    aim = chief_ray_pupil(RF50, obj, 589.0)
    comps = _rays_to_pupil(RF50, obj, torch.cat([aim[:, None], pup[None]], 1), p.entrance_pupil_z_mm)
    o = torch.stack([c[0] for c in comps[:3]], -1)
    d = torch.stack([c[0] for c in comps[3:]], -1)
    res = trace(RF50, Rays(o, d, None), 589.0, sensor_z_mm=zs)
    hit, ok = res.rays.o[:, :2].numpy(), res.rays.valid.numpy()
    cell = b.scale[0] * RF50.sensor.pixel_mm
    col = -(hit[1:, 0] - hit[0, 0]) / cell + 5
    row = (hit[1:, 1] - hit[0, 1]) / cell + 5
    ref = np.zeros((11, 11))
    for c, r, v in zip(col, row, ok[1:]):
        if not v:
            continue
        for cc in (math.floor(c), math.floor(c) + 1):
            for rr in (math.floor(r), math.floor(r) + 1):
                if 0 <= cc < 11 and 0 <= rr < 11:
                    ref[rr, cc] += (1 - abs(c - cc)) * (1 - abs(r - rr)) / n_in
    # float32 ray hits vs float64: ~1e-4 of a cell each (2.5e-6 mm seen), so the kernel moves by ~1e-4 of its peak
    # cell, itself ~0.1 of the energy
    assert_close(b.kernels[0], ref, 3e-5, scale=ref.sum(), what="kernel vs float64 splat")
    assert b.energy[0] == pytest.approx(ok[1:].sum() / n_in, rel=1e-6)
    # the float32 chief-ray solve stops at FLOAT32_NEWTON_TOL_MM (an absolute length by design)
    assert np.allclose(b.center_mm[0], -hit[0], rtol=0, atol=FLOAT32_NEWTON_TOL_MM)


def test_on_axis_in_focus_is_a_point_with_full_energy():
    b = raytrace_psfs(RF50, 0.0, 0.0, 2.0, 2.0, n_rays=2048)
    k = b.kernels[0]
    # No vignetting on axis. Energy is relative to the paraxial pupil area; the real pupil of a near object is a
    # little larger (pupil aberration), so slightly more than 1 arrives.
    assert b.energy[0] == pytest.approx(1.0, rel=5e-3)
    assert float(k.sum()) == pytest.approx(b.energy[0], rel=1e-5)  # a float32 sum of the splats
    assert float(k[4:7, 4:7].sum()) > 0.95  # within one pixel of the chief ray


def test_defocus_blur_size_matches_thin_lens_geometry():
    """On axis the RF50 behaves like its thin-lens twin: second moment of a defocused PSF ~ disk of CoC."""
    for lens in (RF50, THIN):
        b = raytrace_psfs(lens, 0.0, 0.0, 1.0, 2.0, n_rays=8192)
        k = b.kernels[0].double().numpy()
        g = (np.arange(11) - 5) * b.scale[0]
        yy, xx = np.meshgrid(g, g, indexing="ij")
        r2 = ((xx**2 + yy**2) * k).sum() / k.sum() - 2 * b.scale[0] ** 2 / 6  # minus the tent's variance
        coc = thin_lens_blur_px(lens, 1.0, 2.0)
        assert math.sqrt(r2) == pytest.approx(coc / 2 / math.sqrt(2), rel=0.08 if lens is RF50 else 0.02)


def test_vignetting_lowers_energy_and_upright_position():
    b = raytrace_psfs(RF50, [0.0, 0.5, 1.0], [0.0, 0.5, 1.0], 2.0, 2.0, n_rays=2048)
    assert b.energy[0] > b.energy[1] > b.energy[2] > 0.15
    assert np.allclose(b.kernels.sum((1, 2)).numpy(), b.energy * b.energy_in_window, rtol=1e-5)
    # Upright image coordinates: field (+x, +y) appears up and right; off its infinity-focus position by
    # focus breathing (sensor 1.3 mm further back at 2 m: +2.2 %) and distortion (+0.5 %).
    w, h = RF50.sensor.width_mm / 2, RF50.sensor.height_mm / 2
    assert np.allclose(b.center_mm[2], [w * 1.026, h * 1.026], rtol=0.005)


def test_point_symmetry_of_a_rotationally_symmetric_lens():
    b = raytrace_psfs(RF50, [0.7, -0.7], [0.3, -0.3], 1.4, 1.7, n_rays=8192, seed=5)
    a, c = b.kernels[0], torch.flip(b.kernels[1], (0, 1))
    assert float((a - c).abs().sum()) < 0.08 * float(a.sum())  # equal up to ray noise


@pytest.mark.numerics
def test_oversampled_psf_downsamples_exactly():
    spec = KernelSpec.for_lens(RF50)
    a = raytrace_psfs(RF50, 0.5, 0.5, 1.1, 1.5, spec, n_rays=1024, seed=7)
    f = raytrace_psfs(RF50, 0.5, 0.5, 1.1, 1.5, spec, n_rays=1024, seed=7, oversample=2)
    assert f.kernels.shape[-1] == 23
    # the same splats summed in another order, float32: ~log2(n) eps of the energy
    assert_close(downsample2(f.kernels), a.kernels, 2e-6, scale=a.kernels.sum())


def test_large_defocus_is_not_truncated():
    b = raytrace_psfs(RF50, [0.0, 0.9], [0.0, 0.9], 0.35, 20.0, n_rays=2048)
    assert b.scale[0] > 5  # the window grew with the blur
    assert b.energy_in_window.min() > 0.97


def _centroid_cells(k: torch.Tensor) -> np.ndarray:
    """(B, k, k) -> (B, 2) centroid (x right, y up) in cells from the window centre."""
    g = torch.arange(k.shape[-1], dtype=torch.float64) - k.shape[-1] // 2
    k = k.double()
    e = k.sum((1, 2))
    return torch.stack([(k.sum(1) * g).sum(1) / e, -(k.sum(2) * g).sum(1) / e], -1).numpy()


def test_kernels_centred_on_another_wavelength_keep_lateral_colour():
    """center_wavelength_nm: a blue PSF centred on the 589 nm chief ray is the blue PSF centred on its own chief
    ray, moved by the offset between the two chief rays (lateral colour), and reports the 589 nm hit."""
    spec = KernelSpec.for_lens(RF50)
    x, y, d, f = np.array([0.0, 0.9, -0.8]), np.array([0.0, 0.9, 0.5]), np.array([2.0, 3.0, 1.5]), np.array([2.0, 3.0, 1.2])
    ref = raytrace_psfs(RF50, x, y, d, f, spec, n_rays=16)
    own = raytrace_psfs(RF50, x, y, d, f, spec, n_rays=8192, wavelength_nm=465.0)
    moved = raytrace_psfs(RF50, x, y, d, f, spec, n_rays=8192, wavelength_nm=465.0, center_wavelength_nm=589.0)
    # the same float32 chief-ray solve; other batch shapes may route an element through vector or scalar code
    np.testing.assert_allclose(moved.center_mm, ref.center_mm, rtol=1e-6, atol=0)
    shift_cells = (own.center_mm - ref.center_mm) / RF50.sensor.pixel_mm / own.scale[:, None]
    assert np.abs(shift_cells[1:]).max() > 0.01  # off axis the chief rays part
    np.testing.assert_allclose(_centroid_cells(moved.kernels) - _centroid_cells(own.kernels), shift_cells, atol=2e-3)
    same = raytrace_psfs(RF50, x, y, d, f, spec, n_rays=256, wavelength_nm=465.0, center_wavelength_nm=465.0)
    # the same rays through the same code: bit for bit
    assert torch.equal(same.kernels, raytrace_psfs(RF50, x, y, d, f, spec, n_rays=256, wavelength_nm=465.0).kernels)


def test_focus_table_reaching_a_phone_lens_working_range():
    """A surrogate's focus range nearer than 0.2 m gets a table that reaches it (a phone lens focuses at 7 cm);
    ranges of 0.2 m or farther keep the default table (every stored surrogate and dataset stays as it was)."""
    from training.psf.geometry import focus_table_reaching

    assert focus_table_reaching(RF50, 0.3) is focus_table(RF50)
    phone = load_lens(LENSES / "cellphone_asphere.json")
    t = focus_table_reaching(phone, 0.05, n=9)  # 9 samples: a real-ray focus search each
    assert t.diopters[-1] == pytest.approx(20.0)
    assert float(t(0.05)) == pytest.approx(focus(phone, 0.05, phone.design_wavelength_nm), abs=1e-6)
    with pytest.raises(ValueError, match="outside the table"):
        focus_table(phone, n=9)(0.07)
