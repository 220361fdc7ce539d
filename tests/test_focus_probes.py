"""The issue-32 probes' arithmetic on hand-made cases: a frame's focus error split over regions
(`benchmarks/probes/focus_frame_regions.py`) and a family refitted to the per-frame estimates
(`benchmarks/probes/focus_family_on_estimates.py`), and the systematic allowances compared from stored fits
(`benchmarks/probes/focus_systematic_level.py`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks.probes import focus_family_on_estimates as fe
from benchmarks.probes import focus_frame_regions as fr


def test_a_frames_error_splits_over_its_regions_by_their_pull():
    """Quadratic region costs a_r (x - m_r)^2: the estimate is the a-weighted mean of the m_r, each region pulls
    a_r (m_r - true) / sum a, the pulls add up to the error, and leaving one out gives the others' mean."""
    xs = np.arange(0.8, 1.2 + 1e-9, 0.0005)
    a, m, true = np.array([1.0, 3.0, 0.5]), np.array([1.05, 0.98, 1.10]), 1.0
    costs = a * (xs[:, None] - m) ** 2
    dec = fr.decompose(costs, xs, true)
    est = float(np.sum(a * m) / a.sum())
    assert abs(dec["est"] - est) <= 0.0005
    assert np.allclose(dec["pull"], a * (m - true) / a.sum(), atol=2e-3)
    assert abs(dec["pull"].sum() - (dec["est"] - true)) < 1e-9  # exact by construction of the secant
    assert np.allclose(dec["own"], m, atol=0.0005)
    loo0 = np.sum(a[1:] * m[1:]) / a[1:].sum()
    assert abs(dec["loo"][0] - loo0) <= 0.0005
    assert int(np.argmax(np.abs(dec["pull"]))) == 1  # the heavy region, though region 2 sits farther off


def test_a_family_refitted_to_the_estimates_is_their_weighted_least_squares():
    """An offset row: the refit is the reported focus less the inverse-variance weighted mean of (reported -
    estimate); a frame with a 10x smaller variance dominates it."""
    rep = np.array([1.6, 1.2, 0.8, 0.4])
    est = rep - np.array([0.05, 0.06, 0.04, 0.10])
    sd = np.array([0.01, 0.01, 0.01, 0.01])
    sys_d = np.array([0.01, 0.01, 0.01, 0.1])  # the last frame barely counts
    row = {"family": "offset", "frame_focus_sd_d": [sd.tolist()], "frame_systematic_d": [sys_d.tolist()],
           "families": [{"family": "none", "true_d": [rep.tolist()]},
                        {"family": "offset", "true_d": [(rep - 0.06).tolist()]},
                        {"family": "per_frame", "true_d": [est.tolist()]}]}
    w = 1 / (sd ** 2 + sys_d ** 2)
    b = np.sum(w * (rep - est)) / w.sum()
    assert np.allclose(fe.refit(row), rep - b)
    assert abs(b - 0.05) < 0.002
    assert fe.refit(dict(row, family="quantisation")) is None  # not linear in its parameters: not refitted


def test_the_model_averaging_variant_adds_the_competing_familys_spread_where_it_is_asked_for():
    """`sd_variants`: a scale chosen (score 10) over a curve (score 12, weight e^-1 of the scale's) whose focus is
    0.05 D away at a left-out frame 0: model averaging adds p (0.05)^2, p = e^-1 / (1 + e^-1) = 0.269, there (sd
    0.026 D: undetermined), at every frame or at the left-out frame only; as fitted the set is claimed and 0.03 D off."""
    row = {"kind": "scale_1.1", "family": "scale", "error_scale": 1.5, "frames_noise_dominated": [True, False],
           "corrected_sd_d": [[0.01, 0.005]], "corrected_err_d": [0.03, 0.0],
           "families": [{"family": "scale", "score": 10.0, "true_d": [[1.0, 0.5]]},
                        {"family": "monotone", "score": 12.0, "true_d": [[1.05, 0.5]]},
                        {"family": "per_frame", "score": 0.0, "true_d": [[9.0, 9.0]]}]}  # never averaged in
    v = fe.sd_variants([row])
    assert v["as fitted"]["claimed_wrong"] == 1 and v["as fitted"]["covered"] == 1
    for name in ("model averaging, every frame", "model averaging, left-out frames"):
        assert v[name]["claimed_wrong"] == 0 and v[name]["covered"] == 2
    p = np.exp(-1) / (1 + np.exp(-1))
    assert np.hypot(0.01, 0.05 * np.sqrt(p)) > 0.02 > np.hypot(0.01, 0.0)
    assert v["times the error scale"]["claimed_wrong"] == 1  # 0.015 D: still claimed


def level_sweep():
    """A far scene (every region 2-6 m away) seen over the shipped sample's focus (0.6-6 m), its curves a third as
    steep as `tests/deploy/diagnose/test_focusfit.py`'s and the frames' levels off by 0.15 log (sd): most frames see
    nothing in focus, the level misfit times the nearest frame's sensitivity exceeds the median-scaled allowance."""
    from aat_deploy.diagnose import focusfit as ff

    rng = np.random.default_rng(0)
    true = np.linspace(1 / 0.6, 1 / 6.0, 8)[None]
    grid = np.arange(0.0, 2.2, 0.06)
    depth = rng.uniform(0.17, 0.5, size=54)
    peak = lambda dd, f: -np.log1p(((f[..., None, :] - dd[:, None]) / 0.15) ** 2) * 1.5
    cap = np.stack([peak(depth[r:r + 1], true[0])[0] for r in range(54)])[None] / 3
    cap = cap + rng.normal(0, 0.4, size=(1, 54, 1)) + rng.normal(0, 0.005, size=cap.shape) + rng.normal(0, 0.15, 8)
    xy = np.stack([np.tile(np.linspace(-0.9, 0.9, 9), 6), np.repeat(np.linspace(0.8, -0.8, 6), 9)], 1)
    return ff.SweepData(grid, peak(depth, grid)[None] / 3, cap, true.copy(), true.copy(), xy), true


def level_rows(true: np.ndarray) -> list[dict]:
    """Stored fits of one scene: its untouched copy and a copy reported at 1.1 x the distance, both fitted exactly
    (their per-frame estimates the truth)."""
    t = true.tolist()
    common = {"capture": "scene", "frame_focus_sd_d": [[0.004] * 8], "frame_systematic_d": [[0.01] * 8],
              "corrected_err_d": [0.0] * 8, "frame_max_err_d": 0.0, "frames_on_bound": 0, "focus_named": False,
              "commit": "old", "fit_only": True}
    none = {**common, "kind": "none", "family": "none", "family_true": "none", "reported_max_err_d": 0.0,
            "families": [{"family": "none", "k": 0, "true_d": t}, {"family": "offset", "k": 1, "true_d": t},
                         {"family": "per_frame", "k": 8, "true_d": t}]}
    rep = (true / 1.1).tolist()
    scale = {**common, "kind": "scale_1.1", "family": "scale", "family_true": "scale",
             "reported_max_err_d": float(np.abs(true / 1.1 - true).max()),
             "families": [{"family": "none", "k": 0, "true_d": rep}, {"family": "scale", "k": 1, "true_d": t},
                          {"family": "per_frame", "k": 8, "true_d": t}]}
    return [none, scale]


def test_focus_systematic_level_compares_each_allowance_on_the_untouched_copys_sweep(monkeypatch):
    """`focus_systematic_level.variants`: each row's allowance is computed on its scene's untouched copy's sweep at
    the row's own per-frame estimates, by the formula its variant names (capped at MAX_ERROR_D); the code now is
    `frame_systematic(from_level=True)` and on a scene where most frames see nothing in focus it gives the nearest
    frame more than the median scaling; the scene's level misfit and sensitivities are reported; rows of a scene
    whose sweep is not cached, or without a stored allowance, are left out."""
    from aat_deploy.diagnose import focusfit as ff
    from benchmarks.probes import focus_systematic_level as fsl

    data, true = level_sweep()
    monkeypatch.setattr(fsl, "prepared_none", lambda cap, cache: data if cap == "scene" else None)
    rows = level_rows(true) + [{**level_rows(true)[1], "capture": "uncached"},
                               {**level_rows(true)[1], "kind": "scale_0.9", "frame_systematic_d": None}]
    out, info = fsl.variants(rows, Path("unused"))
    m, k = ff.level_misfit(data, true)[0], ff.level_sensitivity(data, true)[0]
    assert set(info) == {"scene"} and info["scene"][0] == m and np.array_equal(info["scene"][1], k)
    assert m > 0.005  # the frames' levels off (an untouched far scene's misfit is under 0.005 log)
    median = ff.frame_systematic(data, true, from_level=False)[0]
    lev = m * np.abs(k)
    want = {"median": median, "level_max": np.maximum(ff.SYSTEMATIC_D, lev),
            "level_quadrature": np.hypot(ff.SYSTEMATIC_D, lev), "median_or_level": ff.frame_systematic(data, true)[0]}
    for name, w in want.items():
        assert [(r["capture"], r["kind"]) for r in out[name]] == [("scene", "none"), ("scene", "scale_1.1")]
        for r in out[name]:
            assert np.allclose(r["frame_systematic_d"][0], np.round(np.minimum(w, ff.MAX_ERROR_D), 5), atol=1e-9)
            assert r["rescored_from"] == "old"
    now = np.asarray(out["median_or_level"][0]["frame_systematic_d"][0])
    assert now[0] > 1.5 * median[0] and np.all(now >= np.round(median, 5))


def test_focus_systematic_level_writes_its_tables_and_never_over_an_input(monkeypatch, tmp_path, capsys):
    """The probe's command: the scene's level misfit and each variant's rescored table, to stdout and (--out) a
    markdown file; an --out that is one of the results read is refused before anything is written."""
    import json
    import sys

    import pytest

    from benchmarks.probes import focus_systematic_level as fsl

    data, true = level_sweep()
    monkeypatch.setattr(fsl, "prepared_none", lambda cap, cache: data)
    src = tmp_path / "fits.jsonl"
    src.write_text("".join(json.dumps(r) + "\n" for r in level_rows(true)))
    before = src.read_bytes()
    out = tmp_path / "out.md"
    monkeypatch.setattr(sys, "argv", ["probe", str(src), "--out", str(out)])
    fsl.main()
    text = out.read_text()
    assert text.startswith("# Systematic allowance from the capture's level misfit")
    assert f"| scene | {ff_misfit(data, true):.3f} |" in text
    for label in fsl.VARIANTS.values():
        assert f"### {label}, rescored from the stored fits" in text
    assert "- scene: family right" in capsys.readouterr().out
    monkeypatch.setattr(sys, "argv", ["probe", str(src), "--out", str(src)])
    with pytest.raises(SystemExit, match="is one of the results read"):
        fsl.main()
    assert src.read_bytes() == before


def ff_misfit(data, true) -> float:
    from aat_deploy.diagnose import focusfit as ff

    return float(ff.level_misfit(data, true)[0])


def test_focus_family_on_estimates_refuses_in_one_line_and_never_replaces_its_out(tmp_path, capsys, monkeypatch):
    """Its defaults are committed results files: an existing --out (or, with --choice, the .json beside it) and a
    missing input are refused before any row is read; a good run writes both files."""
    rows = tmp_path / "r.jsonl"
    rows.write_text("")
    out = tmp_path / "c.md"
    cases = [([str(tmp_path / "none.jsonl"), "--out", str(out)], "none.jsonl: no such results file"),
             ([str(rows), "--choice", "--out", str(tmp_path / "c.json")], "not .json")]
    (tmp_path / "k.json").write_text("mine")
    cases.append(([str(rows), "--choice", "--out", str(tmp_path / "k.md")], "k.json: exists"))
    (tmp_path / "m.md").write_text("mine")
    cases.append(([str(rows), "--out", str(tmp_path / "m.md")], "m.md: exists"))
    called = []
    monkeypatch.setattr(fe, "choice", lambda rows: called.append(rows) or {"sets": 0})
    for args, says in cases:
        with pytest.raises(SystemExit):
            fe.main(args)
        assert says in capsys.readouterr().err.strip().splitlines()[-1]
    assert called == [] and (tmp_path / "k.json").read_text() == "mine" and (tmp_path / "m.md").read_text() == "mine"
    assert not out.exists()
    assert fe.main([str(rows), "--choice", "--out", str(out)]) == 0
    assert called == [[]] and json.loads(out.with_suffix(".json").read_text()) == {"files": [str(rows)], "sets": 0}
    assert out.read_text().startswith("# `python -m benchmarks.probes.focus_family_on_estimates --choice ")


def test_focus_noise_weight_refuses_in_one_line_and_pairs_the_sets(tmp_path, capsys):
    """`focus_noise_weight`: a missing input, a non-.md --out and an existing --out or .json beside it are refused in
    one line before any row is read; a run pairs each row with and without the noise-share weights, and its sign test
    is the binomial one (9 of 10 scenes: p = 22 / 1024)."""
    from benchmarks.probes import focus_noise_weight as nw

    assert nw.sign_test(9, 10) == pytest.approx(22 / 1024) and nw.sign_test(5, 10) == 1.0
    rows = tmp_path / "r.jsonl"
    rep = np.array([[1.63, 1.31, 0.97, 0.72, 0.51, 0.33]])  # an offset of 0.05 D; frame 0 left out
    est = rep - 0.05 - np.array([[0.15, 0.04, 0, 0, 0, 0]])  # frame 1 (share 0.4) 0.04 D under the truth
    fams = [{"family": "none", "k": 0, "true_d": rep.tolist()}, {"family": "offset", "k": 1, "true_d": (rep - 0.05).tolist()},
            {"family": "per_frame", "k": 6, "true_d": est.tolist()}]
    row = {"capture": "scene1", "kind": "offset_+0.05", "family": "offset", "family_true": "offset", "families": fams,
           "frame_focus_sd_d": [[None] + [0.004] * 5], "frame_systematic_d": [[0.03, 0.025] + [0.01] * 4],
           "corrected_err_d": [0.0] * 6, "frames_noise_dominated": [True] + [False] * 5,
           "frame_noise_share": [0.7, 0.4, 0.1, 0.0, 0.0, 0.0], "commit": "old"}
    rows.write_text(json.dumps(row) + "\n")
    (tmp_path / "k.json").write_text("mine")
    (tmp_path / "m.md").write_text("mine")
    for args, says in [([str(tmp_path / "none.jsonl"), "--out", str(tmp_path / "a.md")], "none.jsonl: no such results file"),
                       ([str(rows), "--out", str(tmp_path / "a.json")], "a .md file"),
                       ([str(rows), "--out", str(tmp_path / "k.md")], "k.json: exists"),
                       ([str(rows), "--out", str(tmp_path / "m.md")], "m.md: exists")]:
        with pytest.raises(SystemExit):
            nw.main(args)
        assert says in capsys.readouterr().err.strip().splitlines()[-1]
    assert (tmp_path / "k.json").read_text() == "mine" and (tmp_path / "m.md").read_text() == "mine"
    out = tmp_path / "c.md"
    assert nw.main([str(rows), "--out", str(out)]) == 0
    got = json.loads(out.with_suffix(".json").read_text())
    assert got["plain"]["sets"] == got["weighed"]["sets"] == 1
    # the offset moves towards frame 1 by 0.0017 D plain, 0.0004 D weighed: the set's largest error falls
    assert got["paired"]["sets_better"] == 1 and got["paired"]["scene_mean_change_d"]["scene1"] < -0.001
    assert got["rows_repeating_a_set"] == 0 and "repeat a set" not in capsys.readouterr().out
    # the same set given twice (a rerun in a later file): counted once, its last row, and said in one line
    twice = tmp_path / "r2.jsonl"
    twice.write_text(json.dumps(dict(row, commit="rerun")) + "\n")
    out2 = tmp_path / "d.md"
    assert nw.main([str(rows), str(twice), "--out", str(out2)]) == 0
    said = [x for x in capsys.readouterr().out.splitlines() if "repeat a set" in x]
    assert said == ["1 of 2 rows repeat a set (capture, kind) given earlier: each set's last row is used"]
    got = json.loads(out2.with_suffix(".json").read_text())
    assert got["rows_repeating_a_set"] == 1 and got["plain"]["sets"] == 1
    assert said[0] in out2.read_text()


def test_focus_choice_nearest_ranks_fitted_frames_nearest_first_and_restores_the_code():
    """`focus_choice_nearest.by_rank`: a left-out frame is not ranked, the nearest fitted frame (largest reported
    diopters) is rank 0, its standardised error its error over the spread and systematic error in quadrature;
    `variants` leaves `focusfit`'s functions as they were."""
    from aat_deploy.diagnose import focusfit as ff
    from benchmarks.probes import focus_choice_nearest as fcn

    row = {"frame_err_d": [0.5, 0.03, 0.004], "frame_focus_sd_d": [[None, 0.0, 0.003]],
           "frame_systematic_d": [[0.01, 0.01, 0.004]], "frames_noise_dominated": [True, False, False],
           "frame_noise_share": [0.7, 0.3, 0.1], "families": [{"family": "none", "true_d": [[1.6, 1.2, 0.4]]}]}
    b = fcn.by_rank([row])
    assert [x["frames"] for x in b] == [1, 1]
    assert b[0]["rms_err_d"] == 0.03 and b[0]["rms_z"] == 3.0 and b[0]["median_share"] == 0.3
    assert b[1]["rms_z"] == 0.8
    before = ff.error_scale, ff.score_families, ff.signal_weight, ff.CHOICE_NEAREST_FACTOR
    fcn.variants([], [1.0, 3.0])
    assert (ff.error_scale, ff.score_families, ff.signal_weight, ff.CHOICE_NEAREST_FACTOR) == before


def test_focus_choice_nearest_pairs_scenes_and_refuses_an_existing_out(tmp_path, capsys):
    """`scenes_moved`: a scene whose set gains its family (or stops being claimed wrong) with nothing lost is better, the
    reverse worse, and the sign test runs over such scenes; `main` refuses an existing or non-.md --out in one line
    before reading any row."""
    from benchmarks.probes import focus_choice_nearest as fcn

    def r(cap, kind, ok, err, und=0):
        return {"capture": cap, "kind": kind, "family_ok": ok, "corrected_max_err_d": err, "frames_undetermined": und}

    base = [r("a", "scale_0.9", False, 0.06), r("b", "monotone", True, 0.01, 2), r("c", "none", True, 0.0)]
    var = [r("a", "scale_0.9", True, 0.004), r("b", "monotone", False, 0.04, 2), r("c", "none", True, 0.0)]
    m = fcn.scenes_moved(base, var)
    assert m["scenes"] == {"a": ["scale_0.9 better"], "b": ["monotone worse"]}
    assert (m["scenes_better"], m["scenes_worse"], m["sign_test_p"]) == (1, 1, 1.0)
    rows = tmp_path / "r.jsonl"
    rows.write_text("")
    (tmp_path / "x.md").write_text("mine")
    for args, says in [([str(rows), "--out", str(tmp_path / "x.md")], "exists"),
                       ([str(rows), "--out", str(tmp_path / "x.json")], "a .md file"),
                       ([str(tmp_path / "no.jsonl")], "no such results file")]:
        with pytest.raises(SystemExit):
            fcn.main(args)
        assert says in capsys.readouterr().err.strip().splitlines()[-1]
    assert (tmp_path / "x.md").read_text() == "mine"


def test_focus_family_mixture_widens_where_tied_families_part_and_refuses_in_one_line(tmp_path, capsys):
    """`focus_family_mixture`: a scale set whose left-out frames the offset extrapolates differently, the two tied on
    the fitted frames: `mix:offset,scale` keeps the corrected focus and widens the left-out frames' standard error by
    the families' spread there (undetermined), the fitted frames' hardly; `bma` moves the corrected focus towards the
    posterior mean; an existing or non-.md --out is refused in one line before any row is read."""
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes import focus_family_mixture as fm

    true = np.linspace(1 / 0.6, 1 / 6.0, 8)
    rep = true / 1.05
    est = true + np.array([0.0, 0, 0, 0, 0.002, -0.002, 0.001, -0.001])
    fams = [{"family": "none", "k": 0, "true_d": [rep.tolist()]}, {"family": "scale", "k": 1, "true_d": [true.tolist()]},
            {"family": "per_frame", "k": 8, "true_d": [est.tolist()]}]
    row = {"capture": "s", "kind": "scale_1.05", "family": "scale", "family_true": "scale", "families": fams,
           "frame_focus_sd_d": [[None] * 4 + [0.003] * 4], "frame_systematic_d": [[0.01] * 8],
           "corrected_err_d": [0.0] * 8, "frames_noise_dominated": [True] * 4 + [False] * 4, "commit": "old"}
    r = bench.rescored(row, "code", on_estimates=True)
    f = {x["family"]: x for x in r["families"]}
    part = np.abs(np.asarray(f["offset"]["true_d"][0]) - np.asarray(f["scale"]["true_d"][0]))
    assert part[0] > 0.03 and part[:4].min() > part[4:].max()  # they part most at the left-out frames
    p = fm.posterior(f, ["offset", "scale"])
    assert abs(sum(p.values()) - 1) < 1e-12 and min(p.values()) > 0.05  # tied enough to matter
    m = fm.variant(row, r, "mix:offset,scale")
    sd0, sd1 = np.asarray(r["corrected_sd_d"])[0], np.asarray(m["corrected_sd_d"])[0]
    assert np.all(sd1 >= sd0 - 1e-12) and sd1[0] >= 0.02 > sd0[0] and m["frames_undetermined"] >= 1
    assert m["corrected_err_d"] == r["corrected_err_d"]
    b = fm.variant(row, r, "bma:offset,scale")
    assert b["corrected_sd_d"] == r["corrected_sd_d"] and abs(b["corrected_err_d"][0]) > 0.002
    rows = tmp_path / "r.jsonl"
    rows.write_text(json.dumps(row) + "\n")
    (tmp_path / "x.md").write_text("mine")
    for args, says in [([str(rows), "--out", str(tmp_path / "x.md")], "exists"),
                       ([str(rows), "--out", str(tmp_path / "y.json")], "a .md file")]:
        with pytest.raises(SystemExit):
            fm.main(args)
        assert says in capsys.readouterr().err.strip().splitlines()[-1]
    assert fm.main([str(rows), "--out", str(tmp_path / "z.md")]) == 0
    assert "| mix:offset,scale | s scale_1.05 |" in (tmp_path / "z.md").read_text()


def test_focus_shared_misfit_splits_a_scenes_common_pattern_and_its_variants_restore_the_code(tmp_path, capsys):
    """`focus_shared_misfit`: a scene whose sets carry one error pattern has it all common, one whose sets' errors
    differ has none common; the untouched copy's slope against the true focus is its fitted b; the correlated choice
    with L = 0 scores every family as the code does (and `variants` leaves `focusfit` as it was); a family within the
    gap that puts a frame over 0.02 D away makes it undetermined, one outside the gap does not; an existing --out is
    refused in one line before any row is read."""
    from aat_deploy.diagnose import focusfit as ff
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes import focus_shared_misfit as sm

    true = np.linspace(1 / 0.6, 1 / 6.0, 8)
    pattern = 0.01 - 0.02 * true  # slope -0.02 against the true focus

    def row(cap, kind, err, rep=None, fam="none"):
        rep = true if rep is None else rep
        est = true + err
        fams = [{"family": "none", "k": 0, "score": 0.0, "true_d": [rep.tolist()]},
                {"family": "scale", "k": 1, "score": 0.0, "true_d": [true.tolist()]},
                {"family": "offset", "k": 1, "score": 0.0, "true_d": [(rep + np.mean(est - rep)).tolist()]},
                {"family": "per_frame", "k": 8, "score": 0.0, "true_d": [est.tolist()]}]
        return {"capture": cap, "kind": kind, "family": fam, "family_true": fam, "family_ok": True, "families": fams,
                "frame_err_d": err.tolist(), "frame_focus_sd_d": [[0.001] * 8], "frame_systematic_d": [[0.01] * 8],
                "corrected_err_d": (np.asarray(fams[[f["family"] for f in fams].index(fam)]["true_d"][0]) - true).tolist(),
                "commit": "old"}

    rng = np.random.default_rng(0)
    rows = [row("a", "none", pattern), row("a", "scale_1.1", pattern, true / 1.1, "scale"),
            row("b", "none", rng.normal(0, 0.01, 8)), row("b", "scale_1.1", rng.normal(0, 0.01, 8), true / 1.1, "scale")]
    sh, share = sm.shared(rows)
    got = {x["scene"]: x for x in sh}
    assert got["a"]["common_share"] == 1.0 and got["a"]["untouched_corr"] is None  # two sets: no others' mean to take
    assert got["b"]["common_share"] < 0.8 and 0 < share < 1
    slope = {x["scene"]: x for x in sm.apparent_slope(rows, [bench.rescored(r, "c", on_estimates=True) for r in rows])}
    assert slope["a"]["slope"] == pytest.approx(-0.02, abs=1e-4) and slope["a"]["offset_d"] == pytest.approx(0.01, abs=1e-4)
    assert set(slope["a"]["scales_read"]) == {"1.1"}
    # L = 0: the correlated choice is the code's
    code = bench.rescored(rows[1], "c", on_estimates=True)
    before = ff.score_families, ff.error_scale
    try:
        ff.score_families, ff.error_scale = sm.gls(0.0)
        zero = bench.rescored(rows[1], "c", on_estimates=True)
    finally:
        ff.score_families, ff.error_scale = before
    assert [f["score"] for f in zero["families"]] == pytest.approx([f["score"] for f in code["families"]])
    sm.variants(rows[:2])
    assert (ff.score_families, ff.error_scale) == before
    # the runner-up rule
    r = {"family": "scale", "corrected_sd_d": [[0.005] * 8], "frames_undetermined": 0,
         "families": [{"family": "scale", "score": 1.0, "true_d": [true.tolist()]},
                      {"family": "offset", "score": 2.5, "true_d": [(true + np.r_[0.05, np.zeros(7)]).tolist()]},
                      {"family": "per_frame", "score": -5.0, "true_d": [(true + 0.1).tolist()]}]}
    assert sm.runner_up(r, 2.0)["frames_undetermined"] == 1 and sm.runner_up(r, 1.0)["frames_undetermined"] == 0
    p = tmp_path / "r.jsonl"
    p.write_text("".join(json.dumps(x) + "\n" for x in rows))
    (tmp_path / "x.md").write_text("mine")
    with pytest.raises(SystemExit):
        sm.main([str(p), "--out", str(tmp_path / "x.md")])
    assert "does not exist yet" in capsys.readouterr().err.strip().splitlines()[-1]
    assert sm.main([str(p), "--out", str(tmp_path / "y.md")]) == 0
    assert json.loads((tmp_path / "y.json").read_text())["counts"]["code"]["sets"] == 4


def test_focus_shared_misfit_invariant_gives_every_set_its_untouched_copys_errors():
    """`invariant`: each set's estimates become the truth plus the untouched copy's errors where that copy fitted the
    frame, the set's own estimate where it did not; a scene without an untouched copy is left out."""
    from benchmarks.probes import focus_shared_misfit as sm

    true = np.array([1.5, 1.0, 0.5])

    def row(cap, kind, err, est):
        return {"capture": cap, "kind": kind, "family": "none", "frame_err_d": err, "corrected_err_d": [0.0] * 3,
                "families": [{"family": "none", "true_d": [true.tolist()]},
                             {"family": "per_frame", "true_d": [est]}]}

    rows = [row("a", "none", [float("nan"), 0.01, -0.02], [9.0, 1.01, 0.48]),
            row("a", "offset_+0.05", [0.3, 0.03, 0.0], [1.8, 1.03, 0.5]), row("b", "offset_+0.05", [0, 0, 0], [0, 0, 0])]
    out = sm.invariant(rows)
    assert [(r["capture"], r["kind"]) for r in out] == [("a", "none"), ("a", "offset_+0.05")]
    per = next(f for f in out[1]["families"] if f["family"] == "per_frame")["true_d"][0]
    assert per == pytest.approx([1.8, 1.01, 0.48])
    assert next(f for f in rows[1]["families"] if f["family"] == "per_frame")["true_d"][0] == [1.8, 1.03, 0.5]  # input kept


def test_focus_shared_misfit_runner_gap_counts_only_families_that_move_a_frame_over_0_02_d():
    """`runner_gap`: the nearest score among the families that put some frame more than 0.02 D from the chosen one's
    focus (`per_frame` and families within 0.02 D everywhere not counted); None without one; `gap_by_outcome` files
    the set by its outcome."""
    from benchmarks.probes import focus_shared_misfit as sm

    t = np.array([1.5, 1.0, 0.5])
    r = {"kind": "scale_1.1", "family": "scale", "frames_undetermined": 0, "corrected_max_err_d": 0.05,
         "families": [{"family": "scale", "score": 1.0, "true_d": [t.tolist()]},
                      {"family": "offset", "score": 1.5, "true_d": [(t + 0.01).tolist()]},
                      {"family": "monotone", "score": 4.0, "true_d": [(t + np.r_[0.03, 0, 0]).tolist()]},
                      {"family": "per_frame", "score": -9.0, "true_d": [(t + 0.3).tolist()]}]}
    assert sm.runner_gap(r) == pytest.approx(3.0)
    assert sm.gap_by_outcome([r])["claimed_over"]["median"] == 3.0
    r["families"] = r["families"][:2]
    assert sm.runner_gap(r) is None


def test_focus_start_invariance_starts_from_the_first_pass_and_summarises_against_the_untouched_copy(tmp_path, capsys):
    """`focus_start_invariance`: the first pass is the stored `per_frame` estimates, the chosen family's value at the
    frames left out; the summary's coefficient on the untouched errors is 1 for the untouched pattern and the stored
    row's beside it; --mode start refuses two captures of one kind in one line."""
    from benchmarks.probes import focus_start_invariance as si

    true = np.array([1.6, 1.2, 0.8, 0.4])
    pattern = np.array([np.nan, -0.01, 0.02, -0.01])

    def row(kind, rep, err):
        fams = [{"family": "none", "k": 0, "true_d": [rep.tolist()]}, {"family": "scale", "k": 1, "true_d": [true.tolist()]},
                {"family": "offset", "k": 1, "true_d": [(rep - 0.01).tolist()]},
                {"family": "per_frame", "k": 4, "true_d": [(true + np.nan_to_num(err, nan=0.3)).tolist()]}]
        return {"capture": "s", "kind": kind, "family": "scale", "family_true": "scale", "families": fams,
                "frame_err_d": err.tolist(), "frame_focus_sd_d": [[None, 0.001, 0.001, 0.001]],
                "frame_systematic_d": [[0.01] * 4], "corrected_err_d": [0.0] * 4,
                "frames_noise_dominated": [True, False, False, False], "corrected_max_err_d": 0.0,
                "frames_undetermined": 0, "commit": "old"}

    stored = [row("none", true, pattern), row("scale_1.1", true / 1.1, 2 * pattern)]
    stored[0]["family"] = "none"
    stored[0]["corrected_err_d"] = [0.0] * 4
    assert si.first_pass(stored[1]) == pytest.approx([1.6, 1.18, 0.84, 0.38])  # frame 0 left out: the scale's value
    rerun = [dict(stored[1], frame_err_d=pattern.tolist())]
    s = si.summary(rerun, stored)[0]
    assert (s["coef"], s["stored_coef"]) == (1.0, 2.0)
    # a rerun whose own fit chose a wrong family, claimed 0.05 D off, against a stored set the code reads right
    t = si.tally([dict(rerun[0], family="offset", family_ok=False, corrected_max_err_d=0.05, frames_undetermined=0)],
                 stored)
    assert (t["sets_better"], t["sets_worse"], t["scenes_worse"]) == (0, 1, 1)
    with pytest.raises(SystemExit):
        si.main(["--mode", "start", "--rows", str(tmp_path / "none.jsonl"), "--out", "x.jsonl"])
    assert "no such results file" in capsys.readouterr().err.strip().splitlines()[-1]
    rows = tmp_path / "r.jsonl"
    rows.write_text("".join(json.dumps(r) + "\n" for r in stored))
    with pytest.raises(SystemExit):
        si.main(["--mode", "start", "--rows", str(rows), "--out", str(tmp_path / "o.jsonl"), "--",
                 "--sets", "a:scale_1.1,b:scale_1.1"])
    assert "one capture per kind" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "o.jsonl").exists()


def test_focus_start_invariance_refuses_start_without_sets_and_a_summary_of_sets_not_in_rows(tmp_path, capsys):
    """`focus_start_invariance`: --mode start with no --sets after -- and --summary of a rerun set (or its untouched
    copy) that --rows lacks each end in one line naming what is missing, nothing run or printed."""
    from benchmarks.probes import focus_start_invariance as si

    rows = tmp_path / "r.jsonl"
    rows.write_text(json.dumps({"capture": "s", "kind": "none"}) + "\n")
    with pytest.raises(SystemExit):
        si.main(["--mode", "start", "--rows", str(rows), "--out", str(tmp_path / "o.jsonl"), "--", "--fit-only"])
    assert "--sets CAPTURE:KIND" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "o.jsonl").exists()
    rerun = tmp_path / "rerun.jsonl"
    rerun.write_text(json.dumps({"capture": "t", "kind": "scale_1.1"}) + "\n")
    with pytest.raises(SystemExit):
        si.main(["--summary", str(rerun), "--rows", str(rows)])
    out = capsys.readouterr()
    assert "has no row of t none, t scale_1.1" in out.err.strip().splitlines()[-1] and out.out == ""


def test_focus_dense_subset_plan_is_the_declared_rule():
    """`focus_dense_subset --plan`: the declared strata (every problem set of the universe, seeded samples of right
    ones), never a set the earlier probe ran, never a scene of the next held-out round (3304 on), and the same order
    every time; `moved_d` reads a row's first estimates' distance from its reported focus."""
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes import focus_dense_subset as ds

    order = ds.plan()
    assert order == ds.plan() and len(set(order)) == len(order)
    assert {s: sum(x[0] == s for x in order) for s in ("H0", "A1", "A2", "H1")} == {"H0": 8, "A1": 9, "A2": 20, "H1": 16}
    assert [x[0] for x in order[:17]] == ["H0"] * 8 + ["A1"] * 9
    assert all(int(c[5:]) < 3304 and c in ds.CACHED_SCENES for _, c, _ in order)
    done = {(r["capture"], r["kind"]) for r in ds.read(ds.ROOT / "results" / f for f in ds.DONE_FILES)}
    assert not done & {(c, k) for _, c, k in order}
    rows = ds.stored()
    for s, c, k in order:
        fam, within, claimed = ds.marks(bench.rescored(rows[(c, k)], "code", on_estimates=True))
        assert (s == "A1") == (not fam or claimed)
        assert s != "H1" or (fam and within and k != "none")
        assert s != "H0" or (fam and k == "none")
    cmds = ds.commands(order)  # every set once, in order, with its round's flag and rows
    sets = [x for c in cmds for x in c.split("--sets ")[1].split(",")]
    assert sets == [f"{c}:{k}" for _, c, k in order]
    assert all(("--fresh3 1" in c) == ("scene2038" in c) and ("--fresh11 4" in c) == ("fresh11_fitonly" in c) for c in cmds)
    assert ds.moved_d({"robust": {"moved_d": [0.004, 0.03]}}) == 0.03
    assert ds.moved_d({"robust": {"anchors_d": [[1.0, 2.0]], "reanchored_d": [[1.02, 1.95]]}}) == pytest.approx(0.05)
    assert ds.moved_d({"robust": {"anchors_d": [[1.0, 2.0]]}}) == 0.0


def test_focus_dense_subset_run_skips_only_commands_whose_sets_are_all_in_their_out(tmp_path):
    """`focus_dense_subset.remaining`: a command's --sets not yet in its --out (all of them without an --out file), so
    `--run` waits for the lane's lock only for commands with something left to run."""
    from benchmarks.probes import focus_dense_subset as ds

    out = tmp_path / "o.jsonl"
    argv = ["--mode", "dense", "--out", str(out), "--", "--sets", "s1:none,s1:scale_1.1,s2:quantised"]
    assert ds.remaining(argv) == ["s1:none", "s1:scale_1.1", "s2:quantised"]
    out.write_text(json.dumps({"capture": "s1", "kind": "scale_1.1"}) + "\n" + json.dumps({"capture": "s2", "kind": "none"})
                   + "\n")
    assert ds.remaining(argv) == ["s1:none", "s2:quantised"]
    out.write_text("".join(json.dumps({"capture": c, "kind": k}) + "\n"
                           for c, k in (("s1", "none"), ("s1", "scale_1.1"), ("s2", "quantised"))))
    assert ds.remaining(argv) == []


def test_focus_dense_subset_cutoff_takes_any_hour_and_run_starts_nothing_at_or_after_it(tmp_path, monkeypatch, capsys):
    """`focus_dense_subset.cutoff`: --until is the clock time nearest the run's start (an afternoon cut-off is one; the
    code before took only cut-offs before noon, so a run at 12:45 with --until 12:40 went on); `run` starts no command
    at or after it, and skips commands whose sets are all done."""
    import datetime as dt

    from aat_deploy.diagnose import lookup
    from aat_deploy.infer import model as model_mod
    from benchmarks.probes import focus_dense_subset as ds
    from benchmarks.probes import focus_start_invariance as si

    utc = dt.timezone.utc
    at = lambda d, h, m: dt.datetime(2026, 11, d, h, m, tzinfo=utc)  # noqa: E731
    assert ds.cutoff("12:40", at(28, 11, 30)) == at(28, 12, 40)
    assert ds.cutoff("12:40", at(28, 12, 45)) == at(28, 12, 40)
    assert ds.cutoff("01:14", at(27, 23, 30)) == at(28, 1, 14)
    assert ds.cutoff("10:20", at(28, 10, 25)) == at(28, 10, 20)
    assert ds.cutoff("23:50", at(28, 0, 10)) == at(27, 23, 50)
    for bad in ("24:10", "abc", "1230", "12:3x", "-1:10", "12:60"):
        with pytest.raises(ValueError, match="not HH:MM"):
            ds.cutoff(bad, at(28, 11, 0))
    for name in ("DfFModel",):
        monkeypatch.setattr(model_mod, name, getattr(model_mod, name))
    monkeypatch.setattr(lookup, "find_lens", lookup.find_lens)
    monkeypatch.setattr(lookup, "find_surrogate", lookup.find_surrogate)
    monkeypatch.setattr("os.nice", lambda n: 0)
    ran = []
    monkeypatch.setattr(si, "main", lambda argv: ran.append(argv[-1]))
    out = tmp_path / "o.jsonl"
    out.write_text(json.dumps({"capture": "s1", "kind": "none"}) + "\n")
    cmds = [f"python -m benchmarks.probes.focus_start_invariance --mode m --out {out} -- --sets {s}"
            for s in ("s1:none", "s2:none", "s3:none")]
    clock = iter([at(28, 12, 30), at(28, 12, 35), at(28, 12, 35), at(28, 12, 40), at(28, 12, 40)])
    ds.run(cmds, "12:40", tmp_path / "lock", now=lambda: next(clock))
    assert ran == ["s2:none"]
    assert "stopped before command 3 of 3 at 12:40:00 UTC" in capsys.readouterr().out
    ran.clear()
    ds.run(cmds, "12:40", tmp_path / "lock", now=lambda: at(28, 12, 45))
    assert ran == []


@pytest.mark.parametrize("probe", ["focus_dense_subset", "focus_exposure_subset", "focus_channel_correction"])
def test_subset_probes_refuse_a_bad_until_in_one_line_before_running(probe, tmp_path, monkeypatch, capsys):
    """--until that is not HH:MM is refused by the command line (one line, exit 2), before any lock or command: the
    cut-off was parsed only inside `run`, so `--run --until 9x` ended in a traceback."""
    import importlib

    from benchmarks.probes import focus_dense_subset as ds

    mod = importlib.import_module(f"benchmarks.probes.{probe}")
    monkeypatch.setattr(ds, "run", lambda *a, **k: pytest.fail("ran"))
    for bad in ("9x", "25:00", "1230"):
        with pytest.raises(SystemExit) as e:
            mod.main(["--run", "--until", bad, "--lock", str(tmp_path / "lock")])
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and err[-1].endswith(f"--until {bad}: not HH:MM")
    assert not (tmp_path / "lock").exists()


def test_focus_start_invariance_step_mode_sets_the_sweeps_spacing(tmp_path, monkeypatch):
    """`focus_start_invariance --mode step --step-d 0.03`: the benchmark runs with `fitters.focus_sweep`'s spacing
    0.03 D (its other defaults kept), its own arguments and --out passed through."""
    from aat_deploy.diagnose import fitters
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes import focus_start_invariance as si

    monkeypatch.setattr(fitters.focus_sweep, "__defaults__", fitters.focus_sweep.__defaults__)  # restored after
    seen = {}
    monkeypatch.setattr(bench, "main", lambda: seen.update(defaults=fitters.focus_sweep.__defaults__, argv=list(sys.argv)))
    rows = tmp_path / "r.jsonl"
    rows.write_text(json.dumps({"capture": "s", "kind": "none"}) + "\n")
    assert fitters.focus_sweep.__defaults__[0] == fitters.SWEEP_STEP_D == 0.06
    si.main(["--mode", "step", "--step-d", "0.03", "--rows", str(rows), "--out", str(tmp_path / "o.jsonl"), "--",
             "--fit-only", "--sets", "s:none"])
    assert seen["defaults"] == (0.03, True, False)
    assert seen["argv"][1:] == ["--fit-only", "--sets", "s:none", "--out", str(tmp_path / "o.jsonl")]


def test_focus_misfit_by_frame_splits_each_sets_own_part_by_frame():
    """`focus_misfit_by_frame`: a set's own part is its error less its untouched copy's at the frames both fitted,
    ranked from the nearest fitted frame, with |reported - true| from its kind and its sign towards the reported focus;
    `left_out_at` leaves out the frames at or over a noise share (rows without shares unchanged); `replaced` puts the
    untouched copy's errors on the nearest fitted frame only, or on every other one."""
    from benchmarks.probes import focus_misfit_by_frame as mf

    true = np.array([1.6, 1.2, 0.8, 0.4])

    def row(kind, err, share=None, dom=None):
        est = true + np.nan_to_num(np.asarray(err, np.float64), nan=0.5)
        fams = [{"family": "none", "k": 0, "true_d": [true.tolist()]}, {"family": "per_frame", "k": 4, "true_d": [est.tolist()]}]
        return {"capture": "s", "kind": kind, "family": "none", "families": fams, "frame_err_d": list(err),
                "corrected_err_d": [0.0] * 4, **({"frame_noise_share": share} if share else {}),
                "frames_noise_dominated": dom or [False] * 4}

    nan = float("nan")
    un = row("none", [nan, 0.01, -0.01, 0.0])
    off = row("offset_+0.10", [nan, 0.05, -0.02, 0.01], share=[0.6, 0.35, 0.1, 0.02], dom=[True, False, False, False])
    parts = mf.own_parts([un, off])
    assert [p["rank"] for p in parts] == [0, 1, 2]  # frame 0 fitted in neither: frame 1 is the nearest fitted
    assert [p["own_d"] for p in parts] == pytest.approx([0.04, -0.01, 0.01])
    assert [p["off_d"] for p in parts] == pytest.approx([0.1] * 3)
    assert [p["toward_d"] for p in parts] == pytest.approx([0.04, -0.01, 0.01])  # reported nearer: + is towards it
    assert [p["share"] for p in parts] == [0.35, 0.1, 0.02]
    scale = row("scale_1.1", [nan, -0.03, 0.0, 0.0])  # reported further (fewer diopters): -0.04 D is towards it
    p = mf.own_parts([un, scale])[0]
    assert p["off_d"] == pytest.approx(1.2 - 1.2 / 1.1) and p["toward_d"] == pytest.approx(0.04)
    assert mf.left_out_at(off, 0.3)["frames_noise_dominated"] == [True, True, False, False]
    assert mf.left_out_at(un, 0.3) is un
    near = next(f for f in mf.replaced([un, off], "nearest")[1]["families"] if f["family"] == "per_frame")["true_d"][0]
    rest = next(f for f in mf.replaced([un, off], "rest")[1]["families"] if f["family"] == "per_frame")["true_d"][0]
    assert near == pytest.approx([2.1, 1.21, 0.78, 0.41])
    assert rest == pytest.approx([2.1, 1.25, 0.79, 0.4])


def test_focus_start_invariance_fullwell_mode_fixes_the_focus_twins_full_well(tmp_path, monkeypatch):
    """`focus_start_invariance --mode fullwell --full-well-e 8000`: the benchmark runs with `fitters.full_well_on_floor`
    answering 8000 e- whatever the sweep (the focus twin's ratio then makes its floor 8000 e-'s)."""
    from aat_deploy.diagnose import fitters
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes import focus_start_invariance as si

    monkeypatch.setattr(fitters, "full_well_on_floor", fitters.full_well_on_floor)  # restored after
    seen = {}
    monkeypatch.setattr(bench, "main", lambda: seen.update(fw=fitters.full_well_on_floor(None, 5000.0)))
    rows = tmp_path / "r.jsonl"
    rows.write_text(json.dumps({"capture": "s", "kind": "none"}) + "\n")
    si.main(["--mode", "fullwell", "--full-well-e", "8000", "--rows", str(rows), "--out", str(tmp_path / "o.jsonl"),
             "--", "--fit-only", "--sets", "s:none"])
    assert seen["fw"][0] == 8000.0 and seen["fw"][1] == {"oracle_full_well_e": 8000.0}


def test_focus_ptc_subset_plan_is_the_declared_rule():
    """`focus_ptc_subset --plan`: dense anchoring's declared 53 (H0, A1 first), the 28 its probe ran (P) after A1,
    then A2 and H1 in dense anchoring's order, then U, every other untouched copy of the 25 scenes: 98 sets, none twice,
    none of a scene of 3304 on; every command reruns with `--mode ptc` into results/focus_ptc_subset.jsonl."""
    from benchmarks.probes import focus_dense_subset as ds
    from benchmarks.probes import focus_ptc_subset as ps

    order = ps.plan()
    assert order == ps.plan() and len({(c, k) for _, c, k in order}) == len(order) == 98
    assert {s: sum(x[0] == s for x in order) for s in ("H0", "A1", "P", "A2", "H1", "U")} == \
        {"H0": 8, "A1": 9, "P": 28, "A2": 20, "H1": 16, "U": 17}
    assert [x[0] for x in order[:45]] == ["H0"] * 8 + ["A1"] * 9 + ["P"] * 28
    assert [x for x in order if x[0] in ("A2", "H1")] == [x for x in ds.plan() if x[0] in ("A2", "H1")]
    assert all(k == "none" for s, _, k in order if s == "U")
    assert {c for s, c, k in order if k == "none"} == set(ds.CACHED_SCENES)  # every untouched copy of the universe
    assert all(int(c[5:]) < 3304 for _, c, _ in order)
    cmds = ds.commands(order, mode="ptc", out_file=ps.OUT)
    assert [x for c in cmds for x in c.split("--sets ")[1].split(",")] == [f"{c}:{k}" for _, c, k in order]
    assert all("--mode ptc " in c and "--out results/focus_ptc_subset.jsonl " in c for c in cmds)


def test_focus_start_invariance_ptc_mode_measures_the_full_well(tmp_path, monkeypatch):
    """`focus_start_invariance --mode ptc`: the benchmark runs with `fitters.FULL_WELL_BY_PHOTON_TRANSFER` on."""
    from aat_deploy.diagnose import fitters
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes import focus_start_invariance as si

    monkeypatch.setattr(fitters, "FULL_WELL_BY_PHOTON_TRANSFER", False)  # restored after
    seen = {}
    monkeypatch.setattr(bench, "main", lambda: seen.update(on=fitters.FULL_WELL_BY_PHOTON_TRANSFER))
    rows = tmp_path / "r.jsonl"
    rows.write_text(json.dumps({"capture": "s", "kind": "none"}) + "\n")
    si.main(["--mode", "ptc", "--rows", str(rows), "--out", str(tmp_path / "o.jsonl"), "--", "--fit-only", "--sets",
             "s:none"])
    assert seen == {"on": True}


def test_photon_transfer_check_reads_a_folders_full_well(tmp_path):
    """`photon_transfer_check --captures`: a folder of two DNG frames of flat patches rendered at 5000 e- reads within
    5 % of it, pooled and frame by frame; a folder without frames is refused."""
    from aat_deploy.render.effects.noise import poisson_gaussian
    from benchmarks.probes import photon_transfer_check as pc
    from tests.deploy.diagnose.test_photon import patches, write_frames

    rng = np.random.default_rng(11)
    lin = np.stack([np.stack([patches(rng.uniform(0.1, 0.8, (10, 15)))] * 3) for _ in range(2)])
    write_frames(tmp_path / "cap", np.stack([poisson_gaussian(f, 5000.0, 3.0, rng) for f in lin]))
    row = pc.capture_rows(tmp_path / "cap")[0].split("|")
    assert float(row[2]) == pytest.approx(5000.0, rel=0.05)
    assert all(float(x) == pytest.approx(5000.0, rel=0.08) for x in row[5].split(","))
    with pytest.raises(SystemExit):
        pc.main(["--captures", str(tmp_path)])


def test_focus_start_invariance_ptc_exposure_mode_measures_the_full_well_and_puts_the_floor_at_the_exposure(
        tmp_path, monkeypatch):
    """`focus_start_invariance --mode ptc_exposure`: the benchmark runs with `fitters.FULL_WELL_BY_PHOTON_TRANSFER`
    and `fitters.FLOOR_AT_CAPTURE_EXPOSURE` both on (the declared change of `focus_exposure_subset`)."""
    from aat_deploy.diagnose import fitters
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes import focus_start_invariance as si

    monkeypatch.setattr(fitters, "FULL_WELL_BY_PHOTON_TRANSFER", False)  # restored after
    monkeypatch.setattr(fitters, "FLOOR_AT_CAPTURE_EXPOSURE", False)
    seen = {}
    monkeypatch.setattr(bench, "main", lambda: seen.update(ptc=fitters.FULL_WELL_BY_PHOTON_TRANSFER,
                                                           exposure=fitters.FLOOR_AT_CAPTURE_EXPOSURE))
    rows = tmp_path / "r.jsonl"
    rows.write_text(json.dumps({"capture": "s", "kind": "none"}) + "\n")
    si.main(["--mode", "ptc_exposure", "--rows", str(rows), "--out", str(tmp_path / "o.jsonl"), "--", "--fit-only",
             "--sets", "s:none"])
    assert seen == {"ptc": True, "exposure": True}


@pytest.mark.parametrize("mode, want", [("code", (False, False, False)), ("channel", (False, False, True)),
                                        ("ptc_exposure_channel", (True, True, True)),
                                        ("ptc_exposure", (True, True, False))])
def test_focus_start_invariance_code_and_channel_modes_set_only_their_switches(tmp_path, monkeypatch, mode, want):
    """`--mode code` runs the code unchanged (the same machine's baseline), `channel` with the binning correction
    each channel's own (`anchors.PER_CHANNEL`), `ptc_exposure_channel` with both that and `ptc_exposure`'s switches."""
    from aat_deploy.diagnose import anchors, fitters
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes import focus_start_invariance as si

    for mod, name in ((fitters, "FULL_WELL_BY_PHOTON_TRANSFER"), (fitters, "FLOOR_AT_CAPTURE_EXPOSURE"),
                      (anchors, "PER_CHANNEL")):
        monkeypatch.setattr(mod, name, False)  # restored after
    seen = []
    monkeypatch.setattr(bench, "main", lambda: seen.append((fitters.FULL_WELL_BY_PHOTON_TRANSFER,
                                                            fitters.FLOOR_AT_CAPTURE_EXPOSURE, anchors.PER_CHANNEL)))
    rows = tmp_path / "r.jsonl"
    rows.write_text(json.dumps({"capture": "s", "kind": "none"}) + "\n")
    for m in ("ptc_exposure_channel", mode):  # one after another in one process (`focus_dense_subset.run`)
        si.main(["--mode", m, "--rows", str(rows), "--out", str(tmp_path / "o.jsonl"), "--", "--fit-only",
                 "--sets", "s:none"])
    assert seen == [(True, True, True), want]  # the second mode does not inherit the first's switches


def test_focus_exposure_subset_plan_is_the_ptc_subsets_sets_rerun_with_the_declared_change(capsys):
    """`focus_exposure_subset --plan`: the same 98 sets in the same order as `focus_ptc_subset`, every command with
    `--mode ptc_exposure` into results/focus_exposure_subset.jsonl; without --plan, --run or --tally it refuses."""
    from benchmarks.probes import focus_dense_subset as ds
    from benchmarks.probes import focus_exposure_subset as es
    from benchmarks.probes import focus_ptc_subset as ps

    es.main(["--plan"])
    out = capsys.readouterr().out
    cmds = [c for c in out.splitlines() if c.startswith("OMP_NUM_THREADS")]
    order = ps.plan()
    assert cmds == ds.commands(order, mode="ptc_exposure", out_file=es.OUT)
    assert [x for c in cmds for x in c.split("--sets ")[1].split(",")] == [f"{c}:{k}" for _, c, k in order]
    assert all("--mode ptc_exposure " in c and "--out results/focus_exposure_subset.jsonl " in c for c in cmds)
    with pytest.raises(SystemExit):
        es.main([])


def test_focus_exposure_subset_check_reruns_two_stored_sets_and_reproduces_only_within_the_tolerance(capsys):
    """`focus_exposure_subset --check`: the reproducibility check's sets (one of each of the two rounds the untouched
    copies still to run need, both already scored) rerun into REPRO_OUT; `compare` says a set reproduces only with the
    same family and frames left out and every frame's estimate within TOL_D (0.002 D), and a set not rerun does not."""
    from benchmarks.probes import focus_dense_subset as ds
    from benchmarks.probes import focus_exposure_subset as es

    es.main(["--check", "--plan"])
    cmds = [c for c in capsys.readouterr().out.splitlines() if c.startswith("OMP_NUM_THREADS")]
    assert sorted(x for c in cmds for x in c.split("--sets ")[1].split(",")) == sorted(f"{c}:{k}" for c, k in es.REPRO_SETS)
    assert all("--mode ptc_exposure " in c and f"--out {es.REPRO_OUT} " in c for c in cmds)
    stored = [r for r in ds.read([ds.ROOT / es.OUT]) if (r["capture"], r["kind"]) in es.REPRO_SETS]
    assert len(stored) == 2 and {r["capture"] for r in stored} == {"scene3045", "scene3251"}
    assert "reproduced: 2 of 2" in es.compare(stored, stored)
    assert "reproduced: 1 of 2" in es.compare(stored[:1], stored)
    moved = [json.loads(json.dumps(r)) for r in stored]
    i = int(np.flatnonzero(np.isfinite(np.asarray(moved[0]["frame_err_d"], np.float64)))[-1])
    moved[0]["frame_err_d"][i] += 0.0019
    assert "reproduced: 2 of 2" in es.compare(moved, stored)
    moved[0]["frame_err_d"][i] += 0.0002
    assert "reproduced: 1 of 2" in es.compare(moved, stored)
    other = [json.loads(json.dumps(r)) for r in stored]
    other[1]["family"] = "none"
    assert "reproduced: 1 of 2" in es.compare(other, stored)
    left = [json.loads(json.dumps(r)) for r in stored]
    j = int(np.flatnonzero(np.isfinite(np.asarray(left[1]["frame_err_d"], np.float64)))[0])
    left[1]["frame_err_d"][j] = float("nan")
    assert "reproduced: 1 of 2" in es.compare(left, stored)


def test_focus_channel_correction_pairs_the_code_and_the_change_on_the_same_sets():
    """`focus_channel_correction`: every stored set of its three development scenes (none of 3304 on), the base's and
    the change's command of each group one after the other, into their own files; the tally pairs the two by set and
    counts a set better only where the change gains (family, within 0.02 D) and loses nothing."""
    from benchmarks.probes import focus_channel_correction as cc

    order = cc.plan()
    assert len(order) == 36 and {c for _, c, _ in order} == set(cc.SCENES)
    assert all(int(c[5:]) < 3304 for _, c, _ in order)
    for exposure, (m0, m1) in cc.PAIRS.items():
        cmds = cc.commands(exposure)
        assert all(f"--mode {m0} " in c and f"--out {cc.out_file(m0)} " in c for c in cmds[::2])
        assert all(f"--mode {m1} " in c and f"--out {cc.out_file(m1)} " in c for c in cmds[1::2])
        assert [c.split("--sets ")[1] for c in cmds[::2]] == [c.split("--sets ")[1] for c in cmds[1::2]]

    def row(kind, fam, err):
        return {"capture": "scene3303", "kind": kind, "family": fam, "family_ok": fam == {"none": "none"}.get(kind, "scale"),
                "frames_undetermined": 0, "corrected_max_err_d": err, "frame_err_d": [err, float("nan")], "seconds": 30}

    base = [row("scale_1.1", "offset", 0.03), row("scale_0.9", "scale", 0.01), row("none", "none", 0.0)]
    var = [row("scale_1.1", "scale", 0.01), row("scale_0.9", "scale", 0.025), row("none", "none", 0.0)]
    text = cc.tally(base, var, ("code", "channel"))
    assert "3 sets (2 with an error): family right 2 -> 3, within 0.02 D with every frame determined 1 -> 1 of 2" in text
    assert "sets better 1, worse 1" in text and "not run (both): 33 of 36" in text
    with pytest.raises(SystemExit):
        cc.main(["--modes", "code", "dense"])  # only the probe's four modes
    with pytest.raises(SystemExit):
        cc.main(["--tally", "results/focus_exposure_subset.jsonl"])  # refused, not ignored


def test_focus_weak_noiseless_reads_a_residual_along_the_twins_slope():
    """`focus_weak_noiseless`: levels profiled per region; a residual that is the slope times a shift in one frame
    reads as that shift there and 0 elsewhere; regions not used count nothing."""
    from benchmarks.probes import focus_weak_noiseless as fw

    r = np.array([[1.0, 2.0, 3.0], [5.0, 5.0, 5.0]])
    assert np.allclose(fw.profiled(r), [[-1.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    slope = np.array([[2.0, -1.0, 3.0], [1.0, 4.0, -2.0], [9.0, 9.0, 9.0]])
    res = np.zeros((3, 3))
    res[:, 1] = slope[:, 1] * 0.02
    res[2] = 5.0  # a region left out
    used = np.array([True, True, False])
    assert np.allclose(fw.focus_reading(res, slope, used), [0.0, 0.02, 0.0])


def test_focus_weak_noiseless_energy_is_the_region_mean_of_the_squared_laplacian_and_its_cross_term():
    """`focus_weak_noiseless.lap_energy`: per region, frame and channel, the mean of lap(a)^2, and with a second stack
    of 2 lap(a) lap(b), so that E(a + b) = E(a) + E(b) + X(a, b) (the split the probe reads the noise term by)."""
    from benchmarks.probes import focus_weak_noiseless as fw

    rng = np.random.default_rng(5)
    a, b = rng.random((2, 3, 24, 36)), rng.normal(0, 0.2, (2, 3, 24, 36))
    grid = (2, 3)
    e = fw.lap_energy(a, grid)
    assert e.shape == (6, 2, 3)
    # OpenCV's 3 x 3 Laplacian (ksize 3: 2 (sum of the 4 corners - 4 centre)), by hand, reflected at the border
    x = np.pad(a[1, 2], 1, mode="reflect")
    lap = 2 * (x[:-2, :-2] + x[:-2, 2:] + x[2:, :-2] + x[2:, 2:] - 4 * x[1:-1, 1:-1])
    assert e[5, 1, 2] == pytest.approx(np.mean(lap[12:, 24:] ** 2), rel=1e-5)
    assert np.allclose(fw.lap_energy(a + b, grid), e + fw.lap_energy(b, grid) + fw.lap_energy(a, grid, b), rtol=1e-4)
