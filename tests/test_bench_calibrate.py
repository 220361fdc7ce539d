"""bench_calibrate: the truth's own reported-focus family (what the fit's interval is compared with) and the guard
that the chart fit's focus measure is the one its truth map was calibrated with."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import bench_calibrate as bc


class _Rig:
    """A stand-in with a truth whose centre is a known function of the true focus."""

    h, w = 3, 5

    def __init__(self, centre):
        self.centre = centre

    def truth(self, effects, true_m):
        t = self.centre(1.0 / np.asarray(true_m, np.float64))
        return np.broadcast_to(t[:, None, None], (len(t), self.h, self.w)).copy()


def test_truth_family_by_hand():
    true_m = 1.0 / np.linspace(5.5, 14.0, 10)  # the phone's charts
    scaled = ["focus_metadata:bias_d=0:scale=1.1", "noise"]
    # the copy's reported distance is 1.1 x the true one, the truth the thin lens: exactly the scale 1.1
    tf = bc.truth_family(_Rig(lambda d: d), scaled, true_m)
    assert tf["scale"] == pytest.approx(1.1, abs=1e-12) and max(map(abs, tf["centre_minus_thin_lens_d"])) < 1e-12
    # the measure's own offset (its in-focus object 0.2 D farther on axis): a pure scale reads less than 1.1,
    # by the least-squares formula over the frames
    tf = bc.truth_family(_Rig(lambda d: d - 0.2), scaled, true_m)
    rep = 1.0 / (1.1 * true_m)
    assert tf["scale"] == pytest.approx(np.sum((1.1 * rep - 0.2) * rep) / np.sum(rep ** 2), rel=1e-12)
    assert tf["scale"] < 1.085
    # no reported-focus error: the measure's offset is the truth's offset
    tf = bc.truth_family(_Rig(lambda d: d - 0.2), ["noise"], true_m)
    assert tf["bias_d"] == pytest.approx(0.2, abs=1e-12) and tf["scale"] < 1.0


def test_a_fit_measure_without_its_truth_map_is_refused():
    with pytest.raises(SystemExit, match="calibrated for measure mlap2.*narrowband"):
        bc.Rig(bc.LENSES["cellphone"], measure="narrowband", prefilter_px=0.0)


def test_every_copy_finds_its_tolerance_table():
    """The copies' decentres are read from a tolerance table (no torch): the RF50's and the phone's committed next to
    their surrogates in models/ (the phone's as the command in models/README.md writes it), the held-out lenses'
    under cache/ (bench_calibrate's tolerance_table)."""
    from aat_deploy.render import effects as fx

    for key in ("rf50", "cellphone"):
        setup = bc.LENSES[key]
        assert setup.tolerance_table is None
        rig = bc.Rig(setup)
        tol = [e for e in fx.parse(bc.effects_for(setup, "copy")) if type(e).__name__ == "LensTolerance"]
        assert len(tol) == 1 and tol[0].torch_reason(rig.ctx()) == ""
        assert tol[0]._table_path(rig.ctx()).parent == bc.ROOT / "models"


def test_a_missing_tolerance_table_is_one_line_with_its_command(tmp_path):
    """A held-out lens's table lives under cache/ and is named by the lens's optics key: a corrected lens file
    needs a new one, refused before any sweep is rendered, with the command that makes it."""
    import dataclasses

    setup = dataclasses.replace(bc.LENSES["z35"], tolerance_table=str(tmp_path / "auto"))
    with pytest.raises(SystemExit) as e:
        bc.check_tolerance_table(setup)
    msg = str(e.value)
    assert "\n" not in msg and str(tmp_path) in msg and "tolerance_" in msg
    assert f"scripts.lens_tolerance_table {setup.lens} --out " in msg
    bc.tolerance_path(setup).write_text("{}")  # there: passes
    bc.check_tolerance_table(setup)
    bc.check_tolerance_table(bc.LENSES["rf50"])  # next to its surrogate: not this check's


def test_a_refused_row_says_how_far_its_sweeps_reach():
    """How far a sweep reaches beyond its chart, in px of thin-lens blur: the RF50's fixed 0.3 D margin, the Z35's
    clipped to its surrogate's focus range (0.2-5 m), which at 0.84 px/D leaves it under the 3.4 px a tile's curve
    needs to fall to half on either side of every chart (why its rows are refused)."""
    rf = bc.Rig(bc.LENSES["rf50"])
    for d, (far, near) in bc.sweep_reach_px(rf).items():
        assert far == pytest.approx(0.3 * rf.blur_px_per_d, rel=1e-6) and near == pytest.approx(far, rel=1e-6)
        assert far > bc.HALF_FALL_PX[1]
    z = bc.Rig(bc.LENSES["z35"])
    assert 0.80 < z.blur_px_per_d < 0.88  # EFL 1.572 mm, F/1.77, 1.66 um pixels (the misread lens: 1.23)
    flo, fhi = z.src.model.focus_range_m
    reach = bc.sweep_reach_px(z)
    assert list(reach) == ["0.3", "0.6", "1.5"]
    for d, (far, near) in reach.items():
        assert far == pytest.approx(z.blur_px_per_d * (1 / float(d) - 1 / fhi), rel=1e-6)
        assert near == pytest.approx(z.blur_px_per_d * (1 / flo - 1 / float(d)), rel=1e-6)
        assert min(far, near) < bc.HALF_FALL_PX[0]
    row = {"lens": "z35", "variant": "nominal", "refused": "x: too few textured tiles", "psf": {
        "rms_radius_px_centre": [0.2, 1.1], "rms_radius_px_x0.7": [0.3, 1.1], "focus_d": [0.2, 5.0], "object_m": 0.6,
        "defocus_blur_px": [2.8], "field_curvature_d": {"r0.5": 0.5, "r1": 0.2}, "reach_px": reach}}
    text = bc.tables({"map": [row]})
    assert "the sweeps reach 0.3 m 2.6 / 1.4, 0.6 m 1.2 / 2.8, 1.5 m 0.4 / 3.7 px of blur beyond the chart" in text
    del row["psf"]["reach_px"]  # a run before the field existed still prints
    assert "refused: too few textured tiles" in bc.tables({"map": [row]})


def test_a_cached_sweep_of_other_lens_files_is_refused(tmp_path, monkeypatch, capsys):
    """A chart sweep's cache name holds the lens's key only: the sweep records the SHA-256 of its lens and PSF
    files, and one of another file is refused in one line (kept); one cached before the record is read with a
    warning."""
    import json

    rig = bc.Rig(bc.LENSES["z35"])
    monkeypatch.setattr(bc, "CACHE", tmp_path)
    f = tmp_path / "z35_nominal_0.3m_soft0.7px.npz"
    arrays = {"frames": np.zeros((3, 3, 4, 6), np.float16), "reported_m": np.array([3.0, 2.0, 1.0]),
              "true_m": np.array([3.0, 2.0, 1.0])}
    now = bc.sweep_sources(rig.setup)
    assert set(now) == {"lens", "psf"} and all(len(v) == 64 for v in now.values())
    np.savez(f, **arrays, sources=json.dumps({**now, "lens": "0" * 64}))
    with pytest.raises(SystemExit) as e:
        bc.sweep(rig, "nominal", 0, lambda m: None)
    msg = str(e.value)
    assert "\n" not in msg and str(f) in msg and "lens 000000000000 then" in msg and "psf" not in msg
    assert f.is_file()
    np.savez(f, **arrays, sources=json.dumps(now))  # the same files: read
    assert bc.sweep(rig, "nominal", 0, lambda m: None)["frames"].shape == (3, 3, 4, 6)
    np.savez(f, **arrays)  # cached before the record: read, with one warning
    bc.sweep(rig, "nominal", 0, lambda m: None)
    bc.sweep(rig, "nominal", 0, lambda m: None)
    assert capsys.readouterr().err.count("read as unverified") == 1


def test_world_views_are_the_same_rendered_or_cached(tmp_path, monkeypatch):
    """The blind part's views: the run that renders them and the runs that read them from the cache get the same
    frames (the cache's float16), so two runs of part d fit the same data."""
    import aat_deploy.calibrate.scene as scene
    import aat_deploy.capture.virtual as virtual
    import training.data.scenes as scenes

    rig = bc.Rig(bc.LENSES["rf50"])
    rng = np.random.default_rng(0)
    monkeypatch.setattr(bc, "CACHE", tmp_path)
    monkeypatch.setattr(scenes, "procedural_scene", lambda cfg, r: (np.zeros((cfg.height, cfg.width, 3), np.float32),
                                                                    np.ones((cfg.height, cfg.width), np.float32)))
    monkeypatch.setattr(scene, "turned_view", lambda rgb, z, f, yaw, pitch, w, h: (np.zeros((3, h, w)), np.ones((h, w))))
    monkeypatch.setattr(virtual, "shoot", lambda *a, **k: (rng.random((8, 3, 4, 6)).astype(np.float32) / 3,
                                                          np.linspace(0.5, 10, 8)))
    fresh = bc.world_views(rig, 0, lambda m: None)
    cached = bc.world_views(rig, 0, lambda m: None)
    assert len(fresh) == len(cached) == 9
    for (a, ra), (b, rb) in zip(fresh, cached):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(ra, rb)


def test_blind_table_rows():
    """Part d's table: the bootstrap's spread, its limit and whether the fit warned; runs recorded before they were
    kept print '-'; a refused row says why."""
    rows = [{"captures": 0, "none (thin lens)": 0.06, "prescription map": 0.05, "chart calibration": 0.005},
            {"captures": 3, "blind": None, "error": "the captures turn one way only"},
            {"captures": 9, "blind": 0.031, "pairs": 36, "sd_rms_d": 0.0123, "limit_d": 0.0271, "warned": False},
            {"captures": 27, "blind": 0.029, "pairs": 105}]
    lines = bc.tables({"blind": {"rf50": rows}}).splitlines()
    assert "| rf50 | 9 | 36 | 0.0310 | 0.0123 | 0.0271 | no |" in lines
    assert "| rf50 | 27 | 105 | 0.0290 | - | - | - |" in lines
    assert any(ln.startswith("| rf50 | 3 | - | refused: the captures turn one way only") for ln in lines)


def test_depth_table_with_the_blind_mappings():
    """Part b's table with part d's blind fit scored as two more mappings: their rows and their paired ratios to the
    prescription map and to the chart calibration (from the stored per-scene scores); a run without them prints no
    such rows."""
    rng = np.random.default_rng(0)
    names = ("thin lens", "prescription map", "calibration", "oracle", *bc.BLIND_MAPPINGS)
    per = {k: [{"scene": i, "mae": m, "mae_outer": m, "mae_d": m / 4}
               for i, m in enumerate(rng.uniform(0.5, 1, 6) * (j + 1))] for j, k in enumerate(names)}
    d = {"scenes": 6, "per_scene": per}
    for k, v in per.items():
        d[k] = {z: [float(np.mean([x[z] for x in v])), 0.0, 1.0] for z in ("mae", "mae_outer", "mae_d")}
    for z in ("mae", "mae_outer", "mae_d"):
        for a, b in (("calibration", "oracle"), ("calibration", "prescription map"), ("prescription map", "oracle")):
            key = f"{'cal' if a == 'calibration' else 'prescription'}/{'oracle' if b == 'oracle' else 'prescription'}"
            d[f"{key} {z}"] = bc.paired_ratio(per[a], per[b], z)
        for k in bc.BLIND_MAPPINGS:
            d[f"{k}/prescription {z}"] = bc.paired_ratio(per[k], per["prescription map"], z)
            d[f"{k}/calibration {z}"] = bc.paired_ratio(per[k], per["calibration"], z)
    text = bc.tables({"depth": {"rf50": d}})
    assert "| rf50 | 6 | blind calibration |" in text and "| rf50 | 6 | blind + chart focus error |" in text
    row = next(ln for ln in text.splitlines() if ln.startswith("| rf50 | blind calibration |"))
    want = bc.paired_ratio(per["blind calibration"], per["prescription map"], "mae")
    assert row.split(" | ")[2] == bc.fmt(want)
    del d["blind calibration"], d["blind + chart focus error"]
    assert "blind" not in bc.tables({"depth": {"rf50": d}})


def test_map_errors_by_field_radius():
    """The map's error by field radius: the bins partition the frame (their squared errors add up to the whole
    frame's) and a truth that departs from the thin lens by a known radial function reads that function's RMS
    and mean in each bin."""
    from aat_deploy.eval.stats import field_radius

    h, w = 48, 64
    rad = field_radius(h, w)

    class Map:
        def radius_px(self, h_, w_):
            return field_radius(h_, w_)

        def frame_diopters(self, focus_m, r):
            return np.full((len(focus_m), np.size(r)), 1.0 / focus_m[0])  # the prescription map: the thin lens

    class Rig:
        fmap = Map()

        def __init__(self):
            self.h, self.w = h, w

        def truth(self, effects, true_m):  # the thin lens plus 0.5 r^2 D nearer
            return np.stack([np.full((h, w), 1.0 / f) + 0.5 * rad ** 2 for f in true_m])

    true_m = np.array([0.5, 1.0, 2.0])
    out = bc.map_errors(Rig(), None, ["noise"], true_m)["thin lens"]
    n = {b: m.sum() for b, m in ((f"{lo:g}-{hi:g}", (rad >= lo) & ((rad < hi) if hi < 1 else (rad <= hi)))
                                  for lo, hi in zip(bc.RADIUS_EDGES[:-1], bc.RADIUS_EDGES[1:]))}
    assert sum(n.values()) == h * w and set(n) == set(out["radius_rms_d"])
    total = sum(n[b] * out["radius_rms_d"][b] ** 2 for b in n) / (h * w)
    assert total == pytest.approx(out["rms_d"] ** 2, rel=1e-5)
    m = (rad >= 0.5) & (rad < 0.66)
    assert out["radius_rms_d"]["0.5-0.66"] == pytest.approx(np.sqrt(np.mean((0.5 * rad[m] ** 2) ** 2)), rel=1e-5)
    assert out["radius_mean_d"]["0.5-0.66"] == pytest.approx(-np.mean(0.5 * rad[m] ** 2), rel=1e-5)


# -- random copies (--copies K --copy-seed S: benchmarks/calibrate_copies) -------------------------------------------
def _copies(key, k, seed=2026, n_el=5):
    from benchmarks import calibrate_copies as cc

    return [cc.draw_copy(bc.LENSES[key], n_el, seed, i) for i in range(k)]


def test_random_copies_are_reproducible_from_the_seed_and_distinct():
    a, b = _copies("ef50", 6), _copies("ef50", 6)
    assert a == b  # the same seed draws the same copies
    assert _copies("ef50", 3) == a[:3]  # K copies are the first K of a larger run (a run resumes copy by copy)
    assert len({tuple(c["effects"]) for c in a}) == 6  # distinct
    assert _copies("ef50", 6, seed=7) != a  # another seed, other copies
    assert [c["effects"] for c in _copies("rf50", 3)] != [c["effects"] for c in a[:3]]  # each lens its own draws


def test_random_copies_have_the_hand_chosen_copys_magnitudes():
    """Decentre 0.1 mm and tilt hypot(0.5, 0.3) deg on the 50 mm lenses (5 um and hypot(0.3, 0.2) on the phone) in
    random directions; the reported focus 1.1 x the true one and noise, as the hand-chosen copy."""
    from aat_deploy.render import effects as fx

    for key, dec, tilt, n_el in (("ef50", 0.1, np.hypot(0.5, 0.3), 5), ("cellphone", 0.005, np.hypot(0.3, 0.2), 6)):
        cs = _copies(key, 40, n_el=n_el)
        for c in cs:
            assert np.hypot(*c["decentre_mm"]) == pytest.approx(dec, rel=1e-4)
            assert np.hypot(*c["tilt_deg"]) == pytest.approx(tilt, rel=1e-4)
            assert c["effects"][2:] == ["focus_metadata:bias_d=0:scale=1.1", "noise"]
            parsed = fx.parse(c["effects"])  # the effects' own parser reads them back
            lt = next(e for e in parsed if e.name == "lens_tolerance").params
            assert (lt["element"], lt["decentre_x_mm"], lt["decentre_y_mm"]) == (c["element"], *c["decentre_mm"])
        # random directions and elements: every element drawn, directions over the whole circle
        assert {c["element"] for c in cs} == set(range(n_el))
        ang = np.array([np.arctan2(c["tilt_deg"][1], c["tilt_deg"][0]) for c in cs])
        assert np.histogram(ang, bins=4, range=(-np.pi, np.pi))[0].min() >= 3


def test_a_random_copys_sweeps_are_cached_apart_from_the_hand_chosen_copys():
    from benchmarks import calibrate_copies as cc

    c = _copies("ef50", 1)[0]
    s = cc.copy_setup(bc.LENSES["ef50"], 2026, c)
    assert s.copy_name == "copy_s2026_0" and bc.LENSES["ef50"].copy_name == "copy"
    assert bc.effects_for(s, "copy")[1] == c["effects"][1] and bc.effects_for(s, "nominal") == ["noise"]


def test_copies_table_pools_by_hand():
    from benchmarks import calibrate_copies as cc

    def per(v):
        return {m: [{"scene": str(i), "mae": x * f, "mae_outer": x * f, "mae_d": x * f} for i, x in enumerate(v)]
                for m, f in (("thin lens", 1.0), ("prescription map", 1.0), ("calibration", 0.5), ("oracle", 0.5))}

    copies = [{"depth": {"per_scene": per([1.0, 3.0])}}, {"depth": {"per_scene": per([2.0, 2.0])}}]
    p = cc.pooled(copies)
    assert p["calibration / prescription map mae"][0] == pytest.approx(0.5)
    assert p["calibration / oracle mae_outer"][0] == pytest.approx(1.0)


def test_departure_table_quantiles_and_the_hand_chosen_copys_rank():
    from benchmarks import calibrate_copies as cc

    rows = [{"departure_d": {"copy - prescription": {"all": v, "outer": v}}} for v in (0.01, 0.02, 0.03, 0.04)]
    res = {"departures": {"ef50": {"copies": rows, "hand_chosen_d": {"all": 0.025, "outer": 0.03},
                                   "quantiles_d": {"0.5": 0.025, "0.1": 0.013}}}}
    line = cc.departure_table(res).splitlines()[-1]
    assert line == "| ef50 | 4 | 0.0130 / 0.0250 | 0.0250 (50 % of the copies depart less) |"


def test_the_hand_chosen_copy_is_read_from_its_depth_and_departure_and_drawn(tmp_path):
    from benchmarks import calibrate_copies as cc

    ratio = {f"cal/prescription {z}": [0.8, 0.7, 0.9] for z in ("mae", "mae_outer", "mae_d")}
    res = {"depth": {"rf50": ratio}, "departures": {"rf50": {"hand_chosen_d": {"all": 0.05, "outer": 0.07}}}}
    assert cc.hand_chosen(res, "rf50") == {"departure_d": 0.05, **ratio}
    assert cc.hand_chosen(res, "ef50") is None and cc.hand_chosen({"depth": res["depth"]}, "rf50") is None
    copy = {"departure_d": {"copy - prescription": {"all": 0.02, "outer": 0.03}}, "depth": ratio}
    res["copies"] = {"rf50": {"copies": [copy]}}
    cc.figure(res, tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 0


def test_truth_at_field_points_is_the_truth_at_those_pixels():
    """Rig.truth_at (a tile's truth, benchmarks/probes/phone_map_budget) agrees with Rig.truth's per-pixel map on the
    phone's copy (sensor tilt and decentre: a field-varying focus), at pixel centres across the frame."""
    from aat_deploy.calibrate.format import field_grid

    rig = bc.Rig(bc.LENSES["cellphone"])
    eff = bc.effects_for(rig.setup, "copy")
    true_m = np.array([0.07, 0.1, 0.18])
    full = rig.truth(eff, true_m)
    gx, gy = field_grid(rig.h, rig.w)
    rows, cols = np.array([0, 17, 240, 479, 479]), np.array([0, 600, 320, 3, 639])
    at = rig.truth_at(eff, gx[rows, cols], gy[rows, cols], true_m)
    np.testing.assert_allclose(at, full[:, rows, cols], atol=2e-4)
    assert np.ptp(at[1]) > 1.0  # the corners differ from the centre by diopters: the test can tell points apart


def test_the_phone_with_a_near_chart_keeps_the_phones_charts_range_and_sweeps(tmp_path, monkeypatch):
    """cellphone_near adds a chart at 5.5 cm after the phone's three, its distance fitted (`fit_distance`): the
    same first three charts (distances, tilts, the copy), the same part a range (7-18 cm, not down to 5.5 cm), the
    lens's own random copies, and its sweeps twice as dense (0.7 px of blur per step), cached apart from the
    phone's under the phone's names with the step (their seeds and tape errors follow the order, unchanged)."""
    p, n = bc.LENSES["cellphone"], bc.LENSES["cellphone_near"]
    assert n.distances_m[:3] == p.distances_m and n.tilts[:3] == p.tilts and n.copy_effects == p.copy_effects
    assert n.distances_m[3] == 0.055 and len(n.tilts) == 4
    assert n.fit_distance == (3,) and p.fit_distance == () and n.step_px == 0.7 and p.step_px is None
    assert _copies("cellphone_near", 3, n_el=6) == _copies("cellphone", 3, n_el=6)

    class Rig:  # sweep_diopters' needs: the setup, the lens's blur per diopter, its surrogate's focus range
        blur_px_per_d = 1.26

        class src:
            class model:
                focus_range_m = (0.05, 2.0)

    coarse, fine = Rig(), Rig()
    coarse.setup, fine.setup = p, n
    a, b = bc.sweep_diopters(coarse, 14.0, 11.0), bc.sweep_diopters(fine, 14.0, 11.0)
    assert a[0] == b[0] and a[-1] == b[-1]  # the same reach
    assert np.mean(np.diff(a)) == pytest.approx(1.4 / 1.26, rel=0.1) and np.mean(np.diff(b)) == pytest.approx(
        0.7 / 1.26, rel=0.1) and len(b) >= 2 * len(a) - 2
    np.testing.assert_array_equal(n.inside(), p.inside())
    assert n.inside().max() == pytest.approx(0.18) and n.inside().min() == pytest.approx(0.07)
    names = []

    class Stop(Exception):
        pass

    def fake_chart_for(rig, d):
        return None, None

    monkeypatch.setattr(bc, "CACHE", tmp_path)
    monkeypatch.setattr(bc, "chart_for", fake_chart_for)
    monkeypatch.setattr(bc, "sweep_sources", lambda s: {})
    real_is_file = bc.Path.is_file

    def spy(self):
        names.append(self.name)
        raise Stop

    monkeypatch.setattr(bc.Path, "is_file", spy)

    class R:
        setup = n

    for i in range(4):
        with pytest.raises(Stop):
            bc.sweep(R(), "copy", i)
    monkeypatch.setattr(bc.Path, "is_file", real_is_file)
    assert names == ["cellphone_copy_0.07m_step0.7px_soft0.7px.npz", "cellphone_copy_0.1m_step0.7px_soft0.7px.npz",
                     "cellphone_copy_0.18m_step0.7px_soft0.7px.npz", "cellphone_copy_0.055m_step0.7px_soft0.7px.npz"]


def test_the_benchmarks_chart_is_aat_calibrates_softened_chart_cached_apart_from_the_sharp_one(tmp_path, monkeypatch):
    """Every setup's chart is `aat-calibrate chart --frame-px`'s: the dead leaves softened by SOFT_SENSOR_PX camera
    pixels where the chart spans the frame (its image has CHART_PX_PER_PX pixels per camera pixel there), the
    markers drawn sharp; its sweeps are cached under names of their own (`_soft0.7px`), the sharp dead leaves'
    (chart_soften_px = 0, before 2026-11-27) under their old names."""
    import dataclasses

    from aat_deploy.calibrate import chart

    assert bc.SOFT_SENSOR_PX == chart.SOFT_SENSOR_PX == 0.7
    assert all(s.chart_soften_px == chart.SOFT_SENSOR_PX for s in bc.LENSES.values())

    class R:
        w, h, f_px = 640, 480, 500.0  # a camera: its frame and focal length (px)
        setup = bc.LENSES["cellphone_near"]

    img, layout = bc.chart_for(R(), 0.1)
    assert layout.spec["texture_sigma_mm"] * layout.px_per_mm == pytest.approx(0.7 * bc.CHART_PX_PER_PX)
    frame_mm = layout.size_mm[0] / 1.3
    assert layout.spec["texture_sigma_mm"] == pytest.approx(chart.texture_sigma_for(frame_mm, R.w))
    R.setup = dataclasses.replace(bc.LENSES["cellphone_near"], chart_soften_px=0.0)
    sharp, layout0 = bc.chart_for(R(), 0.1)
    assert layout0.spec["texture_sigma_mm"] == 0.0 and np.abs(sharp.astype(int) - img).mean() > 5

    names = []

    class Stop(Exception):
        pass

    monkeypatch.setattr(bc, "CACHE", tmp_path)
    monkeypatch.setattr(bc, "chart_for", lambda rig, d: (None, None))
    monkeypatch.setattr(bc, "sweep_sources", lambda s: {})

    def spy(self):
        names.append(self.name)
        raise Stop

    monkeypatch.setattr(bc.Path, "is_file", spy)
    for setup in (bc.LENSES["rf50"], dataclasses.replace(bc.LENSES["rf50"], chart_soften_px=0.0)):
        R.setup = setup
        with pytest.raises(Stop):
            bc.sweep(R(), "nominal", 0)
    assert names == ["rf50_nominal_0.6m_soft0.7px.npz", "rf50_nominal_0.6m.npz"]


def test_a_random_copys_sweeps_are_named_after_the_copy():
    """The fit names each sweep (its warnings, `residuals.per_sweep`) after its copy, not the variant: a random
    copy's sweeps were all named `..._copy_...` before, like the hand-chosen copy's."""
    from benchmarks import calibrate_copies as cc

    base = bc.LENSES["cellphone_near"]
    s = cc.copy_setup(base, 2026, _copies("cellphone_near", 1, n_el=6)[0])

    class R:
        setup, w, h, efl, fno = s, 8, 6, 5.6, 2.8

        class lens:
            name = "phone"

    sw = {"distance_m": 0.055, "frames": np.zeros((3, 3, 6, 8), np.float32), "reported_m": np.array([3.0, 2.0, 1.0])}
    assert bc.as_sweep(R(), sw, "copy").path.name == "cellphone_near_copy_s2026_0_0.055m"
    assert bc.as_sweep(R(), sw, "nominal").path.name == "cellphone_near_nominal_0.055m"
    R.setup = base
    assert bc.as_sweep(R(), sw, "copy").path.name == "cellphone_near_copy_0.055m"
    # every other frame from the second (benchmarks/probes/tile_bias.py: the sweep at twice the step, both phases)
    np.testing.assert_array_equal(bc.as_sweep(R(), sw, "nominal", 2, 1).reported_m, [2.0])
    np.testing.assert_array_equal(bc.as_sweep(R(), sw, "nominal", 2).reported_m, [3.0, 1.0])


def test_the_maps_error_is_split_where_tiles_measured_the_field():
    """Within the farthest tile's field radius (the file's `best_focus.radius_max`) and beyond it, where the field
    term is held: the two parts' squared errors add up to the whole frame's, and an error only beyond reads 0
    within."""
    from aat_deploy.calibrate.format import field_grid, field_radius_of

    h, w = 48, 64
    x, y = field_grid(h, w)
    rad = field_radius_of(x, y, w / h)
    d = np.stack([np.where(rad > 0.8, 0.5, 0.0), np.where(rad > 0.8, -0.3, 0.0)])
    out = bc.tile_coverage(d, 0.8, w / h)
    share = float(np.mean(rad > 0.8))
    assert out["within_tiles_rms_d"] == 0 and out["beyond_tiles_share"] == pytest.approx(share)
    assert out["beyond_tiles_rms_d"] == pytest.approx(np.sqrt((0.25 + 0.09) / 2))
    assert out["beyond_tiles_rms_d"] ** 2 * share == pytest.approx(np.mean(d ** 2))
    assert bc.tile_coverage(d, 2.0, w / h)["beyond_tiles_rms_d"] is None
