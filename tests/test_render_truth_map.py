"""benchmarks/render_truth_map: the map built from render_truth's points recovers an ideal thin lens's truth (in
focus where the frame is focused, at every radius); it reproduces the points it was made from and extrapolates by the
base map with the correction held; bench_calibrate --truth uses it as part a's truth only (the prescription's map
stays the best-focus map) and refuses a malformed one in one line before any render."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from benchmarks import ROOT
from benchmarks import render_truth_map as rtm
from benchmarks.probes import render_truth as rt

THIN = rt.Setup(lens="lenses/canon_rf50mm_f1.8.json", psf=None, fmap=None, texture="leaves", sensor_px=(96, 64),
                step_d=0.1, before_d=0.95, n_frames=20, r_edges=(0.0, 0.3, 0.6, 0.9))
BASE = "lenses/best_focus/canon_rf50mm_f1.8.json"
PHONE_BASE = "lenses/best_focus/cellphone_asphere.json"


def _probe(setup, rows) -> dict:
    return {"setup": dataclasses.asdict(setup), "setup_key": setup.key(), "objects_d": sorted({q["object_d"] for q in
                                                                                               rows}), "rows": rows}


def test_the_map_recovers_a_thin_lens_truth_at_every_radius(tmp_path, monkeypatch):
    monkeypatch.setattr(rt, "CACHE", tmp_path / "rt")
    rows = []
    for od in (1.0, 1.37, 1.8):  # planes between frames 0.1 D apart
        got = [rt.draw(THIN, od, s) for s in (1, 2)]
        rows += rt.plane_stats(THIN, od, np.stack([d["curves"] for d in got]), got[0]["frames_d"], None, 20,
                               np.random.default_rng(0))
    m = rtm.RenderTruthMap(rtm.build(_probe(THIN, rows), "probe.json", BASE, "test"))
    f = np.linspace(1.05, 1.75, 15)  # frames between the planes' peaks
    for r in (0.0, 0.15, 0.3, 0.45, 0.75):
        got, meas = m.evaluate(np.full(f.size, r), f)
        assert meas.all()
        # the thin lens: the frame's own focus is in focus everywhere
        assert np.abs(got - f).max() < 0.02, (r, got - f)


def test_the_map_passes_through_its_points_and_extrapolates_by_the_base_map():
    setup = rt.Setup(r_edges=(0.0, 0.5, 0.9))  # mids 0.25, 0.7
    rows = [{"object_d": od, "r": r, "ok": True, "peak_frame_d": od + dr, "se_object_d": 0.01,
             "se_peak_frame_d": 0.01, "n_draws": 10}
            for r, dr in ((0.25, 0.1), (0.7, -1.0)) for od in (5.0, 8.0, 11.0)]
    d = rtm.build(_probe(setup, rows), "probe.json", PHONE_BASE, "test")
    m = rtm.RenderTruthMap(d)
    got, meas = m.evaluate([0.25, 0.25, 0.7, 0.475], [5.1, 9.6, 7.0, 6.55])
    assert got[:3] == pytest.approx([5.0, 9.5, 8.0]) and meas.all()
    assert got[3] == pytest.approx(0.5 * (6.45 + 7.55))  # linear in r between the annuli
    base = m._base
    # beyond the points' frames: the base map plus the correction at the nearest point
    g, ok = m.evaluate([0.25], [14.0])
    corr = 11.0 - base(np.array([0.25]), np.array([11.1]))[0]
    assert g[0] == pytest.approx(base(np.array([0.25]), np.array([14.0]))[0] + corr) and not ok[0]
    # beyond the last annulus: the base map plus the last annulus's correction at that frame
    g, ok = m.evaluate([0.95], [7.0])
    corr = 8.0 - base(np.array([0.7]), np.array([7.0]))[0]
    assert g[0] == pytest.approx(base(np.array([0.95]), np.array([7.0]))[0] + corr) and not ok[0]


def _good_map(tmp_path) -> dict:
    setup = rt.Setup(r_edges=(0.0, 0.5, 0.9))
    rows = [{"object_d": od, "r": r, "ok": True, "peak_frame_d": od, "se_object_d": 0.01, "se_peak_frame_d": 0.01,
             "n_draws": 10} for r in (0.25, 0.7) for od in (5.0, 8.0)]
    return rtm.build(_probe(setup, rows), "probe.json", PHONE_BASE, "test")


@pytest.mark.parametrize("spoil", ["not json", "format", "descending", "short", "missing", "base"])
def test_the_benchmark_refuses_a_malformed_truth_map_in_one_line_before_any_render(tmp_path, spoil, capsys):
    from benchmarks import bench_calibrate as B

    d = _good_map(tmp_path)
    path = tmp_path / "truth.json"
    if spoil == "not json":
        path.write_text("{")
    elif spoil != "missing":
        if spoil == "format":
            d["format"] = "aat-best-focus-map-v1"
        elif spoil == "descending":
            d["annuli"][1]["frame_d"] = d["annuli"][1]["frame_d"][::-1]
        elif spoil == "short":
            d["annuli"] = d["annuli"][:1]
        elif spoil == "base":
            d["extrapolation"]["base_map"] = "lenses/best_focus/nope.json"
        path.write_text(json.dumps(d))
    out = tmp_path / "res.json"
    with pytest.raises(SystemExit) as e:
        B.main(["--lenses", "cellphone_near", "--parts", "map", "--truth", str(path), "--out", str(out)])
    msg = str(e.value.code)
    assert msg.startswith("bench_calibrate: --truth ") and "\n" not in msg and str(path) in msg, msg
    assert not out.exists()


def test_the_benchmark_refuses_another_lenss_truth_in_one_line_before_any_render(tmp_path):
    """A render truth is one lens's (its "lens"): --lenses naming another lens is refused in one line, nothing
    written."""
    from benchmarks import bench_calibrate as B

    path = tmp_path / "truth.json"
    path.write_text(json.dumps(_good_map(tmp_path)))  # the phone lens's (render_truth's default setup)
    out = tmp_path / "res.json"
    with pytest.raises(SystemExit) as e:
        B.main(["--lenses", "cellphone_near,rf50", "--parts", "map", "--truth", str(path), "--out", str(out)])
    msg = str(e.value.code)
    assert msg.startswith("bench_calibrate: --truth ") and "\n" not in msg, msg
    assert "lenses/cellphone_asphere.json" in msg and "rf50 (lenses/canon_rf50mm_f1.8.json)" in msg
    assert "cellphone_near" not in msg and not out.exists()


def test_truth_goes_with_the_map_parts_only(tmp_path):
    from benchmarks import bench_calibrate as B

    path = tmp_path / "truth.json"
    path.write_text(json.dumps(_good_map(tmp_path)))
    with pytest.raises(SystemExit) as e:
        B.main(["--lenses", "cellphone_near", "--parts", "map,depth", "--truth", str(path),
                "--out", str(tmp_path / "r.json")])
    assert e.value.code == 2


def test_a_truth_made_of_the_base_maps_own_values_leaves_the_truth_and_the_prescription_map(tmp_path):
    from aat_deploy.focus.bestfocus import load_json
    from benchmarks import bench_calibrate as B

    base = load_json(ROOT / PHONE_BASE)
    edges = tuple(float(v) for v in np.round(np.arange(0.0, 0.951, 0.05), 3))
    mids = [0.5 * (a + b) for a, b in zip(edges[:-1], edges[1:])]
    fr = base.focus_diopters[(base.focus_diopters > 2) & (base.focus_diopters < 19)]
    rows = [{"object_d": float(base.frame_diopters([1 / f], [r])[0, 0]), "r": r, "ok": True, "peak_frame_d": float(f),
             "se_object_d": 0.0, "se_peak_frame_d": 0.0, "n_draws": 1} for r in mids for f in fr]
    path = tmp_path / "truth.json"
    path.write_text(json.dumps(rtm.build(_probe(rt.Setup(), rows), "probe.json", PHONE_BASE, "test")))
    setup = B.LENSES["cellphone_near"]
    plain, mine = B.Rig(setup), B.Rig(setup, truth=str(path))
    assert mine.fmap.to_dict() == plain.fmap.to_dict()  # the prescription's map is the best-focus map still
    eff = B.effects_for(setup, "copy")
    f = setup.inside()[[0, 5, 9]]
    a, b = plain.truth(eff, f), mine.truth(eff, f)
    within = plain.fmap.radius_px(plain.h, plain.w) <= 0.9
    d = (b - a)[:, within]
    # the base map's surface, piecewise linear in r^2 between its 13 radii, sampled at the 19 annuli and read linearly
    # in r between them: close, not equal (0.021 D RMS, chords across the base map's kinks)
    assert np.sqrt(np.mean(d ** 2)) < 0.03 and np.abs(d).max() < 0.15
    ok = mine.truth_measured(eff, f)
    assert ok[:, within].mean() > 0.95 and not ok[:, ~(plain.fmap.radius_px(plain.h, plain.w) <= 0.925)].any()


def test_the_builder_refuses_a_bad_probe_file_in_one_line_with_nothing_written(tmp_path, capsys):
    """render_truth_map's own input (a render_truth result): missing, not JSON, not that probe's, or naming no base
    map in the repository is one error line; an existing --out is kept without --force."""
    good = _probe(rt.Setup(r_edges=(0.0, 0.5, 0.9)), [])
    cases = {"missing": None, "not json": "{", "not the probe's": json.dumps({"rows": []}),
             "no base": json.dumps(dict(good, setup=dict(good["setup"], fmap="lenses/best_focus/nope.json")))}
    says = {"missing": "cannot read", "not json": "not JSON", "not the probe's": "not a benchmarks.probes.render_truth",
            "no base": "no base map 'lenses/best_focus/nope.json'"}
    out = tmp_path / "map.json"
    for name, text in cases.items():
        probe = tmp_path / f"{name.replace(' ', '_')}.json"
        if text is not None:
            probe.write_text(text)
        with pytest.raises(SystemExit):
            rtm.main([str(probe), "--out", str(out)])
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert says[name] in err and str(probe) in err, (name, err)
        assert not out.exists()
    out.write_text("mine")
    probe.write_text(json.dumps(good))
    with pytest.raises(SystemExit):
        rtm.main([str(probe), "--out", str(out)])
    assert "give --force" in capsys.readouterr().err and out.read_text() == "mine"


def test_render_truth_score_refuses_before_any_sweep(tmp_path, capsys, monkeypatch):
    """probes/render_truth_score: an existing --out, a variant not declared, or a malformed --truth is one error line
    before any sweep is rendered (`run` is never called), nothing written."""
    from benchmarks.probes import render_truth_score as rts

    monkeypatch.setattr(rts, "run", lambda *a, **k: pytest.fail("a sweep was started"))
    good = tmp_path / "truth.json"
    good.write_text(json.dumps(_good_map(tmp_path)))
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    out = tmp_path / "score.json"
    taken = tmp_path / "taken.json"
    taken.write_text("mine")
    for args, says in [(["--truth", str(good), "--out", str(taken)], "taken.json: exists"),
                       (["--truth", str(good), "--variants", "nominal,copy_s2026_7", "--out", str(out)],
                        "--variants: copy_s2026_7 not of nominal, copy,"),
                       (["--truth", str(bad), "--out", str(out)], "render_truth_score: --truth ")]:
        with pytest.raises(SystemExit) as e:
            rts.main(args)
        err = capsys.readouterr().err.strip().splitlines()
        msg = err[-1] if err else str(e.value.code)
        assert says in msg and "\n" not in msg, (args, msg)
        assert not out.exists() and taken.read_text() == "mine"
