"""The one place the loop meets `training.data.stacks`: build a FocalStackDataset from a config's `data` dict.

Interface the loop relies on (training/data/stacks.py): each item is a dict with "stack" float32 (S, 3, H, W)
normalised per docs/contracts.md, "focus_m" (S,) ascending, "depth_m" (H, W) metres (0 = invalid) and
"aif" (3, H, W) normalised like the stack. The dataset's config dataclass receives the `data` dict plus
`simulator` ("aat" | "thin_lens"), and `lens` / `effects` when it has such fields.
"""

from __future__ import annotations

import dataclasses
import inspect
import typing
from pathlib import Path

from torch.utils.data import Dataset

ROOT = Path(__file__).resolve().parents[2]


def _config_class(dataset_cls) -> type:
    """The dataclass FocalStackDataset is built from (its `config_class` attribute or its first __init__ arg's type)."""
    cls = getattr(dataset_cls, "config_class", None)
    if cls is not None:
        return cls
    hints = typing.get_type_hints(dataset_cls.__init__)
    for name in list(inspect.signature(dataset_cls.__init__).parameters)[1:]:
        if dataclasses.is_dataclass(hints.get(name)):
            return hints[name]
    raise TypeError("training.data.stacks.FocalStackDataset: cannot find its config dataclass")


def resolve_lens_path(lens: str) -> str:
    p = Path(lens)
    return str(p if p.is_absolute() or p.exists() else ROOT / p)


def make_dataset(data: dict, simulator: str, lens: str, effects: list[str] | None = None,
                 device: str = "cpu") -> Dataset:
    """FocalStackDataset for one split, everything but the simulator identical between AAT and baseline runs;
    device: where it renders (the items come back on the CPU)."""
    if simulator == "any_camera":  # the any-camera net's data: its own cameras, no lens or effects of the config
        if device != "cpu":
            raise ValueError(f"device {device!r}: the any-camera data (training.data.anycam) renders on the CPU only")
        from training.data.anycam import AnyCamConfig, AnyCamDataset

        try:
            return AnyCamDataset(AnyCamConfig(**data))
        except TypeError as e:
            raise ValueError(f"data config: {e}") from None
    from training.data import stacks

    cfg_cls = _config_class(stacks.FocalStackDataset)
    names = {f.name for f in dataclasses.fields(cfg_cls)}
    kw = dict(data)
    kw["simulator"] = simulator
    if "lens" in names:
        kw.setdefault("lens", resolve_lens_path(lens))
    if "effects" in names and effects is not None:
        kw.setdefault("effects", tuple(effects))
    unknown = sorted(set(kw) - names)
    if unknown:
        raise ValueError(f"data config: keys {unknown} are not fields of {cfg_cls.__name__} ({sorted(names)})")
    if device != "cpu":
        return stacks.FocalStackDataset(cfg_cls(**kw), device=device)
    return stacks.FocalStackDataset(cfg_cls(**kw))
