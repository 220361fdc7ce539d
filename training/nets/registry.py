"""The DfF nets by name: what builds each, its sizes, its input channels, the loss weights of its output levels,
its display label and the short names commands accept. A new net is one entry in NETS (and its module).

Read by `training.nets.model.build_model`, the training config (`training.train.config`), the lens-to-model chain
(`training.chain`: `--net` aliases, the loss level weights it trains with), the held-out tables' labels
(`training.train.heldout`) and `aat-train --net`'s choices. Importing this module imports no torch; a builder
imports its net when called.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from aat_deploy.errors import AatError


class UnknownNet(AatError):
    """A net name (or size, or field-channel count) no entry has."""


def _aifnet(size: str, in_channels: int):
    from training.nets.aifnet import AIFNET_CONFIGS, AiFNet

    return AiFNet(AIFNET_CONFIGS[size], in_channels)


def _dfvnet(size: str, in_channels: int):
    from training.nets.dfvnet import DFVNET_CONFIGS, DFVNet

    return DFVNet(DFVNET_CONFIGS[size], in_channels=in_channels)


def _dfvaat(size: str, in_channels: int):
    from training.nets.dfvaat import build

    return build(size)


@dataclass(frozen=True)
class NetSpec:
    """One net. builder(size, in_channels) -> the net: a backbone returning focus logits per level (wrapped with
    the focus-distance head by `build_model`), or with `focus_maps` the whole model, which takes per-pixel focus
    maps instead of focus distances (the any-camera net, trained on its own data: simulator "any_camera").
    field_channels: extra input channels per frame it can take (2: the pixel's normalised sensor position).
    level_weights: loss weight per output level, finest first, that `aat-train --lens` trains it with (configs
    give their own). chain: offered by `aat-train --lens`."""

    name: str  # in configs, checkpoints and the ONNX metadata (aat.net)
    label: str  # in tables and reports
    builder: Callable
    sizes: tuple[str, ...] = ("small", "full")
    field_channels: tuple[int, ...] = (0, 2)
    level_weights: tuple[float, ...] = (1.0,)
    aliases: tuple[str, ...] = ()
    focus_maps: bool = False
    chain: bool = True

    def check(self, size: str, field_channels: int = 0) -> None:
        if size not in self.sizes:
            raise UnknownNet(f"unknown size {size!r} for {self.name}; expected one of {self.sizes}")
        if field_channels not in self.field_channels:
            raise UnknownNet(f"{self.name}: field_channels must be one of {self.field_channels}, got "
                             f"{field_channels!r}")


NETS: dict[str, NetSpec] = {s.name: s for s in (
    NetSpec("aifnet", "AiFNet", _aifnet, level_weights=(1.0,), aliases=("aif",)),
    NetSpec("dfvnet", "DFVNet", _dfvnet, level_weights=(8.0, 4.0), aliases=("dfv",)),
    NetSpec("dfvaat", "DFVNet with focus maps", _dfvaat, sizes=("small", "small_replicate", "small_x", "small_replicate_x",
                                                                    "small_xb", "small_replicate_xb",
                                                                    "small_xbk", "small_replicate_xbk"),
            field_channels=(0,),
            level_weights=(8.0, 4.0), focus_maps=True, chain=False),
)}


def aliases(chain_only: bool = False) -> dict[str, str]:
    """{name or alias: name} of every net (or of those `aat-train --lens` offers)."""
    return {a: s.name for s in NETS.values() if s.chain or not chain_only for a in (s.name, *s.aliases)}


def get(name: str) -> NetSpec:
    """The entry of a net by name or alias; UnknownNet naming the choices."""
    key = aliases().get(name)
    if key is None:
        raise UnknownNet(f"unknown net {name!r}; expected one of {tuple(NETS)}")
    return NETS[key]
