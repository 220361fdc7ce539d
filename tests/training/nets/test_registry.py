"""The nets' registry (training.nets.registry): every entry builds what it says, the any-camera net is an entry
without changing what it builds, and a new net is one entry that the builder, the training config and the tables'
labels pick up."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch

from training.chain.config import NET_ALIASES
from training.nets import registry
from training.nets.aifnet import AIFNET_CONFIGS
from training.nets.blocks import count_params
from training.nets.dfvaat import SIZES as DFVAAT_SIZES
from training.nets.dfvaat import FocusMapDfF, build
from training.nets.dfvnet import DFVNET_CONFIGS, DFVNet
from training.nets.model import DfFNet, build_model
from training.train.config import ConfigError, TrainConfig
from training.train.heldout import model_label


def test_entries_build_in_their_sizes():
    configs = {"aifnet": AIFNET_CONFIGS, "dfvnet": DFVNET_CONFIGS, "dfvaat": DFVAAT_SIZES}
    for name, spec in registry.NETS.items():
        assert set(spec.sizes) == set(configs[name]), name  # the sizes its module configures
        m = build_model(name, "small")
        assert m.name == name and m.size == "small"
        assert isinstance(m, FocusMapDfF if spec.focus_maps else DfFNet)
    with pytest.raises(ValueError, match="unknown size"):
        build_model("dfvaat", "full")
    with pytest.raises(ValueError, match="field_channels"):
        build_model("dfvaat", "small", field_channels=2)


def test_the_any_camera_net_is_what_it_was():
    torch.manual_seed(0)
    a = build_model("dfvaat", "small")
    torch.manual_seed(0)
    b = build("small")
    sa, sb = a.state_dict(), b.state_dict()
    assert list(sa) == list(sb) and all(torch.equal(sa[k], sb[k]) for k in sa)
    assert count_params(a) == count_params(b)


def test_aliases_and_what_the_chain_offers():
    assert registry.get("dfv").name == "dfvnet" and registry.get("aif").name == "aifnet"
    assert NET_ALIASES == {"aifnet": "aifnet", "aif": "aifnet", "dfvnet": "dfvnet", "dfv": "dfvnet"}
    assert "dfvaat" in registry.aliases() and "dfvaat" not in NET_ALIASES  # trained on its own data, not by --lens
    with pytest.raises(ValueError, match="unknown net"):
        registry.get("resnet")


def _config(net: str, simulator: str = "aat", size: str = "small") -> TrainConfig:
    return TrainConfig(name="t", net=net, size=size, simulator=simulator, lens="lenses/canon_rf50mm_f1.8.json")


def test_training_config_asks_the_registry():
    _config("dfvnet").validate()
    _config("dfvaat", "any_camera").validate()
    with pytest.raises(ConfigError, match="any_camera"):
        _config("dfvaat", "aat").validate()
    with pytest.raises(ConfigError, match="any_camera"):
        _config("aifnet", "any_camera").validate()
    with pytest.raises(ConfigError, match="size"):
        _config("dfvaat", "any_camera", "full").validate()


def test_a_new_net_is_one_entry(monkeypatch):
    def tiny(size, in_channels):
        return DFVNet(dataclasses.replace(DFVNET_CONFIGS["small"], context_fuse=8), in_channels=in_channels)

    spec = registry.NetSpec("tinynet", "TinyNet", tiny, sizes=("small",), level_weights=(2.0, 1.0), aliases=("tiny",))
    monkeypatch.setitem(registry.NETS, "tinynet", spec)
    m = build_model("tiny", "small", field_channels=2)
    assert isinstance(m, DfFNet) and m.name == "tinynet" and m.field_channels == 2
    _config("tinynet").validate()
    assert model_label({"aat.net": "tinynet", "aat.simulator": "aat"}, Path("x_tiny.onnx")) == "AAT TinyNet"
