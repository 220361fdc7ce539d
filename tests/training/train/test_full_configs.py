"""The full-size nets as training configurations (configs/full/, for GPUs; not trained here): they load, build
the published widths with the parameter counts their comments state, and read the same data (cache) as the
small Table 2 configs next to them."""

from __future__ import annotations

import json
import re
from pathlib import Path

from training.nets.model import build_model
from training.train.config import load_config

ROOT = Path(__file__).resolve().parents[3]


def test_full_size_configs_state_their_parameter_counts_and_share_the_small_configs_data():
    paths = sorted((ROOT / "configs" / "full").glob("*.json"))
    assert [p.name for p in paths] == ["rf50_aifnet_aat.json", "rf50_aifnet_thin.json", "rf50_dfvnet_aat.json",
                                       "rf50_dfvnet_thin.json"]
    for p in paths:
        cfg = load_config(p)
        assert cfg.size == "full"
        n = build_model(cfg.net, cfg.size, cfg.field_channels).n_params
        stated = int(re.search(r"([\d,]+) parameters", json.loads(p.read_text())["comment"])[1].replace(",", ""))
        assert stated == n, p
        small = load_config(ROOT / "configs" / "table2" / p.name)
        assert small.size == "small" and n > 15 * build_model(cfg.net, "small").n_params
        assert cfg.data == small.data and cfg.val_data == small.val_data and cfg.simulator == small.simulator
