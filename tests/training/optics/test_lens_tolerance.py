"""Lens manufacturing tolerance (training/optics/tolerance.py, the lens_tolerance effect): the decentred tracer
against our own tracer and against optiland, the focal-surface changes' symmetries, and the sensitivity table's
agreement with tracing."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch

from aat_deploy.lens.io import load_lens
from aat_deploy.render import effects as fx
from aat_deploy.render.effects.lens_tolerance import air_gaps, elements, optics_key, table_name
from training.optics.tolerance import focal_surface_change_mm, sensitivity_table, trace_decentred
from training.optics.trace import Rays, rays_through_pupil, trace, uniform_disk_grid

RF50 = "lenses/canon_rf50mm_f1.8.json"


@pytest.fixture(scope="module")
def lens():
    return load_lens(RF50)


def _rays(lens):
    pupil = uniform_disk_grid(7)
    bundles = [rays_through_pupil(lens, pupil, None, (ax, ay)) for ax, ay in ((0, 0), (0.2, 0), (-0.15, 0.25))]
    return Rays(torch.cat([b.o for b in bundles]), torch.cat([b.d for b in bundles]), None)


def test_structure_of_the_rf50(lens):
    assert air_gaps(lens) == [1, 4, 5, 7, 9]  # the back focus (after 11) is focusing, not a tolerance
    assert elements(lens) == [[0, 1], [2, 3, 4], [6, 7], [8, 9], [10, 11]]  # the cemented doublet moves as one


def test_decentred_tracer_without_offsets_is_the_tracer(lens):
    rays = _rays(lens)
    z = lens.nominal_sensor_z_mm
    ref = trace(lens, rays, sensor_z_mm=z)
    x, y, dx, dy, dz, valid = trace_decentred(lens, *rays.o.unbind(-1), *rays.d.unbind(-1), z, {})
    assert torch.equal(valid, ref.rays.valid)
    v = valid
    assert torch.allclose(torch.stack([x, y], -1)[v], ref.rays.o[v, :2], atol=1e-12)
    assert torch.allclose(torch.stack([dx, dy, dz], -1)[v], ref.rays.d[v], atol=1e-12)


def test_decentred_element_matches_optiland(lens):
    """The cemented doublet moved 0.2 mm along x: the same rays through optiland with those surfaces decentred
    (dx) land at the same image points (to 1e-6 mm) and the same rays are lost."""
    pytest.importorskip("optiland")
    from optiland.materials import IdealMaterial
    from optiland.optic import Optic
    from optiland.physical_apertures import RadialAperture

    from tests.training.optics.test_optiland_crosscheck import _optiland_trace

    w = lens.design_wavelength_nm
    n = lens.indices(w)
    moved = elements(lens)[1]
    op = Optic()
    op.surfaces.add(index=0, radius=np.inf, thickness=np.inf, material=IdealMaterial(n=n[0]))
    for i, s in enumerate(lens.surfaces):
        kw = dict(index=i + 1, radius=s.radius_mm, thickness=s.thickness_mm, material=IdealMaterial(n=n[i + 1]),
                  is_stop=i == lens.stop_index, dx=0.2 if i in moved else 0.0)
        if not s.is_spherical:
            kw.update(surface_type="even_asphere", conic=s.conic, coefficients=list(s.asphere_from_r2), tol=1e-13)
        op.surfaces.add(aperture=RadialAperture(r_max=s.semi_diameter_mm), **kw)
    op.surfaces.add(index=len(lens.surfaces) + 1)
    op.set_aperture(aperture_type="float_by_stop_size", value=2 * lens.surfaces[lens.stop_index].semi_diameter_mm)
    op.fields.set_type(field_type="angle")
    op.fields.add(y=0.0)
    op.wavelengths.add(value=w / 1000.0, is_primary=True)
    rays = _rays(lens)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        xyz, alive, _ = _optiland_trace(op, rays, w)
    x, y, *_, valid = trace_decentred(lens, *rays.o.unbind(-1), *rays.d.unbind(-1), lens.nominal_sensor_z_mm,
                                      {i: (0.2, 0.0) for i in moved}, w)
    v = valid.numpy()
    assert v.sum() > 50 and np.array_equal(v, alive)
    ours = torch.stack([x, y], -1).numpy()[v]
    assert np.abs(ours - xyz[-1][v, :2]).max() < 1e-6
    # and the decentre does move the image (the comparison is not of two undisturbed traces)
    ref = trace(lens, rays, sensor_z_mm=lens.nominal_sensor_z_mm).rays.o[:, :2].numpy()[v]
    assert np.abs(ours - ref).max() > 1e-3


def test_focal_surface_changes_have_the_lens_symmetries(lens):
    """A gap change is rotationally symmetric (dz(x) = dz(-x)); a decentre along x is odd in x and even in y, and
    along y it is the x one rotated by 90 degrees; both are linear in the amount and zero for none."""
    pts = np.array([[0.8, 0.0], [-0.8, 0.0], [0.0, 0.8], [0.5, 0.5], [0.5, -0.5]])
    g = focal_surface_change_mm(lens, pts, 2.0, gap=4, gap_mm=0.1, n_rays=256)
    assert abs(g[0]) > 1e-3 and g[0] == pytest.approx(g[1], abs=2e-4) and g[3] == pytest.approx(g[4], abs=2e-4)
    d = focal_surface_change_mm(lens, pts, 2.0, element=1, decentre_mm=(0.1, 0.0), n_rays=256)
    assert abs(d[0]) > 0.02 and d[0] == pytest.approx(-d[1], rel=0.05) and abs(d[2]) < 0.1 * abs(d[0])
    d2 = focal_surface_change_mm(lens, pts, 2.0, element=1, decentre_mm=(0.2, 0.0), n_rays=256)
    assert d2[0] == pytest.approx(2 * d[0], rel=0.05)
    # rotational symmetry: the same 9 mm off axis along y (normalised 0.75) for a y decentre as along x (0.5)
    ex = focal_surface_change_mm(lens, np.array([[0.5, 0.0]]), 2.0, element=1, decentre_mm=(0.1, 0.0), n_rays=256)
    ey = focal_surface_change_mm(lens, np.array([[0.0, 0.75]]), 2.0, element=1, decentre_mm=(0.0, 0.1), n_rays=256)
    assert ey[0] == pytest.approx(ex[0], rel=0.05)
    assert np.allclose(focal_surface_change_mm(lens, pts, 2.0, gap=4, gap_mm=0.0, n_rays=256), 0.0, atol=1e-12)


def test_shipped_table_agrees_with_tracing_and_renders_without_torch(lens, tmp_path):
    """models/tolerance_<key>.json (scripts/lens_tolerance_table.py) gives the traced change at its grid points
    and the effect finds it next to the lens's surrogate (no torch needed); without it, the effect says torch."""
    from pathlib import Path

    from conftest import ROOT

    path = ROOT / "models" / table_name(lens)
    t = json.loads(path.read_text())
    assert t["optics_key"] == optics_key(lens) and t["unit_mm"] == 0.05
    q = next(p for p in t["perturbations"] if p["kind"] == "decentre" and p["element"] == 1 and p["axis"] == "x")
    fxs, fys = np.array(t["field_x"]), np.array(t["field_y"])
    traced = focal_surface_change_mm(lens, np.array([[fxs[-1], fys[2]], [fxs[1], fys[-1]]]), 1.0 / t["diopters"][1],
                                     element=1, decentre_mm=(0.05, 0.0))
    assert np.allclose([q["dz_mm"][1][2][-1], q["dz_mm"][1][-1][1]], traced, atol=2e-4)

    class Src:  # a lens source that sits in models/
        path = Path(ROOT / "models" / "psf_rf50.onnx")

    ctx = fx.SimContext(lens, (640, 960), lens_source=Src())
    e = fx.make("lens_tolerance", element=1.0, decentre_x_mm=0.1)
    assert e.torch_reason(ctx) == ""
    shift = e.sensor_shift_mm(ctx)(np.array([1.0, -1.0]), np.array([0.0, 0.0]), np.array([1.0 / t["diopters"][1]] * 2))
    assert shift == pytest.approx(-2 * np.array([q["dz_mm"][1][2][-1], q["dz_mm"][1][2][0]]), rel=1e-6)
    elsewhere = fx.SimContext(lens, (640, 960), lens_source=type("S", (), {"path": tmp_path / "psf.onnx"})())
    assert "traces the perturbed lens" in e.torch_reason(elsewhere) and fx.make("lens_tolerance").torch_reason(elsewhere) == ""
    with pytest.raises(ValueError, match="no such file"):
        fx.make("lens_tolerance", table=str(tmp_path / "missing.json"))
    other = load_lens("lenses/canon_ef50mm_f1.8.json")
    with pytest.raises(ValueError, match="made for lens"):
        fx.make("lens_tolerance", element=1.0, decentre_x_mm=0.1, table=str(path)).sensor_shift_mm(
            fx.SimContext(other, (640, 960)))


def test_small_table_matches_the_traced_effect(lens, tmp_path):
    """sensitivity_table on a coarse grid and the effect traced on first use (torch) give the same shifts at
    the grid points."""
    t = sensitivity_table(lens, nx=3, ny=3, n_rays=256)
    assert len(t["perturbations"]) == len(air_gaps(lens)) + 2 * len(elements(lens))
    p = tmp_path / "t.json"
    p.write_text(json.dumps(t))
    ctx = fx.SimContext(lens, (640, 960))
    a = fx.make("lens_tolerance", gap=4.0, gap_mm=0.1, table=str(p)).sensor_shift_mm(ctx)(
        np.array([1.0, 0.0]), np.array([1.0, 1.0]), np.array([1.5, 1.5]))
    b = focal_surface_change_mm(lens, np.array([[1.0, 1.0], [0.0, 1.0]]), 1.5, gap=4, gap_mm=0.05, n_rays=256)
    assert a == pytest.approx(-2 * b, abs=1e-6)
