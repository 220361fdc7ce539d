"""benchmarks/probes/middle_field: the render-truth map read with a cubic in radius reproduces a field that is cubic in
radius where the map's linear reading does not; the leave-one-out check of the radial reading finds a curved field's
bias with the linear reading and none with the cubic; the mean of two maps is their mean. `renders()` pools
each render's tiles over the charts and measures them against every ruler read both ways, and `part_a_rulers()`
scores one fit against the truth read both ways, both checked by hand on a stand-in rig (no render, no fit)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks import render_truth_map as rtm
from benchmarks.probes import middle_field as mf
from benchmarks.probes import render_truth as rt

PHONE_BASE = "lenses/best_focus/cellphone_asphere.json"
EDGES = tuple(float(v) for v in np.round(np.arange(0.0, 0.951, 0.05), 3))


def _field(r):  # a field offset (D) cubic in radius, curved like the phone's middle field
    return -3.0 * r ** 3 + 1.5 * r ** 2 - 0.2 * r


def _map(offset=_field) -> rtm.RenderTruthMap:
    setup = rt.Setup(r_edges=EDGES)
    mids = 0.5 * (np.array(EDGES[:-1]) + np.array(EDGES[1:]))
    rows = [{"object_d": od, "r": float(r), "ok": True, "peak_frame_d": od - offset(r), "se_object_d": 0.01,
             "se_peak_frame_d": 0.01, "n_draws": 10} for r in mids for od in (5.0, 8.0, 11.0, 14.0)]
    probe = {"setup": dataclasses.asdict(setup), "setup_key": setup.key(), "objects_d": [5.0, 8.0, 11.0, 14.0],
             "rows": rows}
    return rtm.RenderTruthMap(rtm.build(probe, "probe.json", PHONE_BASE, "test"))


def test_the_cubic_reading_reproduces_a_field_cubic_in_radius_and_the_linear_does_not():
    m = _map()
    r = np.linspace(0.1, 0.85, 61)
    f = np.full(r.size, 9.0)
    want = f + _field(r)  # the object in focus: the frame plus the field's offset (the points lie on a line in F)
    lin = m.object_d(r, f)
    cub = mf.CubicRadial(m).object_d(r, f)
    assert np.abs(cub - want).max() < 1e-6  # the map stores its points to 1e-6 D
    val, measured = mf.CubicRadial(m).evaluate(r, f)  # what bench_calibrate's part a reads (Rig.truth_measured)
    assert np.array_equal(val, cub) and np.array_equal(measured, m.evaluate(r, f)[1])
    between = np.abs(((r - 0.025) / 0.05) % 1 - 0.5) < 0.4  # away from the annuli's mids
    assert np.abs(lin - want)[between].max() > 1e-3  # the linear reading misses a curved field between mids
    # the mean of two maps
    m2 = _map(lambda x: _field(x) + 0.1)
    assert mf.Mean([m, m2]).object_d(r, f) == pytest.approx(0.5 * (m.object_d(r, f) + m2.object_d(r, f)))


def test_the_radial_check_finds_the_linear_readings_bias_and_not_the_cubics():
    c = mf.radial_check(_map())
    lin, cub = c["linear from the two neighbours"], c["cubic from the four nearest others"]
    # f'' = -18 r + 3 < 0 beyond r = 1/6: a chord lies below the field there, by -f'' h^2 / 2 = 0.0225 D at r 0.4
    assert lin["0.33-0.5"]["mean_d"] == pytest.approx(0.5 * (-18 * 0.4 + 3) * 0.05 ** 2, abs=2e-3)
    assert abs(cub["0.33-0.5"]["mean_d"]) < 1e-6 and cub["all"]["rms_d"] < 1e-6


def test_lagrange4_is_exact_for_cubics_and_linear_with_fewer_points():
    xs = np.array([0.0, 0.1, 0.25, 0.4, 0.6])
    x = np.linspace(0.0, 0.6, 25)
    assert mf._lagrange4(xs, xs ** 3 - xs, x) == pytest.approx(x ** 3 - x, abs=1e-12)
    assert mf._lagrange4(xs[:3], xs[:3] ** 2, x[:5]) == pytest.approx(np.interp(x[:5], xs[:3], xs[:3] ** 2))


def test_annuli_against_reads_another_truths_points_at_the_same_annulus():
    m = _map()
    got = mf.annuli_against(_map(lambda x: _field(x) + 0.1), m)  # in focus 0.1 D farther at every frame
    inner = {r: v for r, v in got.items() if float(r) < 0.8}  # beyond, m's points end first: its base map reads
    assert len(inner) == 16 and all(v["mean_d"] == pytest.approx(0.1, abs=1e-5) for v in inner.values())
    assert all(abs(v["mean_d"]) < 1e-5 for v in mf.annuli_against(m, m).values())


# -- renders() and part_a_rulers(), on a stand-in rig (no render, no fit) -------------------------------------------
# The field of _field, on a map whose planes cover every frame the tests read (objects 2-20 D).
WIDE = (2.0, 5.0, 8.0, 11.0, 14.0, 17.0, 20.0)
MIDS = 0.5 * (np.array(EDGES[:-1]) + np.array(EDGES[1:]))


def _wide_map(offset=_field) -> dict:
    setup = rt.Setup(r_edges=EDGES)
    rows = [{"object_d": od, "r": float(r), "ok": True, "peak_frame_d": od - offset(r), "se_object_d": 0.01,
             "se_peak_frame_d": 0.01, "n_draws": 10} for r in MIDS for od in WIDE]
    probe = {"setup": dataclasses.asdict(setup), "setup_key": setup.key(), "objects_d": list(WIDE), "rows": rows}
    return rtm.build(probe, "probe.json", PHONE_BASE, "test")


def _rig(tmap, h=48, w=64):
    """bench_calibrate.Rig's truth readers (`truth`, `truth_at`, `truth_measured`) on the phone's best-focus map
    and a render-truth map, with no lens, surrogate or effects (focus the same over the field)."""
    from aat_deploy.focus.bestfocus import load_json
    from benchmarks import ROOT
    from benchmarks import bench_calibrate as B

    class Rig(B.Rig):
        def __init__(self):
            self.setup, self.truth_map = B.LENSES["cellphone_near"], tmap
            self.fmap = load_json(ROOT / PHONE_BASE)
            self.h, self.w, self.measure, self.prefilter_px = h, w, "mlap2", 1.0

        def ctx(self):
            return None

    return Rig()


@pytest.fixture
def stand_in(monkeypatch):
    """middle_field's rig, variant effects and development fit replaced: (patch dict, the rig)."""
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT

    rig = _rig(rtm.RenderTruthMap(_wide_map()))
    monkeypatch.setattr(B, "Rig", lambda *a, **k: None)
    monkeypatch.setattr(CT, "rig_for", lambda base, texture, variant: (rig, variant))
    monkeypatch.setattr(B, "effects_for", lambda setup, variant: [])
    return rig


def test_renders_reads_each_renders_tiles_against_every_ruler_linearly_and_by_the_cubic(stand_in, monkeypatch,
                                                                                        tmp_path):
    """Tiles whose rendered object is the field's exact in-focus object plus a known offset per render: against the
    truth read by the cubic they measure exactly that offset, read linearly the offset plus the chord's miss (by
    hand: np.interp through the annuli's mids), against an alt map 0.1 D farther the offset minus 0.1; the two
    charts' tiles are pooled per render and bin, and a chart the setup does not have is one error line."""
    from aat_deploy.calibrate import sweep as SW
    from aat_deploy.calibrate.format import field_radius_of
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import tile_bias as TB

    alt = tmp_path / "farther.json"
    alt.write_text(__import__("json").dumps(_wide_map(lambda x: _field(x) + 0.1)))
    offsets = {"noisy": 0.0, "clean": 0.02}  # rendered object minus the field's exact one, per render
    aspect = 64 / 48
    r_tiles = np.array([0.35, 0.42, 0.48, 0.55, 0.7, 0.8])  # 0.33-0.5 x3, 0.5-0.66, 0.66-0.75, 0.75-0.84

    def tiles(m, inv, truth, asp):
        d, how = m  # what measure_sweep returned: (chart m, render)
        assert asp == pytest.approx(aspect) and truth.scale == 1.0
        x = r_tiles / 0.8 if d == 0.07 else r_tiles  # along x (r = 0.8 x) or the diagonal (r = x = y)
        y = np.zeros_like(x) if d == 0.07 else r_tiles
        rep = np.array([8.0, 9.0, 10.0, 11.0, 12.0, 9.5])  # frame focus (D)
        r = field_radius_of(x, y, aspect)
        return {"x": x, "y": y, "r": r, "reported_d": rep, "object_true_d": rep + _field(r) + offsets[how]}

    monkeypatch.setattr(TB, "RENDERS", {"clean": {"tag": "clean"}})
    monkeypatch.setattr(B, "sweep", lambda rig, v, i, log: {"tag": (rig.setup.distances_m[i], "noisy"), "layout": 0})
    monkeypatch.setattr(TB, "rendered_scene", lambda rig, i: (None, np.ones((48, 64), np.float32), None))
    monkeypatch.setattr(TB, "render_sweep", lambda rig, i, how, log: {
        "tag": (rig.setup.distances_m[i], how["tag"]), "layout": 0, "inv_depth": np.ones((48, 64))})
    monkeypatch.setattr(B, "as_sweep", lambda rig, sw, v: sw)
    monkeypatch.setattr(SW, "measure_sweep", lambda sw, layout, **k: sw["tag"])
    monkeypatch.setattr(TB, "tiles", tiles)

    out = mf.renders([0.07, 0.1], "unused.json", {"farther": str(alt)}, lambda m: None)
    assert out["charts_m"] == [0.07, 0.1] and set(out["measurement"]) == {"noisy (as swept)", "clean"}
    chord = np.interp(r_tiles, MIDS, _field(MIDS)) - _field(r_tiles)  # the linear reading minus the field
    for name, off in (("noisy (as swept)", 0.0), ("clean", 0.02)):
        got = out["measurement"][name]
        assert set(got) == {"--truth", "--truth, read cubic in radius", "farther", "farther, read cubic in radius"}
        cub, lin = got["--truth, read cubic in radius"], got["--truth"]
        assert cub["all"]["n"] == 12 and cub["0.33-0.5"]["n"] == 6  # both charts' tiles, pooled
        for b in ("0.33-0.5", "0.5-0.66", "0.66-0.75", "0.75-0.84", "all"):
            assert cub[b]["mean_d"] == pytest.approx(off, abs=1e-5)
            assert got["farther, read cubic in radius"][b]["mean_d"] == pytest.approx(off - 0.1, abs=1e-5)
        assert lin["0.33-0.5"]["mean_d"] == pytest.approx(off - chord[:3].mean(), abs=1e-5)
        assert lin["0.75-0.84"]["mean_d"] == pytest.approx(off - chord[5], abs=1e-5)
        assert abs(chord[:3].mean()) > 3e-4  # the chord's miss there (7e-4 D) is 30 x the tolerance
    with pytest.raises(SystemExit, match=r"--renders 0.2: not a chart of cellphone_near"):
        mf.renders([0.2], "unused.json", {}, lambda m: None)


def test_part_a_rulers_scores_the_same_fit_against_the_truth_read_linearly_and_by_the_cubic(stand_in, monkeypatch):
    """A calibration with no field term (the thin lens) against a field cubic in radius: part a's error at each
    pixel is minus the field as the ruler reads it, so read by the cubic its RMS per radius bin is the field's own
    RMS there and read linearly the chord's (both by hand over the same pixels); the benchmark's rig is not
    changed."""
    from aat_deploy.calibrate.format import CameraCalibration, CameraIdentity, FieldPoly, FocusError
    from aat_deploy.eval.stats import field_radius
    from benchmarks.probes import phone_map_budget as P

    rig = stand_in
    cal = CameraCalibration(CameraIdentity(), (64, 48), FocusError(),
                            FieldPoly(np.array([[1, 0]]), np.zeros((1, 1)), (5.0, 15.0), 0.95, 64 / 48))
    seen = []
    monkeypatch.setattr(P, "development_fit", lambda r, v, log: (seen.append((r, v)) or [], 1.0, [], [],
                                                                  type("Fit", (), {"calibration": cal})()))
    before = rig.truth_map
    out = mf.part_a_rulers("copy", "unused.json", lambda m: None)
    assert seen == [(rig, "copy")] and rig.truth_map is before
    assert set(out) == {"linear, the benchmark's", "cubic in radius"}
    lin, cub = out["linear, the benchmark's"], out["cubic in radius"]
    assert set(lin) == {"rms_d", "p95_d", "within_tiles_rms_d", "radius_rms_d"}
    r = rig.fmap.radius_px(48, 64).astype(np.float64)  # the radius the truth is read at
    bins = field_radius(48, 64)  # the radius map_errors bins by
    for b, lo, hi in (("0.33-0.5", 0.33, 0.5), ("0.5-0.66", 0.5, 0.66), ("0.75-0.84", 0.75, 0.84)):
        m = (bins >= lo) & (bins < hi)
        assert cub["radius_rms_d"][b] == pytest.approx(np.sqrt(np.mean(_field(r[m]) ** 2)), abs=1e-5)
        assert lin["radius_rms_d"][b] == pytest.approx(
            np.sqrt(np.mean(np.interp(r[m], MIDS, _field(MIDS)) ** 2)), abs=1e-5)
    assert abs(lin["radius_rms_d"]["0.33-0.5"] - cub["radius_rms_d"]["0.33-0.5"]) > 3e-4  # 30 x the tolerance
