"""bench_anycam_rgbd's summary over a handful of real scenes, checked by hand."""

from __future__ import annotations

import math

import pytest

from benchmarks.bench_anycam_rgbd import CL_MAP, SCENES, geomean_interval, scene_rows


def test_geomean_of_equal_ratios_has_no_spread():
    assert geomean_interval([0.8] * 4) == pytest.approx((0.8, 0.8, 0.8))


def test_geomean_interval_of_two_scenes_by_hand():
    # logs -a and +a; the 4 resamples' means are -a, 0, 0, a: the 2.5th percentile lies 0.075 of the way from -a to 0
    a = math.log(2)
    gm, lo, hi = geomean_interval([0.5, 2.0])
    assert gm == pytest.approx(1.0)
    assert lo == pytest.approx(math.exp(-0.925 * a)) and hi == pytest.approx(math.exp(0.925 * a))


def test_scene_rows_divide_each_scene_by_the_classical_method():
    maes = dict(zip(SCENES, (0.2, 0.05, 0.1, 0.04)))
    res = {"net": {s: [{"mae": 0.5 * m}] for s, m in maes.items()},
           CL_MAP: {s: [{"mae": m}] for s, m in maes.items()}}
    res["net"]["aloe"] = [{"mae": 0.1}]  # one scene no better
    (row,) = scene_rows(res, ["net"])
    assert row["per_scene"] == pytest.approx({"middlebury": 0.5, "nyu": 0.5, "aloe": 1.0, "arc2017": 0.5})
    assert row["at_most_0.7"] == 3
    assert row["geomean"][0] == pytest.approx(0.5 ** 0.75)
