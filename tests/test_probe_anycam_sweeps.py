"""benchmarks/probes/anycam_sweeps.py --test-only: one lens's test rows recomputed into the results file, the rest
of it kept (the Z35's row after its lens file was corrected)."""

import json

import numpy as np

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
