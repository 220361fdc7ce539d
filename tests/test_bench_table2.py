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


def test_a_label_two_models_share_names_the_family_and_keeps_the_twin(bench):
    # the current RF50 DFVNets and the first ones have the same metadata labels: before, the later row replaced the
    # earlier one in the results (the paper-protocol run of 2026-11-26 scored dff_dfvnet_* as "AAT DFVNet")
    taken = {"AAT DFVNet": {}, "Baseline DFVNet": {}}
    aat = bench.unique_label("AAT DFVNet", Path("models/reproduce/dff_dfvnet_aat.onnx"), taken)
    thin = bench.unique_label("Baseline DFVNet", Path("models/reproduce/dff_dfvnet_thin.onnx"), taken)
    assert (aat, thin) == ("AAT DFVNet (dff_dfvnet)", "Baseline DFVNet (dff_dfvnet)")
    assert "Baseline " + aat[4:] == thin  # main's twin rule pairs them
    assert bench.unique_label("AAT AiFNet", Path("rf50_aifnet_aat.onnx"), taken) == "AAT AiFNet"  # unique: unchanged
    taken[aat] = {}
    assert bench.unique_label("AAT DFVNet", Path("x/dff_dfvnet_aat.onnx"), taken) == "AAT DFVNet (dff_dfvnet_aat)"
