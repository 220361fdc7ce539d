"""The camera calibration file (`aat-camera-calibration-v1`, aat_deploy/calibrate/format.py): round trips, the
focus-error families against the `focus_metadata` effect that makes them, the per-pixel maps, and the reader's
one-line errors on anything malformed (hand-made cases and hypothesis)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aat_deploy.calibrate import (
    FORMAT,
    CalibrationError,
    CameraCalibration,
    CameraIdentity,
    FieldPoly,
    FocusError,
    defocus_scale_px_per_d,
    in_focus_diopters,
    load_calibration,
    save_calibration,
    thin_lens_defocus_scale_px_per_d,
)
from aat_deploy.calibrate.format import field_grid, poly_terms
from aat_deploy.optics.thin_lens import blur_diameter_px
from aat_deploy.render import effects as fx

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def make_cal(focus=FocusError(), tilt=(0.0, 0.0), curvature=0.0, blur=True, j=2) -> CameraCalibration:
    """x and y tilts (diopters at the frame edge), curvature (diopters at x^2 + y^2 = 1), constant over focus."""
    terms = poly_terms(2, constant=False)  # x, y, x^2, xy, y^2
    c = np.zeros((len(terms), j))
    c[0, 0], c[1, 0], c[2, 0], c[4, 0] = tilt[0], tilt[1], curvature, curvature
    b = FieldPoly(poly_terms(0, constant=True), np.array([[40.0, 4.0]]), (0.1, 2.0)) if blur else None
    return CameraCalibration(CameraIdentity("Canon", "EOS R", "RF50mm F1.8 STM", 50.0, 1.8), (960, 640), focus,
                             FieldPoly(terms, c, (0.1, 2.0)), b, (36.0, 24.0), {"rms_d": 0.01}, {}, {"method": "test"})


def test_round_trip(tmp_path):
    cal = make_cal(FocusError("monotone", map_d=(0.1, 0.12, 1.0, 1.05, 2.0, 2.2), intervals={"bias_d": [0, 0]}),
                   tilt=(0.05, -0.02), curvature=0.03)
    p = save_calibration(cal, tmp_path / "cam.json")
    back = load_calibration(p)
    assert json.loads(p.read_text())["format"] == FORMAT
    f = [0.5, 1.3, 7.0]
    np.testing.assert_array_equal(in_focus_diopters(back, f, 40, 60), in_focus_diopters(cal, f, 40, 60))
    np.testing.assert_array_equal(defocus_scale_px_per_d(back, 40, 60), defocus_scale_px_per_d(cal, 40, 60))
    assert back.camera == cal.camera and back.size_px == cal.size_px and back.sensor_mm == cal.sensor_mm


def test_existing_file_needs_force(tmp_path):
    p = tmp_path / "cam.json"
    p.write_text("mine")
    with pytest.raises(CalibrationError, match="exists"):
        save_calibration(make_cal(), p)
    assert p.read_text() == "mine"
    save_calibration(make_cal(), p, force=True)
    assert load_calibration(p).size_px == (960, 640)


@pytest.mark.parametrize("params", [{"bias_d": 0.07}, {"bias_d": -0.1}, {"bias_d": 0.0, "scale": 1.3},
                                    {"bias_d": 0.0, "scale": 0.8},
                                    {"bias_d": 0.0, "map_d": [0.2, 0.25, 1.0, 1.1, 2.5, 2.45 + 0.2]}])
def test_focus_error_inverts_the_focus_metadata_effect(params):
    """The family that the `focus_metadata` effect applies to the true focus is undone exactly by FocusError."""
    eff = fx.make("focus_metadata", **params)
    true_m = np.array([0.45, 0.7, 1.0, 1.9, 4.0, 9.0])
    reported = eff.report_focus(true_m, None, np.random.default_rng(0))
    family = "monotone" if params.get("map_d") else "scale" if params.get("scale", 1) != 1 else "offset"
    fe = FocusError(family, bias_d=params["bias_d"], scale=params.get("scale", 1.0), map_d=tuple(params.get("map_d", ())))
    np.testing.assert_allclose(fe.true_diopters(1 / reported), 1 / true_m, atol=1e-12)


def test_maps_centre_tilt_curvature_and_shapes():
    cal = make_cal(FocusError("scale", scale=1.25), tilt=(0.04, 0.0), curvature=0.05)
    h, w = 64, 96
    d = in_focus_diopters(cal, [1.0, 2.0], h, w)
    assert d.shape == (2, h, w) and d.dtype == np.float32
    x, y = field_grid(h, w)
    want = np.array([1.25, 0.625])[:, None, None] + 0.04 * x + 0.05 * (x * x + y * y)
    np.testing.assert_allclose(d, want, atol=1e-6)
    # the right edge (x > 0) is farther in diopters than the left edge by the tilt
    assert d[0, h // 2, -1] - d[0, h // 2, 0] == pytest.approx(0.08 * (1 - 1 / w), abs=1e-5)
    # any resolution: the same field positions
    big = in_focus_diopters(cal, [1.0], 2 * h, 2 * w)[0]
    np.testing.assert_allclose(big.reshape(h, 2, w, 2).mean((1, 3)), d[0], atol=1e-4)


def test_focus_dependent_field_term_is_held_beyond_the_range():
    terms = poly_terms(1, constant=False)
    c = np.array([[0.0, 0.1], [0.0, 0.0]])  # x term: -0.1 at the range's near... P1(tau) = tau
    cal = CameraCalibration(CameraIdentity(), (100, 100), FocusError(), FieldPoly(terms, c, (0.5, 1.5)))
    edge = lambda f: float(in_focus_diopters(cal, [f], 1, 2)[0, 0, 1] - 1 / f)  # x = 0.5
    assert edge(1 / 1.5) == pytest.approx(0.05, abs=1e-6)
    assert edge(1 / 0.5) == pytest.approx(-0.05, abs=1e-6)
    assert edge(1 / 3.0) == pytest.approx(0.05, abs=1e-6)  # held beyond
    assert edge(1.0) == pytest.approx(0.0, abs=1e-6)


def test_defocus_scale_scales_with_width_and_thin_lens_fallback():
    cal = make_cal()
    k = defocus_scale_px_per_d(cal, 640, 960)
    lo, hi = cal.best_focus.focus_range_d
    assert k.shape == (640, 960) and float(k[0, 0]) == pytest.approx(40.0, rel=1e-6)  # middle of the range: P1 = 0
    assert float(defocus_scale_px_per_d(cal, 320, 480)[0, 0]) == pytest.approx(20.0, rel=1e-6)
    assert float(defocus_scale_px_per_d(cal, 640, 960, focus_m=1 / hi)[0, 0]) == pytest.approx(44.0, rel=1e-6)
    thin = make_cal(blur=False)
    kt = defocus_scale_px_per_d(thin, 640, 960, focus_m=1.0)
    want = thin_lens_defocus_scale_px_per_d(50.0, 1.8, 36 / 960 * 1000, 1.0)
    assert float(kt[0, 0]) == pytest.approx(want, rel=1e-6)
    # the thin-lens slope against the blur formula itself, 0.3 D from focus (linear in diopters within 2 %)
    b = blur_diameter_px(np.array([1 / 1.3]), np.array([1.0]), 50.0, 50 / 1.8, 0.0375)[0]
    assert want * 0.3 == pytest.approx(b, rel=0.02)
    anonymous = CameraCalibration(CameraIdentity(), (960, 640), FocusError(), thin.best_focus)
    with pytest.raises(CalibrationError, match="thin-lens"):
        defocus_scale_px_per_d(anonymous, 64, 96)


def test_identity_mismatch():
    cam = make_cal().camera
    assert cam.mismatch("canon", "eos r", None, 50.4, 1.8) == []
    bad = cam.mismatch("Nikon", "Z6", "NIKKOR", 35.0, 2.8)
    assert len(bad) == 5 and "make 'Nikon'" in bad[0]
    assert CameraIdentity().mismatch("Nikon", "Z6", "x", 35, 2) == []  # nothing known: nothing to compare


def test_aspect_warning():
    cal = make_cal()
    assert cal.aspect_warning(480, 720) == ""
    assert "960x640" in cal.aspect_warning(480, 480)


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.update(format="aat-best-focus-map-v1"), "not a camera calibration"),
    (lambda d: d.pop("best_focus"), "missing key 'best_focus'"),
    (lambda d: d["sensor"].update(width_px=0), "width_px"),
    (lambda d: d["sensor"].update(width_px=True), "width_px"),
    (lambda d: d["camera"].update(f_number="f/2"), "f_number"),
    (lambda d: d["focus_error"].update(family="cubic"), "family"),
    (lambda d: d["focus_error"].update(scale=-1), "scale"),
    (lambda d: d["focus_error"].update(map_d=[1.0, 1.0, 0.5, 2.0]), "map_d"),
    (lambda d: d["best_focus"].update(terms=[[0, 0]], coefficients=[[0.1]]), "constant"),
    (lambda d: d["best_focus"].update(coefficients=[[1.0]]), "coefficients"),
    (lambda d: d["best_focus"].update(terms=[[40, 0]] * 5), "degree"),
    (lambda d: d["best_focus"].update(focus_range_d=[2, 1]), "focus_range_d"),
    (lambda d: d["best_focus"].update(coefficients=[[1e300, 0]] * 5), "coefficients"),
    (lambda d: d.update(residuals=[1, 2]), "residuals"),
])
def test_malformed_files_are_one_line_errors(tmp_path, mutate, match):
    d = make_cal().to_dict()
    mutate(d)
    p = tmp_path / "cam.json"
    p.write_text(json.dumps(d))
    with pytest.raises(CalibrationError, match=match) as e:
        load_calibration(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)


def test_unreadable_files(tmp_path):
    for name, content, match in (("missing.json", None, "missing"), ("bin.json", b"\xff\xfe\x00", "UTF-8"),
                                 ("text.json", b"{oops", "not valid JSON"), ("list.json", b"[]", "format")):
        p = tmp_path / name
        if content is not None:
            p.write_bytes(content)
        with pytest.raises(CalibrationError, match=match):
            load_calibration(p)
    with pytest.raises(CalibrationError, match="folder"):
        load_calibration(tmp_path)


# -- property-based: any JSON, and any mutation of a valid file, is a calibration or a CalibrationError -----------
json_values = st.recursive(st.none() | st.booleans() | st.integers(-10**30, 10**30) | st.floats(allow_nan=True)
                           | st.text(max_size=8), lambda c: st.lists(c, max_size=4)
                           | st.dictionaries(st.text(max_size=8), c, max_size=4), max_leaves=12)


def _paths(d, prefix=()):
    if isinstance(d, dict):
        for k, v in d.items():
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield prefix + (i,)
            yield from _paths(v, prefix + (i,))


@FUZZ
@given(data=st.data())
def test_mutated_files_never_crash(tmp_path, data):
    d = make_cal(FocusError("monotone", map_d=(0.1, 0.12, 1.0, 1.05))).to_dict()
    paths = list(_paths(d))
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(paths))
        parent = d
        try:
            for k in path[:-1]:
                parent = parent[k]
            if data.draw(st.booleans()):
                parent[path[-1]] = data.draw(json_values)
            elif isinstance(parent, dict):
                parent.pop(path[-1], None)
        except (KeyError, IndexError, TypeError):
            continue
    p = tmp_path / "fuzz.json"
    p.write_text(json.dumps(d))
    try:
        cal = load_calibration(p)
    except CalibrationError as e:
        assert "\n" not in str(e) and str(p) in str(e)
        return
    try:  # a file that reads must give finite maps (or a one-line error for what it lacks)
        maps = [in_focus_diopters(cal, [0.7, 3.0], 6, 9)]
        maps.append(defocus_scale_px_per_d(cal, 6, 9))
    except CalibrationError:
        return
    for m in maps:
        assert np.isfinite(m).all()


@FUZZ
@given(raw=json_values)
def test_any_json_never_crashes(tmp_path, raw):
    p = tmp_path / "any.json"
    p.write_text(json.dumps(raw))
    with pytest.raises(CalibrationError):
        load_calibration(p)


@FUZZ
@given(bias=st.floats(-0.3, 0.3), scale=st.floats(0.6, 1.6), focus=st.lists(st.floats(0.2, 50), min_size=1,
                                                                              max_size=6))
def test_offset_and_scale_round_trip_through_the_effect(bias, scale, focus):
    eff = fx.make("focus_metadata", bias_d=bias, scale=scale)
    true_m = np.asarray(focus)
    rep = eff.report_focus(true_m, None, np.random.default_rng(0))
    keep = 1 / rep > 0.0101  # the effect stops reports at 100 m
    fe = FocusError("scale", bias_d=bias, scale=scale)
    np.testing.assert_allclose(fe.true_diopters(1 / rep[keep]), 1 / true_m[keep], atol=1e-9)
    assert math.isfinite(float(in_focus_diopters(make_cal(fe), rep, 2, 3).sum()))


def test_format_api_is_torch_free(tmp_path):
    from deploy_fixtures import run_without_torch

    p = save_calibration(make_cal(FocusError("offset", bias_d=0.05), tilt=(0.03, 0.01)), tmp_path / "cam.json")
    r = run_without_torch(f"""
        import sys
        from aat_deploy.calibrate import load_calibration, in_focus_diopters, defocus_scale_px_per_d
        cal = load_calibration({str(p)!r})
        d = in_focus_diopters(cal, [0.5, 1.0, 2.0], 48, 72)
        k = defocus_scale_px_per_d(cal, 48, 72)
        assert d.shape == (3, 48, 72) and k.shape == (48, 72)
        print(any(m == "torch" or m.startswith("torch.") for m in sys.modules))
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == "False"


def test_diagnosis_takes_the_calibrations_focus_error():
    """aat-diagnose --calibration: the captures' reported focus corrected by the calibration's error (scale 1.1:
    a frame reported at 1.1 m was focused at 1.0 m), what the model and the twins are then given."""
    from pathlib import Path

    from aat_deploy.cli.diagnose import build_parser
    from aat_deploy.diagnose.inputs import CaptureData
    from aat_deploy.diagnose.session import calibrated_focus

    cap = CaptureData("c", Path("c"), np.zeros((3, 3, 4, 6), np.float32), np.array([0.55, 1.1, 2.2]),
                      np.ones((4, 6), np.float32))
    (out,), info = calibrated_focus([cap], make_cal(FocusError("scale", scale=1.1)))
    np.testing.assert_allclose(out.focus_m, [0.5, 1.0, 2.0], rtol=1e-12)
    assert info["family"] == "scale" and cap.focus_m[1] == 1.1  # the input is not changed
    a = build_parser().parse_args(["root", "--model", "m.onnx", "--out", "o", "--calibration", "cam.json"])
    assert a.calibration == "cam.json"


def test_field_term_held_beyond_radius_max(tmp_path):
    """radius_max holds the field term along the radius beyond the farthest measured point: unchanged inside it,
    beyond it the value at radius_max in the same direction; stored, read back, and absent in older files."""
    from aat_deploy.calibrate.format import field_radius_of

    terms = np.array([[12, 0], [0, 12], [1, 0]])  # a steep edge (x^12, y^12) and a tilt
    fp = FieldPoly(terms, np.array([[5.0], [3.0], [0.2]]), (1.0, 2.0))
    held = FieldPoly(terms, fp.coefficients, (1.0, 2.0), radius_max=0.9, aspect=4 / 3)
    x, y = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 31))
    r = field_radius_of(x, y, 4 / 3)
    a, b = fp(x, y, [1.5])[0], held(x, y, [1.5])[0]
    inside = r <= 0.9
    np.testing.assert_array_equal(a[inside], b[inside])
    assert np.abs(a[~inside] - b[~inside]).max() > 0.5  # the extrapolation it replaces was steep
    s = 0.9 / r[~inside]
    np.testing.assert_allclose(b[~inside], fp(x[~inside] * s, y[~inside] * s, [1.5])[0], atol=1e-12)
    # a corner point reads its direction's value at radius 0.9, whatever how far out it lies
    u = np.array([0.8, 1.0]) / np.hypot(4 / 3 * 0.8, 1.0) * np.sqrt(1 + (4 / 3) ** 2)  # radius 1 along (0.8, 1)
    assert held(u[0], u[1], [1.5])[0] == pytest.approx(held(u[0] * 0.95, u[1] * 0.95, [1.5])[0], abs=1e-12)
    # stored and read back; a file without it is extrapolated, as before
    cal = make_cal()
    cal = CameraCalibration(cal.camera, cal.size_px, cal.focus_error, held, cal.blur, cal.sensor_mm)
    back = load_calibration(save_calibration(cal, tmp_path / "held.json"))
    assert back.best_focus.radius_max == 0.9 and back.best_focus.aspect == pytest.approx(4 / 3)
    np.testing.assert_allclose(back.best_focus(x, y, [1.5]), held(x, y, [1.5]), atol=1e-6)  # stored to 1e-9
    assert "radius_max" not in FieldPoly(terms, fp.coefficients, (1.0, 2.0)).to_dict()
    assert FieldPoly.from_dict(fp.to_dict()).radius_max is None
    d = json.loads((tmp_path / "held.json").read_text())
    for bad in ("x", -0.5, True):
        d["best_focus"]["radius_max"] = bad
        (tmp_path / "bad.json").write_text(json.dumps(d))
        with pytest.raises(CalibrationError, match="radius_max"):
            load_calibration(tmp_path / "bad.json")


def test_field_term_continued_to_first_order_beyond_radius_max(tmp_path):
    """beyond="linear": unchanged inside radius_max; beyond it the value at radius_max on the ray plus the radial
    slope there times the extra radius (a radial rho^4 by hand: c r_max^4 (1 + 4 (r / r_max - 1))), so between the
    hold and the polynomial; a tilt (degree 1) continues exactly; stored as "beyond" (absent when held), read back,
    and anything else refused in one line."""
    from aat_deploy.calibrate import fit as FIT
    from aat_deploy.calibrate.format import field_radius_of

    a = 4 / 3
    k = a ** 2 + 1.0  # rho^2 = (a^2 x^2 + y^2) / k: rho^4 as monomials x^4, x^2 y^2, y^4, and a tilt x
    terms = np.array([[4, 0], [2, 2], [0, 4], [1, 0]])
    coef = np.array([[3.0 * a ** 4 / k ** 2], [3.0 * 2 * a ** 2 / k ** 2], [3.0 / k ** 2], [0.25]])
    poly = FieldPoly(terms, coef, (1.0, 2.0))
    held = FieldPoly(terms, coef, (1.0, 2.0), radius_max=0.8, aspect=a)
    lin = FieldPoly(terms, coef, (1.0, 2.0), radius_max=0.8, aspect=a, beyond="linear")
    x, y = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 31))
    r = field_radius_of(x, y, a)
    out = r > 0.8
    p, h, li = poly(x, y, [1.5])[0], held(x, y, [1.5])[0], lin(x, y, [1.5])[0]
    np.testing.assert_allclose(p[~out], li[~out], atol=1e-12)
    np.testing.assert_allclose(p[:, :], 3.0 * r ** 4 + 0.25 * x, atol=1e-12)  # the monomials are rho^4 and a tilt
    want = 3.0 * 0.8 ** 4 * (1 + 4 * (r[out] / 0.8 - 1)) + 0.25 * x[out]  # rho^4 to first order, the tilt exactly
    np.testing.assert_allclose(li[out], want, atol=1e-12)
    assert np.all(h[out] - 0.25 * (x[out] * 0.8 / r[out]) < li[out] - 0.25 * x[out])  # above the hold ...
    assert np.all(li[out] < p[out])  # ... below the polynomial (rho^4 is convex)
    # stored and read back; a held field term writes no "beyond"
    cal = make_cal()
    cal = CameraCalibration(cal.camera, cal.size_px, cal.focus_error, lin, cal.blur, cal.sensor_mm)
    back = load_calibration(save_calibration(cal, tmp_path / "lin.json"))
    assert back.best_focus.beyond == "linear"
    np.testing.assert_allclose(back.best_focus(x, y, [1.5]), lin(x, y, [1.5]), atol=1e-6)
    assert "beyond" not in held.to_dict() and FieldPoly.from_dict(held.to_dict()).beyond == "held"
    d = json.loads((tmp_path / "lin.json").read_text())
    for bad in ("cubic", 1, None):
        d["best_focus"]["beyond"] = bad
        (tmp_path / "bad.json").write_text(json.dumps(d))
        with pytest.raises(CalibrationError, match="beyond") as e:
            load_calibration(tmp_path / "bad.json")
        assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="beyond"):
        FieldPoly(terms, coef, (1.0, 2.0), radius_max=0.8, aspect=a, beyond="quadratic")
    del d["best_focus"]["radius_max"]  # a continuation with no radius to continue from
    d["best_focus"]["beyond"] = "linear"
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(CalibrationError, match="beyond 'linear' continues from radius_max, which is missing"):
        load_calibration(tmp_path / "bad.json")
    # the fit marks its field term as fit.BEYOND_TILES says
    from aat_deploy.calibrate.model import Observations

    obs = Observations(np.array([0.5, -0.7]), np.array([0.2, 0.6]), np.ones(2), np.ones(2), np.zeros(2, int),
                       np.zeros(2, int), np.ones(2), aspect=a)
    assert FIT.held_beyond_tiles(poly, obs).beyond == FIT.BEYOND_TILES


def test_field_term_held_at_the_nearest_point_of_the_tile_centres_rectangle(tmp_path):
    """beyond="rectangle": inside the rectangle (x_lo, x_hi, y_lo, y_hi) the polynomial unchanged; outside it the
    value at the rectangle's nearest point (x and y clipped), by hand for F = 2 x^2 + 3 x y - y^3 on
    (-0.8, 0.9, -0.7, 0.6), whatever radius_max says; stored as "rectangle", read back, refused in one line when
    malformed or without beyond "rectangle"."""
    from aat_deploy.calibrate import fit as FIT

    terms = np.array([[2, 0], [1, 1], [0, 3]])
    coef = np.array([[2.0], [3.0], [-1.0]])
    rect = (-0.8, 0.9, -0.7, 0.6)
    poly = FieldPoly(terms, coef, (1.0, 2.0))
    box = FieldPoly(terms, coef, (1.0, 2.0), radius_max=0.5, aspect=4 / 3, beyond="rectangle", rectangle=rect)
    x = np.array([0.3, -0.79, 1.0, 1.0, -1.0, 0.5, 0.95])
    y = np.array([-0.2, 0.59, 0.0, 1.0, -1.0, 0.95, -0.3])
    want = [2 * 0.09 - 3 * 0.06 + 0.008,  # inside (beyond radius_max 0.5: not held there)
            2 * 0.79 ** 2 - 3 * 0.79 * 0.59 - 0.59 ** 3,  # inside, near the corner
            2 * 0.81,  # (0.9, 0): beyond x_hi only
            2 * 0.81 + 3 * 0.54 - 0.216,  # (0.9, 0.6): the corner
            2 * 0.64 + 3 * 0.56 + 0.343,  # (-0.8, -0.7): the opposite corner
            0.5 + 0.9 - 0.216,  # (0.5, 0.6): beyond y_hi only
            2 * 0.81 - 3 * 0.27 + 0.027]  # (0.9, -0.3)
    np.testing.assert_allclose(box(x, y, [1.5])[0], want, atol=1e-12)
    np.testing.assert_allclose(box(x[:2], y[:2], [1.5])[0], poly(x[:2], y[:2], [1.5])[0], atol=1e-15)
    # the focus dependence is untouched: a term linear in focus scales the clipped basis alike
    two = FieldPoly(terms, np.hstack([coef, coef]), (1.0, 2.0), 0.5, 4 / 3, "rectangle", rect)
    np.testing.assert_allclose(two(x, y, [2.0])[0], 2 * np.array(want), atol=1e-12)
    # stored and read back
    cal = make_cal()
    cal = CameraCalibration(cal.camera, cal.size_px, cal.focus_error, box, cal.blur, cal.sensor_mm)
    back = load_calibration(save_calibration(cal, tmp_path / "box.json"))
    assert back.best_focus.beyond == "rectangle" and back.best_focus.rectangle == rect
    gx, gy = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 31))
    np.testing.assert_allclose(back.best_focus(gx, gy, [1.5]), box(gx, gy, [1.5]), atol=1e-6)
    d = json.loads((tmp_path / "box.json").read_text())
    assert d["best_focus"]["rectangle"] == list(rect)
    for bad in ("x", [0.1, 0.2, 0.3], [0.5, 0.1, -0.5, 0.5], [0.1, 0.2, -0.5, 1.5], [True, 0.2, -0.5, 0.5], None):
        e = json.loads(json.dumps(d))
        e["best_focus"]["rectangle"] = bad
        (tmp_path / "bad.json").write_text(json.dumps(e))
        with pytest.raises(CalibrationError, match="rectangle") as err:
            load_calibration(tmp_path / "bad.json")
        assert "\n" not in str(err.value)
    e = json.loads(json.dumps(d))
    del e["best_focus"]["beyond"]  # a rectangle without its mode
    (tmp_path / "bad.json").write_text(json.dumps(e))
    with pytest.raises(CalibrationError, match="rectangle"):
        load_calibration(tmp_path / "bad.json")
    # the fit holds at its kept tiles' bounding box when fit.BEYOND_TILES says "rectangle"
    from aat_deploy.calibrate.model import Observations

    obs = Observations(np.array([0.5, -0.7, 0.1]), np.array([0.2, 0.6, -0.4]), np.ones(3), np.ones(3),
                       np.zeros(3, int), np.zeros(3, int), np.ones(3), aspect=4 / 3)
    assert FIT.tile_rectangle(obs) == (-0.7, 0.5, -0.4, 0.6)
    before = FIT.BEYOND_TILES
    try:
        FIT.BEYOND_TILES = "rectangle"
        held = FIT.held_beyond_tiles(poly, obs)
    finally:
        FIT.BEYOND_TILES = before
    assert held.beyond == "rectangle" and held.rectangle == (-0.7, 0.5, -0.4, 0.6)
    assert FIT.held_beyond_tiles(held, obs).rectangle is None  # as is: held, no rectangle
