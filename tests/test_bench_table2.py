"""bench_table2: labels, and the statistics it uses are the project's (tests/deploy/eval/test_stats.py)."""

from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def bench():
    from benchmarks import bench_table2

    return bench_table2


def test_the_statistics_are_the_projects(bench):
    # the names scripts of work in progress import from here are aat_deploy.eval.stats's, not copies (tested there)
    from aat_deploy.eval import score, stats

    assert bench.paired_ratio is stats.paired_ratio and bench.paired_diff is stats.paired_diff
    assert bench.summarise is stats.summarise and bench.fmt is stats.fmt_interval and bench.N_BOOT == stats.N_BOOT
    assert bench.score is score.scene_scores


def test_labels(bench):
    meta = {"aat.net": "aifnet", "aat.simulator": "aat", "aat.config_name": "paper50_aifnet_aat_aif"}
    assert bench.label_of(meta, Path("x.onnx")) == "AAT AiFNet + AiF loss"
    meta = {"aat.net": "dfvnet", "aat.simulator": "thin_lens", "aat.field_channels": "0"}
    assert bench.label_of(meta, Path("x.onnx")) == "Baseline DFVNet"
