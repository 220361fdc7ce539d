"""Cross-check of our sequential ray tracer against optiland, an independent optical-design package.

Both programs get the same prescription and the same refractive indices (ours from `lens.indices(λ)`,
handed to optiland as constant-index `IdealMaterial`s at that one wavelength), the same clear apertures
(optiland `RadialAperture`s of our semi-diameters) and the same image plane. Compared:

* first-order data: EFL, BFL, F-number to 1e-6 relative; pupil positions and diameters to 1e-6 mm;
* real rays: identical starting rays (positions + direction cosines in object space) traced by both,
  intercepts at every surface and at the image plane to 1e-6 mm, and the same rays lost to vignetting;
* RMS spot radius (about the centroid, 36 x 36 square grid in the unit disk of the paraxial entrance
  pupil, no ray aiming in either program) to 1 %.

Lenses: optiland's sample Double Gauss re-entered in our schema (spherical), a singlet even asphere,
our shipped Cooke triplet (catalogue glasses N-SK16 / F2) and Canon RF50mm F1.8 (aspheres, nd/Vd glasses).
The Double Gauss is also checked against optiland's own sample object and its own trace_generic / spot
API, and against reference numbers noted from optiland.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

optiland = pytest.importorskip("optiland")

from optiland.analysis import SpotDiagram  # noqa: E402
from optiland.materials import IdealMaterial, Material  # noqa: E402
from optiland.optic import Optic  # noqa: E402
from optiland.physical_apertures import RadialAperture  # noqa: E402
from optiland.rays import RealRays  # noqa: E402

from aat_deploy.lens.io import load_lens  # noqa: E402
from aat_deploy.lens.materials import CAUCHY_ANCHOR_NM, parse_material  # noqa: E402
from aat_deploy.lens.schema import Lens, Sensor, Surface  # noqa: E402
from aat_deploy.optics.paraxial import paraxial_data, stop_semi_diameter_for_epd  # noqa: E402
from training.optics.spot import spot  # noqa: E402
from training.optics.trace import Rays, rays_through_pupil, trace, uniform_disk_grid  # noqa: E402

# optiland's numpy backend JIT-compiles some kernels with numba, which emits harmless pedantic warnings.
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::Warning:numba")

LENSES_DIR = Path(__file__).resolve().parents[3] / "lenses"
D_LINE_NM = 587.5618

# Both sides trace in float64 (rounding ~1e-14 of the lens's size): these bound the optics, not rounding; the
# lengths are absolute by design (a micron is a micron wherever the ray is).
REL_FIRST_ORDER = 1e-6  # EFL, BFL, F-number (relative)
ABS_PUPIL_MM = 1e-6  # pupil positions and diameters
ABS_RAY_MM = 1e-6  # real-ray intercepts
REL_RMS = 0.01  # RMS spot radius


# ------------------------------------------------------------------------------------------------
# Lenses
# ------------------------------------------------------------------------------------------------
# Optiland's sample Double Gauss (optiland.samples.objectives.DoubleGauss) in our schema. Glasses by their
# catalogue nd/Vd (N-SSK2, N-SK2, F5, N-SK16); evaluated at the Cauchy anchor 589.3 nm our index is nd exactly,
# which is what the reference numbers below were computed with. Stop (surface 6 in optiland, 5 here) sized
# for a 20 mm entrance pupil.
DG_ND = {"N-SSK2": 1.62229, "N-SK2": 1.60738, "F5": 1.60342, "N-SK16": 1.62041}
_DG_MAT = {"N-SSK2": "1.62229/53.27", "N-SK2": "1.60738/56.65", "F5": "1.60342/38.03", "N-SK16": "1.62041/60.32"}
_DG_ROWS = [  # radius, thickness, glass after the surface
    (56.20238, 8.75, "N-SSK2"),
    (152.28580, 0.5, "air"),
    (37.68262, 12.5, "N-SK2"),
    (None, 3.8, "F5"),
    (24.23130, 16.369445, "air"),
    (None, 13.747957, "air"),  # stop
    (-28.37731, 3.8, "F5"),
    (None, 11.0, "N-SK16"),
    (-37.92546, 0.5, "air"),
    (177.41176, 7.0, "N-SK16"),
    (-79.41143, 61.487536, "air"),
]
DG_EPD_MM = 20.0
DG_MAX_FIELD_DEG = 14.0
# Reference numbers for this lens (optiland, constant indices = nd, EPD 20, image plane of the sample):
DG_FACTS = {
    "efl": 100.003860,
    "fno": 5.000193,
    "bfl": 61.488054,
    "epl": 57.911893,  # entrance pupil after surface 1
    "image_y_14deg": [24.713570, 24.689041, 24.669683, 24.649623, 24.623873],  # Py = -1, -0.5, 0, 0.5, 1
    "rms_um": {0.0: 8.999, 10.0: 22.634, 14.0: 36.174},  # unclipped, 36 x 36 grid, about the centroid
}


def double_gauss() -> Lens:
    surfs = tuple(
        Surface(
            curvature_per_mm=0.0 if r is None else 1.0 / r,
            thickness_mm=t,
            semi_diameter_mm=24.0,
            material=_DG_MAT.get(m, m),
        )
        for r, t, m in _DG_ROWS
    )
    sensor = Sensor.from_half_diagonal(100.0 * math.tan(math.radians(DG_MAX_FIELD_DEG)), 960, 640)
    lens = Lens("Double Gauss (optiland sample)", surfs, 5, sensor, CAUCHY_ANCHOR_NM)
    return lens.with_stop_semi_diameter(stop_semi_diameter_for_epd(lens, DG_EPD_MM))


def asphere_singlet() -> Lens:
    """Even-asphere singlet: R1 40, k -0.6, A4 2e-6, A6 -1.5e-9, t 6, n 1.5168; R2 -200, 70 to the image;
    stop on the first surface, EPD 12."""
    surfs = (
        Surface(1.0 / 40.0, 6.0, 6.0, "1.5168/64.17", conic=-0.6, asphere_from_r2=(0.0, 2e-6, -1.5e-9)),
        Surface(-1.0 / 200.0, 70.0, 10.0, "air"),
    )
    return Lens("asphere singlet", surfs, 0, Sensor.from_half_diagonal(11.5, 960, 640), CAUCHY_ANCHOR_NM)


SINGLET_FACTS = {"efl": 65.053606, "bfl": 61.728873}

# name -> (lens factory, wavelength nm at which both programs get our indices)
CASES = {
    "double_gauss": (double_gauss, CAUCHY_ANCHOR_NM),
    "asphere_singlet": (asphere_singlet, CAUCHY_ANCHOR_NM),
    "cooke_triplet": (lambda: load_lens(LENSES_DIR / "cooke_triplet.json"), D_LINE_NM),
    "cooke_triplet_F": (lambda: load_lens(LENSES_DIR / "cooke_triplet.json"), 486.1327),
    "canon_rf50": (lambda: load_lens(LENSES_DIR / "canon_rf50mm_f1.8.json"), D_LINE_NM),
}


def with_image_distance(lens: Lens, distance_mm: float) -> Lens:
    """The same lens with the last vertex-to-image distance replaced."""
    surfs = list(lens.surfaces)
    surfs[-1] = replace(surfs[-1], thickness_mm=float(distance_mm))
    return replace(lens, surfaces=tuple(surfs))


def to_optiland(lens: Lens, wavelength_nm: float) -> Optic:
    """The same lens in optiland: constant indices from `lens.indices(wavelength_nm)`, object at infinity,
    image surface at our nominal sensor plane, aperture = our stop diameter, angle fields up to our
    half field of view, and our semi-diameters as radial apertures (clipping like ours)."""
    n = lens.indices(wavelength_nm)
    px = paraxial_data(lens, wavelength_nm)
    op = Optic()
    op.surfaces.add(index=0, radius=math.inf, thickness=math.inf, material=IdealMaterial(n=n[0]))
    for i, s in enumerate(lens.surfaces):
        assert s.kind == "standard"
        kw = dict(
            index=i + 1,
            radius=s.radius_mm,
            thickness=s.thickness_mm,
            material=IdealMaterial(n=n[i + 1]),
            is_stop=i == lens.stop_index,
        )
        if not s.is_spherical:
            # optiland's factory default Newton tolerance for aspheres is |F(t)| < 1e-6 mm; ours stops at
            # |dt| < 1e-12 mm. Ask for a float64-tight solve so the comparison measures the tracers, not it.
            kw.update(
                surface_type="even_asphere",
                conic=s.conic,
                coefficients=list(s.asphere_from_r2),
                tol=1e-13,
            )
        op.surfaces.add(aperture=RadialAperture(r_max=s.semi_diameter_mm), **kw)
    op.surfaces.add(index=len(lens.surfaces) + 1)  # image plane
    # The stop's diameter, so optiland derives the entrance pupil (and F-number) itself.
    stop_diameter = 2.0 * lens.surfaces[lens.stop_index].semi_diameter_mm
    op.set_aperture(aperture_type="float_by_stop_size", value=stop_diameter)
    op.fields.set_type(field_type="angle")
    op.fields.add(y=0.0)
    op.fields.add(y=px.hfov_deg)
    op.wavelengths.add(value=wavelength_nm / 1000.0, is_primary=True)
    return op


def _f(x) -> float:
    return float(np.asarray(x).reshape(-1)[0])


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    factory, wavelength = CASES[request.param]
    # Rays are aimed at the paraxial pupil of the design wavelength (ours) / primary wavelength (optiland):
    # make those the wavelength of the comparison.
    lens = replace(factory(), design_wavelength_nm=wavelength)
    # Image plane at the paraxial focus (infinity), so spots compare tracing only.
    lens = with_image_distance(lens, paraxial_data(lens, wavelength).bfl_mm)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = to_optiland(lens, wavelength)
    return request.param, lens, wavelength, op


# ------------------------------------------------------------------------------------------------
# Materials
# ------------------------------------------------------------------------------------------------
# Our catalogue's Sellmeier glasses against optiland's glass database (both from refractiveindex.info's Schott
# data): the Cooke triplet's N-SK16 / F2 and the Double Gauss's N-SK2 / F5.
@pytest.mark.parametrize("glass", ["N-SK16", "F2", "N-SK2", "F5"])
@pytest.mark.parametrize("wavelength_nm", [486.1327, D_LINE_NM, 656.2725])
def test_named_glass_index_matches_optiland_catalogue(glass, wavelength_nm):
    ours = float(parse_material(glass).n(wavelength_nm))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        theirs = _f(Material(glass, "schott").n(wavelength_nm / 1000.0))
    assert ours == pytest.approx(theirs, rel=1e-9), (glass, wavelength_nm, ours, theirs)  # the same Sellmeier data


def test_crosscheck_lenses_use_the_intended_indices():
    assert double_gauss().indices(CAUCHY_ANCHOR_NM)[1:5] == pytest.approx(
        [DG_ND["N-SSK2"], 1.0, DG_ND["N-SK2"], DG_ND["F5"]], rel=1e-14  # float64 at the Cauchy anchor
    )
    assert asphere_singlet().indices(CAUCHY_ANCHOR_NM)[1] == pytest.approx(1.5168, rel=1e-14)
    cooke = load_lens(LENSES_DIR / "cooke_triplet.json")
    assert {s.material for s in cooke.surfaces} == {"N-SK16", "F2", "air"}
    canon = load_lens(LENSES_DIR / "canon_rf50mm_f1.8.json")
    assert any(not s.is_spherical for s in canon.surfaces)


# ------------------------------------------------------------------------------------------------
# First-order data
# ------------------------------------------------------------------------------------------------
def test_paraxial_matches_optiland(case):
    name, lens, w, op = case
    ours = paraxial_data(lens, w)
    efl, fno = _f(op.paraxial.f2()), _f(op.paraxial.FNO())
    bfl = _f(op.paraxial.F2()) + lens.surfaces[-1].thickness_mm  # F2 is measured from the image surface
    assert ours.efl_mm == pytest.approx(efl, rel=REL_FIRST_ORDER), name
    assert ours.bfl_mm == pytest.approx(bfl, rel=REL_FIRST_ORDER), name
    assert ours.fno == pytest.approx(fno, rel=REL_FIRST_ORDER), name
    assert abs(ours.entrance_pupil_mm - _f(op.paraxial.EPD())) < ABS_PUPIL_MM
    assert abs(ours.entrance_pupil_z_mm - _f(op.paraxial.EPL())) < ABS_PUPIL_MM
    image_z = lens.nominal_sensor_z_mm
    assert abs((ours.exit_pupil_z_mm - image_z) - _f(op.paraxial.XPL())) < ABS_PUPIL_MM
    assert abs(ours.exit_pupil_mm - abs(_f(op.paraxial.XPD()))) < ABS_PUPIL_MM


def test_singlet_asphere_reference_numbers():
    px = paraxial_data(asphere_singlet())
    assert px.efl_mm == pytest.approx(SINGLET_FACTS["efl"], rel=REL_FIRST_ORDER)
    assert px.bfl_mm == pytest.approx(SINGLET_FACTS["bfl"], rel=REL_FIRST_ORDER)
    assert px.entrance_pupil_mm == pytest.approx(12.0, rel=1e-12)


# ------------------------------------------------------------------------------------------------
# Real rays
# ------------------------------------------------------------------------------------------------
def _start_rays(lens: Lens, w: float) -> Rays:
    """Rays over a 9 x 9 pupil grid (and a little beyond the pupil edge) at on-axis, meridional and skew
    fields up to the full half field of view, aimed at the paraxial entrance pupil."""
    hfov = math.radians(paraxial_data(lens, w).hfov_deg)
    pupil = uniform_disk_grid(9) * 1.05
    fields = [(0.0, 0.0), (0.0, 0.5 * hfov), (0.0, hfov), (0.45 * hfov, 0.6 * hfov), (-0.7 * hfov, 0.3 * hfov)]
    bundles = [rays_through_pupil(lens, pupil, None, (ax, ay)) for ax, ay in fields]
    o = torch.cat([b.o for b in bundles])
    d = torch.cat([b.d for b in bundles])
    return Rays(o, d, torch.ones(o.shape[0], dtype=torch.bool))


def _optiland_trace(op: Optic, rays: Rays, w: float):
    """Trace exactly these rays through optiland's surfaces (object surface skipped); returns per-surface
    intercepts (num_surfaces + 1, N, 3) in global coordinates (lens surfaces, then the image plane), the
    survival mask at the image and the final direction cosines."""
    o, d = rays.o.numpy(), rays.d.numpy()
    rr = RealRays(o[:, 0], o[:, 1], o[:, 2], d[:, 0], d[:, 1], d[:, 2], np.ones(len(o)), np.full(len(o), w / 1000.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op.surfaces.trace(rr, skip=1)
    surfs = [op.surfaces[k] for k in range(1, len(op.surfaces))]  # lens surfaces, then the image
    xyz = np.stack([np.stack([np.asarray(s.x), np.asarray(s.y), np.asarray(s.z)], axis=-1) for s in surfs])
    alive = (np.asarray(rr.i) > 0) & np.all(np.isfinite(xyz), axis=(0, 2))
    return xyz, alive, np.stack([np.asarray(rr.L), np.asarray(rr.M), np.asarray(rr.N)], axis=-1)


def test_real_ray_intercepts_match_optiland(case):
    name, lens, w, op = case
    rays = _start_rays(lens, w)
    ours = trace(lens, rays, w, record=True)
    xyz, alive, dirs = _optiland_trace(op, rays, w)
    valid = ours.rays.valid.numpy()
    # Same rays survive: both clip at the same clear apertures.
    assert np.array_equal(valid, alive), (name, np.flatnonzero(valid != alive))
    assert valid.sum() >= 0.5 * len(valid), name  # a meaningful number of rays got through
    worst = 0.0
    for i, hit in enumerate(ours.hits):
        diff = np.abs(hit.numpy()[valid] - xyz[i][valid]).max()
        worst = max(worst, diff)
        assert diff < ABS_RAY_MM, (name, f"surface {i}", diff)
    image = np.abs(ours.rays.o.numpy()[valid] - xyz[-1][valid]).max()
    assert image < ABS_RAY_MM, (name, "image plane", image)
    assert np.abs(ours.rays.d.numpy()[valid] - dirs[valid]).max() < 1e-9, name  # unit vectors: relative


# ------------------------------------------------------------------------------------------------
# RMS spot
# ------------------------------------------------------------------------------------------------
def test_rms_spot_matches_optiland(case):
    name, lens, w, op = case
    hfov = paraxial_data(lens, w).hfov_deg
    fractions = (0.0, 0.7, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sd = SpotDiagram(
            op,
            fields=[(0.0, f) for f in fractions],
            num_rings=36,
            distribution="uniform",
            coordinates="global",
            reference="centroid",
        )
        theirs = [1000.0 * _f(r[0]) for r in sd.rms_spot_radius()]
    for f, rms_theirs in zip(fractions, theirs):
        ours = spot(lens, f * hfov, wavelength_nm=w, grid=36, sensor_z_mm=lens.nominal_sensor_z_mm)
        assert ours.rms_um == pytest.approx(rms_theirs, rel=REL_RMS), (name, f, ours.rms_um, rms_theirs)


# ------------------------------------------------------------------------------------------------
# Optiland's own Double Gauss sample, its own tracing API, and the reference numbers
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def dg_sample():
    """optiland.samples.objectives.DoubleGauss with constant indices nd and a 20 mm entrance pupil."""
    from optiland.samples.objectives import DoubleGauss

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = DoubleGauss()
        for i, (_, _, m) in enumerate(_DG_ROWS, start=1):
            if m != "air":
                op.updater.set_index(DG_ND[m], i)
        op.set_aperture(aperture_type="EPD", value=DG_EPD_MM)
        op.wavelengths.add(value=D_LINE_NM / 1000.0, is_primary=True)
    return op


def test_double_gauss_sample_first_order(dg_sample):
    lens = double_gauss()
    ours = paraxial_data(lens)
    theirs = {
        "efl": _f(dg_sample.paraxial.f2()),
        "fno": _f(dg_sample.paraxial.FNO()),
        "bfl": _f(dg_sample.paraxial.F2()) + _DG_ROWS[-1][1],
        "epl": _f(dg_sample.paraxial.EPL()),
    }
    mine = {"efl": ours.efl_mm, "fno": ours.fno, "bfl": ours.bfl_mm, "epl": ours.entrance_pupil_z_mm}
    for k in ("efl", "fno", "bfl"):
        assert mine[k] == pytest.approx(theirs[k], rel=REL_FIRST_ORDER), k
        assert mine[k] == pytest.approx(DG_FACTS[k], rel=REL_FIRST_ORDER), k
    assert abs(mine["epl"] - theirs["epl"]) < ABS_PUPIL_MM
    assert abs(mine["epl"] - DG_FACTS["epl"]) < ABS_PUPIL_MM
    assert ours.entrance_pupil_mm == pytest.approx(DG_EPD_MM, rel=1e-12)


def _dg_unclipped(lens: Lens) -> tuple[Lens, float, float]:
    """The sample has no clear apertures: our lens with every aperture opened up, and the pupil (radius, z)
    of the 20 mm-EPD original to aim at."""
    px = paraxial_data(lens)
    big = replace(lens, surfaces=tuple(replace(s, semi_diameter_mm=30.0) for s in lens.surfaces))
    return big, px.entrance_pupil_mm / 2.0, px.entrance_pupil_z_mm


def test_double_gauss_sample_real_rays(dg_sample):
    big, r_ep, z_ep = _dg_unclipped(double_gauss())
    py = torch.tensor([-1.0, -0.5, 0.0, 0.5, 1.0], dtype=torch.float64)
    pupil = torch.stack([torch.zeros_like(py), py], dim=-1)
    rays = rays_through_pupil(big, pupil, None, (0.0, math.radians(DG_MAX_FIELD_DEG)), r_ep, z_ep)
    ours = trace(big, rays)  # image plane of the sample: its last thickness
    assert bool(ours.rays.valid.all())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        theirs = dg_sample.trace_generic(0.0, 1.0, np.zeros(5), py.numpy(), D_LINE_NM / 1000.0)
    y_ours = ours.rays.o[:, 1].numpy()
    np.testing.assert_allclose(y_ours, np.asarray(theirs.y), rtol=0, atol=ABS_RAY_MM)
    np.testing.assert_allclose(np.asarray(theirs.x), 0.0, atol=1e-12)
    np.testing.assert_allclose(y_ours, DG_FACTS["image_y_14deg"], rtol=0, atol=ABS_RAY_MM)


@pytest.mark.parametrize("field_deg", [0.0, 10.0, 14.0])
def test_double_gauss_sample_rms_spot(dg_sample, field_deg):
    big, r_ep, z_ep = _dg_unclipped(double_gauss())
    rays = rays_through_pupil(big, uniform_disk_grid(36), None, (0.0, math.radians(field_deg)), r_ep, z_ep)
    res = trace(big, rays)
    assert bool(res.rays.valid.all())
    xy = res.rays.o[:, :2]
    ours = 1000.0 * float(torch.sqrt(((xy - xy.mean(0)) ** 2).sum(-1).mean()))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        theirs_rays = dg_sample.trace(0.0, field_deg / DG_MAX_FIELD_DEG, D_LINE_NM / 1000.0, 36, "uniform")
    x, y = np.asarray(theirs_rays.x), np.asarray(theirs_rays.y)
    assert len(x) == xy.shape[0]
    theirs = 1000.0 * math.sqrt(np.mean((x - x.mean()) ** 2 + (y - y.mean()) ** 2))
    assert ours == pytest.approx(theirs, rel=REL_RMS)
    assert ours == pytest.approx(DG_FACTS["rms_um"][field_deg], rel=REL_RMS)
    # Same rays in the same order: the spots agree point by point, not just in RMS.
    np.testing.assert_allclose(xy[:, 0].numpy(), x, rtol=0, atol=ABS_RAY_MM)
    np.testing.assert_allclose(xy[:, 1].numpy(), y, rtol=0, atol=ABS_RAY_MM)


# ------------------------------------------------------------------------------------------------
# The Z35's best-focus map against optiland's field curvature
# ------------------------------------------------------------------------------------------------
def test_z35_map_corner_offset_lies_between_optilands_sagittal_and_tangential_focus():
    # Independent check of the Z35's traced best-focus map: optiland's field curvature of DiffOptics' scaled file,
    # object at infinity, at the full field (the sensor corner). Image-side shift dz (mm, from the paraxial focus)
    # -> object diopters dz / f^2 (Newton). The min-RMS focus the map traces lies between the sagittal and
    # tangential foci. Both tracers read our import, so this checks the tracing, not the reading: with the file's
    # aspheres misread (r^2 terms, before 2026-11-26) they agreed on ~45 D at the corner; read as DiffOptics
    # defines them the lens's field is flat (benchmarks/probes/z35_import.py, tests/deploy/lens/test_lens_io.py).
    from optiland.analysis import FieldCurvature

    from aat_deploy.focus.bestfocus import for_lens

    path = LENSES_DIR / "nikon_z35_f1.8_diffoptics.json"
    lens = load_lens(path)
    w = lens.design_wavelength_nm
    px = paraxial_data(lens, w)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = to_optiland(with_image_distance(lens, px.bfl_mm), w)
        fc = FieldCurvature(op, wavelengths=[w / 1000.0], num_points=11)
    tan_mm, sag_mm = (float(np.asarray(fc.data[0][i]).reshape(-1)[-1]) for i in (0, 1))
    to_d = lambda dz_mm: -dz_mm / px.efl_mm**2 * 1e3  # noqa: E731 (inward image shift = nearer object: +D)
    lo, hi = sorted((to_d(tan_mm), to_d(sag_mm)))
    m, _ = for_lens(path, compute=False)
    corner = float(m.object_diopters[-1, 0] - m.focus_diopters[0])  # frame focused at (near) infinity
    assert m.radius[-1] == 1.0 and m.focus_diopters[0] < 0.05
    assert max(abs(lo), abs(hi)) < 3.0, (lo, hi)  # a corrected field: both foci within ~7 um of the paraxial one
    assert lo <= corner <= hi, (lo, corner, hi)
