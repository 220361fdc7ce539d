"""Ray-tracer physics checks that need no other package: Snell's law, ideal imaging, focus, losses."""

from __future__ import annotations

import math

import pytest
import torch
from conftest import LENSES, assert_close

from aat_deploy.lens.io import load_lens
from aat_deploy.lens.schema import Lens, Sensor, Surface
from aat_deploy.optics.paraxial import paraxial_data, paraxial_image_z_mm
from training.optics.focus import focus, object_z_mm
from training.optics.spot import spot
from training.optics.trace import (
    NEWTON_TOL_MM,
    Rays,
    rays_through_pupil,
    stratified_disk,
    trace,
    uniform_disk_grid,
)

SENSOR = Sensor(36.0, 24.0, 960, 640)


def _lens(surfaces, stop=0):
    return Lens("t", tuple(surfaces), stop, SENSOR, 587.5618)


def _ray(o, d):
    o = torch.tensor([o], dtype=torch.float64)
    d = torch.tensor([d], dtype=torch.float64)
    return Rays(o, d / torch.linalg.vector_norm(d, dim=-1, keepdim=True), None)


def test_snell_at_a_flat_interface():
    n = 1.5
    lens = _lens([Surface(0.0, 10.0, 50.0, "1.5/60"), Surface(0.0, 10.0, 50.0, "air")])
    theta = math.radians(30)
    res = trace(lens, _ray([0, 0, -1], [0, math.sin(theta), math.cos(theta)]), 589.3, record=True)
    d_in_glass = (res.hits[1] - res.hits[0])[0]
    sin_t = float(d_in_glass[1] / torch.linalg.vector_norm(d_in_glass))
    # float64 (eps 2.2e-16) through a dozen operations: a few dozen eps
    assert sin_t == pytest.approx(math.sin(theta) / n, rel=3e-14)
    assert float(res.rays.d[0, 1]) == pytest.approx(math.sin(theta), rel=3e-14)  # parallel plate


def test_total_internal_reflection_and_clipping_lose_rays():
    lens = _lens([Surface(0.0, 10.0, 50.0, "1.5/60"), Surface(0.0, 10.0, 50.0, "air")])
    # Inside the glass at 50 deg > critical 41.8 deg: start a ray in glass by making it enter steeply.
    steep = _ray([0, 0, -1], [0, math.sin(math.radians(89.0)), math.cos(math.radians(89.0))])
    res = trace(lens, steep, 589.3)
    assert not bool(res.rays.valid[0])  # clipped by the 50 mm semi-diameter long before TIR matters
    wide = _lens([Surface(0.0, 1.0, 1e6, "1.5/60"), Surface(-0.5, 10.0, 1e6, "air")])
    r = _ray([0, 1.5, -1], [0, 0, 1])  # hits the strongly curved back surface at 48.6 deg incidence
    assert not bool(trace(wide, r, 589.3).rays.valid[0])  # TIR: sin 48.6 * 1.5 > 1
    ok = _ray([0, 0.5, -1], [0, 0, 1])
    assert bool(trace(wide, ok, 589.3).rays.valid[0])


def test_ideal_lens_images_every_ray_to_one_point():
    f = 50.0
    lens = _lens([Surface(0.0, 100.0, 20.0, kind="ideal", focal_length_mm=f)])
    pupil = uniform_disk_grid(21)
    obj = torch.tensor([0.0, 10.0, -100.0], dtype=torch.float64)  # 100 mm in front: 1:1 at 100 mm
    res = trace(lens, rays_through_pupil(lens, pupil, obj), sensor_z_mm=100.0)
    xy = res.rays.o[:, :2]
    assert bool(res.rays.valid.all())
    assert_close(xy, torch.tensor([0.0, -10.0], dtype=torch.float64).expand_as(xy), 1e-11)  # float64 rounding


def test_sphere_intercept_lies_on_the_surface_and_asphere_converges():
    lens = load_lens(LENSES / "canon_rf50mm_f1.8.json")
    pupil = stratified_disk(2000, torch.Generator().manual_seed(1))
    res = trace(lens, rays_through_pupil(lens, pupil, None, (0.0, math.radians(15))), record=True)
    for s, zv, h in zip(lens.surfaces, lens.vertex_z_mm, res.hits):
        r2 = (h[:, 0] ** 2 + h[:, 1] ** 2)[res.rays.valid]
        sag = torch.tensor([s.sag(float(v)) for v in r2[:200]], dtype=torch.float64)
        # Newton stops at |dt| < NEWTON_TOL_MM (float64: 1e-12 mm, an absolute length by design)
        assert torch.allclose(h[res.rays.valid][:200, 2] - zv, sag, rtol=0, atol=100 * NEWTON_TOL_MM[torch.float64])


def test_paraxial_limit_of_real_rays_matches_paraxial_focus():
    lens = load_lens(LENSES / "canon_ef50mm_f1.8.json")
    p = paraxial_data(lens)
    pupil = torch.tensor([[0.0, 1e-4]], dtype=torch.float64)  # nearly paraxial marginal ray
    res = trace(lens, rays_through_pupil(lens, pupil), record=True)
    d = res.rays.d[0]
    last = res.hits[-1][0]
    z_cross = float(last[2] - last[1] * d[2] / d[1])
    # a ray 1e-4 mm off axis: its spherical aberration and float64 rounding stay far below 2e-8 of the 73 mm
    assert z_cross == pytest.approx(lens.vertex_z_mm[-1] + p.bfl_mm, rel=2e-8)


def test_focus_is_sensor_referenced_and_minimises_rms():
    lens = load_lens(LENSES / "canon_rf50mm_f1.8.json")
    for dist in (0.5, 1.5, 5.0):
        zs = focus(lens, dist)
        # The object plane is `dist` metres in front of the sensor.
        assert zs - object_z_mm(zs, dist) == pytest.approx(1000 * dist)
        best = spot(lens, 0.0, dist, 0.0, grid=48).rms_um
        for dz in (-0.01, 0.01):
            assert spot(lens, 0.0, dist, dz, grid=48).rms_um > best
    assert focus(lens, 0.5) > focus(lens, 1.5) > focus(lens, math.inf)  # nearer = sensor further back
    with pytest.raises(ValueError):
        focus(lens, -1.0)


def test_thin_lens_focus_obeys_the_lens_equation():
    thin = load_lens(LENSES / "ideal_thin_rf50.json")
    f = thin.surfaces[0].focal_length_mm
    for dist in (0.4, 2.0):
        v = focus(thin, dist)
        u = 1000 * dist - v  # object distance from the lens plane
        assert 1 / u + 1 / v == pytest.approx(1 / f, rel=1e-9)
        assert v == pytest.approx(paraxial_image_z_mm(thin, -u), abs=1e-7)  # FOCUS_TOL_MM: a solver tolerance in mm
    assert spot(thin, 15.0, 2.0).rms_um < 1e-6  # aberration-free everywhere


def test_vignetting_increases_off_axis():
    lens = load_lens(LENSES / "canon_rf50mm_f1.8.json")
    on, off = spot(lens, 0.0, 2.0), spot(lens, 20.0, 2.0)
    assert on.n_valid == on.n_rays
    assert off.n_valid < 0.8 * off.n_rays


@pytest.mark.numerics
def test_float32_trace_agrees_with_float64():
    lens = load_lens(LENSES / "canon_rf50mm_f1.8.json")
    pupil = stratified_disk(512, torch.Generator().manual_seed(0))
    r64 = rays_through_pupil(lens, pupil, None, (0.0, math.radians(10)))
    r32 = Rays(r64.o.float(), r64.d.float(), None)
    a, b = trace(lens, r64), trace(lens, r32)
    both = a.rays.valid & b.rays.valid
    assert int((a.rays.valid != b.rays.valid).sum()) <= 2  # rays exactly at a rim may differ
    # float32 (eps 1.2e-7) through ~20 surfaces: ~20 eps of the lens's 60 mm length (2.7e-7 seen)
    assert_close(b.rays.o[both], a.rays.o[both], 3e-6, what="float32 hits (mm)")
