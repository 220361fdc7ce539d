"""Lens files: our schema round-trips, every shipped and shared prescription loads or fails clearly."""

from __future__ import annotations

import json
import math

import pytest
from conftest import LENSES
from hypothesis import given, settings
from hypothesis import strategies as st

from aat_deploy.lens.io import LensFileError, lens_from_dict, load_lens, save_lens
from aat_deploy.lens.materials import CauchyNdVd, UnknownMaterialError, parse_material
from aat_deploy.optics.paraxial import paraxial_data

SHIPPED = sorted(LENSES.glob("*.json"))


def test_all_shipped_lenses_load_with_provenance():
    names = {p.stem for p in SHIPPED}
    assert {"canon_rf50mm_f1.8", "paper_50mm_f2.8", "canon_ef50mm_f1.8", "cooke_triplet",
            "cellphone_asphere", "ideal_thin_rf50"} <= names
    for p in SHIPPED:
        lens = load_lens(p)
        assert lens.provenance.get("source"), p
        assert paraxial_data(lens).efl_mm > 0


def test_roundtrip_our_schema(tmp_path):
    lens = load_lens(LENSES / "canon_rf50mm_f1.8.json")
    out = tmp_path / "rf50.json"
    save_lens(lens, out)
    again = load_lens(out)
    assert again == lens
    assert again.prescription_hash() == lens.prescription_hash()
    with pytest.raises(FileExistsError):
        save_lens(lens, out)  # never overwrite without force


def test_rf50_patent_numbers():
    lens = load_lens(LENSES / "canon_rf50mm_f1.8.json")
    radii = [s.radius_mm for s in lens.surfaces]
    assert radii[0] == pytest.approx(28.621) and radii[9] == pytest.approx(-18.373)
    assert math.isinf(radii[lens.stop_index]) and lens.stop_index == 5
    assert lens.surfaces[8].asphere_from_r2[1] == pytest.approx(-4.12032e-05)
    p = paraxial_data(lens)
    assert p.efl_mm == pytest.approx(49.56, abs=0.05)  # patent: f = 49.56 mm
    assert p.fno == pytest.approx(1.88, abs=0.02)  # the patent's figures, to their last digit


def test_thin_lens_matches_rf50():
    rf, thin = load_lens(LENSES / "canon_rf50mm_f1.8.json"), load_lens(LENSES / "ideal_thin_rf50.json")
    a, b = paraxial_data(rf), paraxial_data(thin)
    assert b.efl_mm == pytest.approx(a.efl_mm, rel=1e-9)
    assert b.fno == pytest.approx(a.fno, rel=1e-9)
    assert thin.sensor == rf.sensor


def _minimal(**over):
    d = {"format": "aat-lens-v1", "name": "t", "stop_index": 0,
         "sensor": {"width_mm": 36, "height_mm": 24, "width_px": 960, "height_px": 640},
         "surfaces": [{"radius_mm": 50, "thickness_mm": 5, "semi_diameter_mm": 10, "material": "N-BK7"},
                      {"radius_mm": None, "thickness_mm": 95, "semi_diameter_mm": 10, "material": "air"}]}
    d.update(over)
    return d


def test_schema_errors_are_one_line_and_name_the_problem():
    bad_glass = _minimal()
    bad_glass["surfaces"][0]["material"] = "UNOBTAINIUM-7"
    with pytest.raises(LensFileError, match=r"x.json: surface 0: unknown glass 'UNOBTAINIUM-7'"):
        lens_from_dict(bad_glass, "x.json")
    with pytest.raises(LensFileError, match="stop_index 7"):
        lens_from_dict(_minimal(stop_index=7), "x.json")
    neg = _minimal()
    neg["surfaces"][1]["semi_diameter_mm"] = -1
    with pytest.raises(LensFileError, match="surface 1: semi-diameter must be positive"):
        lens_from_dict(neg, "x.json")
    with pytest.raises(LensFileError, match="not square"):
        lens_from_dict(_minimal(sensor={"width_mm": 36, "height_mm": 30, "width_px": 960, "height_px": 640}), "x")


def test_load_errors(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text("{not json")
    with pytest.raises(LensFileError, match="broken.json: invalid JSON"):
        load_lens(p)
    with pytest.raises(LensFileError, match="no such file"):
        load_lens(tmp_path / "missing.json")
    z = tmp_path / "tor.zmx"
    z.write_text("UNIT MM\nSURF 0\n  TYPE STANDARD\n  DISZ INFINITY\nSURF 1\n  TYPE TOROIDAL\n  CURV 0.01\n"
                 "  DISZ 5\n  DIAM 10\nSURF 2\n  TYPE STANDARD\n  DIAM 10\n")
    with pytest.raises(LensFileError, match=r"tor.zmx: line 6: surface type TOROIDAL is not supported"):
        load_lens(z)


ZMX = """VERS 190513
UNIT MM X W X CM MR CPMM
ENPD 10
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ INFINITY
SURF 1
  STOP
  TYPE EVENASPH
  CURV 0.025
  CONI -0.6
  PARM 1 0
  PARM 2 2e-6
  PARM 3 -1.5e-9
  DISZ 6
  GLAS N-BK7 1 0 1.5168 64.17
  DIAM 8 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV -0.005
  DISZ 70
  GLAS ___BLANK 1 0 1.6 40
  DIAM 8
SURF 3
  TYPE STANDARD
  CURV 0
  DISZ 1
  DIAM 8
SURF 4
  TYPE STANDARD
  DIAM 12
"""


@pytest.mark.parametrize("encoding", ["ascii", "utf-16"])
def test_zmx_reader(tmp_path, encoding):
    p = tmp_path / "t.zmx"
    p.write_bytes(ZMX.encode(encoding))
    lens = load_lens(p)
    s0 = lens.surfaces[0]
    assert s0.radius_mm == pytest.approx(40.0) and s0.conic == -0.6
    assert s0.asphere_from_r2 == (0.0, 2e-6, -1.5e-9)
    assert s0.material == "N-BK7"
    assert isinstance(parse_material(lens.surfaces[1].material), CauchyNdVd)
    assert lens.surfaces[1].thickness_mm == 70
    assert paraxial_data(lens).entrance_pupil_mm == pytest.approx(10.0)  # stop resized to ENPD
    assert lens.sensor.half_diagonal_mm == pytest.approx(12.0)


def test_legacy_json_uses_absolute_d_and_ai_from_r2(tmp_path):
    d = {"r_last": 21.64, "d_sensor": 60.0, "surfaces": [
        {"type": "Aspheric", "r": 10, "c": 0.02, "d": 0.0, "d_next": 999, "k": 0.0,
         "ai": [1e-4, 2e-6], "mat2": "1.5/60"},
        {"type": "Spheric", "r": 10, "c": -0.01, "d": 5.0, "mat2": "air"},
        {"type": "Spheric", "r": 8, "c": 0.0, "d": 8.0, "mat2": "air"}]}
    p = tmp_path / "legacy.json"
    p.write_text(json.dumps(d))
    lens = load_lens(p)
    assert [s.thickness_mm for s in lens.surfaces] == [5.0, 3.0, 52.0]  # `d` wins over d_next
    assert lens.surfaces[0].asphere_from_r2 == (1e-4, 2e-6)  # starts at r^2
    assert lens.stop_index == 2  # first surface with air on both sides
    assert lens.sensor.width_px == 640 and lens.sensor.half_diagonal_mm == pytest.approx(21.64)



DIFFOPTICS_ROWS = """header line
type distance roc diameter material
O 0 0 0 AIR
S 0 {roc} 4.0 1.5/60 {extra}
S 1.0 -8.0 4.0 AIR
A 0.5 0 3.0 OCCLUDER
I 9.0 0 6.0 AIR
"""


def _format_sag(roc: float, k: float, a_from_r4: tuple[float, ...], r: float) -> float:
    """The DiffOptics format's sag, written from its definition: conic base + a4 r^4 + a6 r^6 + ..."""
    c = 1.0 / roc
    z = c * r * r / (1.0 + math.sqrt(1.0 - (1.0 + k) * c * c * r * r))
    return z + sum(a * r ** (4 + 2 * i) for i, a in enumerate(a_from_r4))


def test_diffoptics_asphere_columns_are_k_then_r4_terms(tmp_path):
    # `S ... material k a4 a6`: the first coefficient after the conic multiplies r^4 (read as r^2 before
    # 2026-11-26, which changed the Z35's paraxial power: benchmarks/probes/z35_import.py).
    p = tmp_path / "asph.txt"
    p.write_text(DIFFOPTICS_ROWS.format(roc=5.0, extra="-0.5 1e-3 2e-5"))
    s = load_lens(p).surfaces[0]
    assert s.conic == -0.5 and s.asphere_from_r2 == (0.0, 1e-3, 2e-5)
    # By hand at r = 1 mm: c = 0.2, 0.2 / (1 + sqrt(1 - 0.5 * 0.04)) = 0.1002526..., + 1e-3 + 2e-5.
    assert s.sag(1.0) == pytest.approx(0.2 / (1.0 + math.sqrt(0.98)) + 1.02e-3, rel=1e-12)
    assert s.paraxial_curvature_per_mm == pytest.approx(0.2)  # aspheric terms leave the paraxial power alone
    p.write_text(DIFFOPTICS_ROWS.format(roc=5.0, extra="-0.5"))  # a conic alone
    s = load_lens(p).surfaces[0]
    assert s.conic == -0.5 and s.asphere_from_r2 == ()


@settings(max_examples=40, deadline=None)
@given(roc=st.floats(3.0, 50.0) | st.floats(-50.0, -3.0), k=st.floats(-2.0, 1.0),
       a=st.lists(st.floats(-1e-3, 1e-3), min_size=1, max_size=4), r=st.floats(0.0, 1.5))
def test_diffoptics_sag_matches_the_format_definition(tmp_path_factory, roc, k, a, r):
    p = tmp_path_factory.mktemp("do") / "asph.txt"
    p.write_text(DIFFOPTICS_ROWS.format(roc=repr(roc), extra=" ".join(map(repr, [k, *a]))))
    s = load_lens(p).surfaces[0]
    assert s.sag(r * r) == pytest.approx(_format_sag(roc, k, tuple(a), r), rel=1e-9, abs=1e-15)


def test_diffoptics_z35_paraxial_focus_is_on_its_image_plane(shared_lenses):
    # Independent evidence for the r^4-first reading: the file's last gap (0.043 mm, cover glass to `I`) puts its
    # image plane at the paraxial focus within a micron; the r^2-first reading put the focus 0.52 mm behind it.
    txt = load_lens(shared_lenses / "diffoptics_nikon_z35_f1.8_JPA2019090949.txt")
    px = paraxial_data(txt, 587.5618)
    assert px.bfl_mm == pytest.approx(txt.surfaces[-1].thickness_mm, abs=2e-3)
    assert px.fno == pytest.approx(1.8, abs=0.05)  # the f/1.8 design, scaled
    shipped = load_lens(LENSES / "nikon_z35_f1.8_diffoptics.json")  # our copy is the reader's, term for term
    assert [s.asphere_from_r2 for s in shipped.surfaces] == [s.asphere_from_r2 for s in txt.surfaces]
    assert [s.curvature_per_mm for s in shipped.surfaces] == [s.curvature_per_mm for s in txt.surfaces]

def test_materials():
    m = parse_material("1.5168/64.17")
    assert float(m.n(589.3)) == pytest.approx(1.5168, rel=1e-12)  # the paper's anchor (float64 rounding)
    nf, nc = float(m.n(486.1)), float(m.n(656.3))
    assert (1.5168 - 1) / (nf - nc) == pytest.approx(64.17)
    bk7 = parse_material("n-bk7")  # case-insensitive names
    assert float(bk7.n(587.5618)) == pytest.approx(1.5168, abs=1e-5)  # the catalogue's nd, to its last digits
    assert parse_material("air").is_air and float(parse_material("AIR").n(500)) == 1.0
    with pytest.raises(UnknownMaterialError, match="unknown glass 'FOO'"):
        parse_material("FOO")


SHARED_EXPECT_FAIL = {  # non-prescription files in shared/data/lenses: they must fail with a clear error
    "MANIFEST.md": "unsupported lens file type",
    "deeplens_lenses_readme.md": "unsupported lens file type",
    "diffoptics_lenses_README_format.md": "unsupported lens file type",
    "sdirt_rf50mm_stop_radius_notes.txt": "not a DiffOptics lens",
}


def test_every_shared_prescription_loads_or_fails_clearly(shared_lenses):
    loaded = []
    for p in sorted(shared_lenses.iterdir()):
        if p.name in SHARED_EXPECT_FAIL:
            with pytest.raises(LensFileError, match=SHARED_EXPECT_FAIL[p.name]) as e:
                load_lens(p)
            assert p.name in str(e.value) and "\n" not in str(e.value)
            continue
        lens = load_lens(p)
        assert paraxial_data(lens).efl_mm > 0, p
        loaded.append(p.name)
    assert len(loaded) >= 13


def test_shared_same_lens_in_two_formats_agrees(shared_lenses):
    a = paraxial_data(load_lens(shared_lenses / "deeplens_ef35mm_f2.0.json"))
    b = paraxial_data(load_lens(shared_lenses / "deeplens_ef35mm_f2.0.zmx"))
    assert a.efl_mm == pytest.approx(b.efl_mm, rel=1e-6)
    assert a.fno == pytest.approx(b.fno, rel=1e-6)
    # The paper's RF50 file and our re-entered patent numbers describe the same lens (radii rounded there).
    paper = paraxial_data(load_lens(shared_lenses / "aat_rf50mm_f1.8_lens.json"), 589.3)
    ours = paraxial_data(load_lens(LENSES / "canon_rf50mm_f1.8.json"), 589.3)
    assert paper.efl_mm == pytest.approx(ours.efl_mm, rel=3e-3)
