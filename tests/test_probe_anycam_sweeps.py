"""benchmarks/probes/anycam_sweeps.py --test-only: one lens's test rows recomputed into the results file, the rest
of it kept (the Z35's row after its lens file was corrected)."""

import json

import numpy as np
import pytest

from benchmarks.probes import anycam_sweeps


def test_test_only_replaces_one_lens_rows_and_keeps_the_rest(tmp_path):
    out = tmp_path / "sweeps.json"
    other = {"span_px": {"n": 1, "p50": 54.2}, "step_px": {"n": 1, "p50": 6.0}, "frames": 10}
    stale = {"span_px": {"n": 1, "p50": 5.78}, "step_px": {"n": 1, "p50": 0.83}, "frames": 8}
    before = {"summary": {"training": {"dfv_aat": {"all": {"x": 1}}},
                          "test": {"paper50 fixed": other, "z35 fixed": stale, "z35 paper": stale,
                                   "rf50 fixed": other}, "window_coverage": {"y": 2}}, "configs": ["c.json"]}
    out.write_text(json.dumps(before))
    assert anycam_sweeps.main(["--test-only", "z35", "--cache", str(tmp_path / "empty_cache"), "--out", str(out)]) == 0
    after = json.loads(out.read_text())
    s = after["summary"]
    assert s["training"] == before["summary"]["training"] and s["window_coverage"] == {"y": 2}
    assert after["configs"] == ["c.json"]
    # the other lenses' rows untouched and in place; the Z35's paper row dropped (its set is not cached here)
    assert list(s["test"]) == ["paper50 fixed", "z35 fixed", "rf50 fixed"]
    assert s["test"]["paper50 fixed"] == other == s["test"]["rf50 fixed"]
    # the Z35 (EFL 1.572 mm, F/1.77, 1.657 um pixels) over 0.2-3 m: a hand thin lens, distances from the lens
    # (the probe's are from the sensor: 0.2 % apart here), focused at the sweep's geometric mean
    efl_mm, epd_mm, pixel_mm, focus_m = 1.5720, 0.88962, 1.65717e-3, np.sqrt(0.2 * 3.0)
    v_mm = 1.0 / (1.0 / efl_mm - 1.0 / (1000 * focus_m))
    hand = epd_mm * v_mm / 1000.0 / pixel_mm * (1 / 0.2 - 1 / 3.0)
    row = s["test"]["z35 fixed"]
    assert row["frames"] == 8 and row["span_px"]["n"] == 1
    assert abs(row["span_px"]["p50"] - hand) < 0.01 * hand, (row["span_px"]["p50"], hand)
    assert abs(row["step_px"]["p50"] - row["span_px"]["p50"] / 7) < 1e-9


def test_figure_only_draws_the_files_test_rows_and_checks_its_training_rows(tmp_path, monkeypatch):
    """--figure-only: the figure from the results file's test rows (as --test-only left them) and the configs'
    training sweeps drawn again, nothing else written; training sweeps that no longer reproduce the file's are
    refused (the histogram would not be the file's)."""
    rows = [{"span_px": float(v)} for v in np.geomspace(2, 90, 50)]
    monkeypatch.setattr(anycam_sweeps, "training_sweeps", lambda config: rows)
    drawn = []
    figure = anycam_sweeps.figure
    monkeypatch.setattr(anycam_sweeps, "figure", lambda *a: drawn.extend(figure(*a)))
    fixed = {"span_px": {"n": 1, "p5": 3.96, "p50": 3.96, "p95": 3.96}, "frames": 8}
    paper = {"span_px": {"n": 24, "p5": 0.65, "p50": 2.52, "p95": 3.39}, "frames": 8}
    results = {"summary": {"training": {"cfg": {"all": {"span_px": anycam_sweeps.stats([r["span_px"] for r in rows])}}},
                           "test": {"z35 fixed": fixed, "z35 paper": paper}}, "configs": ["cfg.json"]}
    out, png = tmp_path / "sweeps.json", tmp_path / "sweeps.png"
    out.write_text(json.dumps(results))
    before = out.read_text()
    argv = ["--figure-only", "--configs", str(tmp_path / "cfg.json"), "--out", str(out), "--figure", str(png)]
    assert anycam_sweeps.main(argv) == 0
    assert png.is_file() and out.read_text() == before
    assert drawn == [("z35 fixed", 3.96), ("z35 paper", 2.52)]
    results["summary"]["training"]["cfg"]["all"]["span_px"]["p50"] += 0.01
    out.write_text(json.dumps(results))
    with pytest.raises(SystemExit, match="differ"):
        anycam_sweeps.main(argv)
    with pytest.raises(SystemExit, match="no training rows of other"):
        anycam_sweeps.main([*argv[:2], str(tmp_path / "other.json"), *argv[3:]])
