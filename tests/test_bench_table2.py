"""bench_table2's interval arithmetic against hand-computed cases."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_table2", ROOT / "benchmarks/bench_table2.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_paired_ratio_of_proportional_scenes_has_no_spread(bench):
    a = [{"mae": v} for v in (1.0, 2.0, 3.0, 4.0)]
    b = [{"mae": 2 * v} for v in (1.0, 2.0, 3.0, 4.0)]
    est, lo, hi = bench.paired_ratio(a, b)
    # every resample keeps the pairs, so every resampled ratio is exactly 0.5
    assert est == pytest.approx(0.5) and lo == pytest.approx(0.5) and hi == pytest.approx(0.5)


def test_paired_ratio_is_ratio_of_means_not_mean_of_ratios(bench):
    a = [{"mae": 1.0}, {"mae": 1.0}]
    b = [{"mae": 1.0}, {"mae": 3.0}]
    est, lo, hi = bench.paired_ratio(a, b)
    assert est == pytest.approx(2.0 / 4.0)  # mean of ratios would be 2/3
    assert lo == pytest.approx(1 / 3) and hi == pytest.approx(1.0)  # the extremes: both scenes drawn the same


def test_one_scene_has_no_interval(bench):
    est, lo, hi = bench.paired_ratio([{"mae": 1.0}], [{"mae": 4.0}])
    assert est == 0.25 and np.isnan(lo) and np.isnan(hi)


def test_summarise_ignores_missing_aif_and_brackets_the_mean(bench):
    keys = bench.KEYS
    per = [{k: float(i) for k in keys} for i in range(1, 6)]
    for s in per:
        s["psnr"] = float("nan")
    out = bench.summarise(per)
    m, lo, hi = out["mae"]
    assert m == pytest.approx(3.0) and 1.0 <= lo < m < hi <= 5.0
    assert all(np.isnan(out["psnr"]))


def test_paired_diff_of_a_constant_offset_has_no_spread(bench):
    a = [{"psnr": v + 0.5} for v in (20.0, 25.0, 30.0)]
    b = [{"psnr": v} for v in (20.0, 25.0, 30.0)]
    assert bench.paired_diff(a, b) == pytest.approx([0.5, 0.5, 0.5])


def test_paired_diff_skips_scenes_without_aif_and_brackets_the_mean(bench):
    a = [{"psnr": x} for x in (21.0, 22.0, float("nan"), 30.0)]
    b = [{"psnr": x} for x in (20.0, 20.0, 25.0, 27.0)]
    est, lo, hi = bench.paired_diff(a, b)  # differences 1, 2, 3 (the NaN scene left out)
    assert est == pytest.approx(2.0) and 1.0 <= lo < est < hi <= 3.0
    assert np.isnan(bench.paired_diff(a[:1], b[:1])[1])  # one scene: no interval


def test_labels(bench):
    meta = {"aat.net": "aifnet", "aat.simulator": "aat", "aat.config_name": "paper50_aifnet_aat_aif"}
    assert bench.label_of(meta, Path("x.onnx")) == "AAT AiFNet + AiF loss"
    meta = {"aat.net": "dfvnet", "aat.simulator": "thin_lens", "aat.field_channels": "0"}
    assert bench.label_of(meta, Path("x.onnx")) == "Baseline DFVNet"
