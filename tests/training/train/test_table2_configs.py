"""The Table 2 configs (configs/table2/): every one loads, and each AAT config's thin-lens twin is identical but for
the simulator (and its name, comment and starting weights), as the paper's comparison requires."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from training.train.config import load_config

ROOT = Path(__file__).resolve().parents[3]
CONFIGS = sorted((ROOT / "configs/table2").glob("*.json"))
PAIRS = [(p, p.with_name(p.name.replace("_aat", "_thin"))) for p in CONFIGS
         if "_aat" in p.stem and p.with_name(p.name.replace("_aat", "_thin")).exists()]


@pytest.mark.parametrize("path", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_loads_and_is_named_after_its_file(path):
    cfg = load_config(path)
    assert cfg.name == path.stem


@pytest.mark.parametrize("aat,thin", PAIRS, ids=[a.stem for a, _ in PAIRS])
def test_twins_differ_only_in_the_simulator(aat, thin):
    a, t = json.loads(aat.read_text()), json.loads(thin.read_text())
    assert (a["simulator"], t["simulator"]) == ("aat", "thin_lens")
    if "init" in a or "init" in t:  # a fine-tune starts each twin from its own twin's trained weights
        assert t["init"] == a["init"].replace("_aat", "_thin") != a["init"]
    for d in (a, t):
        for k in ("simulator", "name", "comment", "init"):
            d.pop(k, None)
    assert a == t


def test_pairs_found():
    assert len(PAIRS) >= 5  # paper50 + rf50, both nets, and the AiF fine-tune
