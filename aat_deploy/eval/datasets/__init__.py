"""Readers of the public depth-from-focus benchmarks as users have them on disk, for `aat-eval --dataset NAME PATH`
(docs/datasets.md: where to download them, their formats and the field's scoring conventions).

Each reader turns one dataset into `Item`s: the frames of one focal stack as the runtime takes them (linear RGB,
sorted near to far, focus distances in metres), the ground truth in the dataset's own unit (metric depth, or
disparity for DDFF-12) with its validity mask, or none (Mobile Depth; the hidden test splits). `Conventions` says
how the field scores it: the unit, the valid pixels, a clip. Readers are torch-free; DDFF-12's HDF5 needs h5py and
FoD500's EXR depth needs OpenEXR (the optional extra `datasets`; without it, a one-line error naming the extra).

    from aat_deploy.eval.datasets import open_dataset
    ds = open_dataset("ddff12", "my_ddff_trainVal.h5", split="val")
    for item in ds.items(): ...
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from ...errors import CaptureError

EXTRA = 'pip install "aat-dff[datasets]"'


class DatasetError(CaptureError):
    """A dataset file or folder is missing or not in the published format (one line naming it)."""


@dataclass(frozen=True)
class Conventions:
    """How the field scores a dataset. unit: "depth_m" (metres) or "disparity" (DDFF-12: bf / depth);
    to_unit(depth_m) -> the unit; clip: (lo, hi) applied to prediction and ground truth before scoring (in the
    unit), or None; text: one paragraph for the tables (valid pixels, unit, whose protocol)."""

    unit: str
    to_unit: Callable[[np.ndarray], np.ndarray]
    clip: tuple[float, float] | None
    text: str


@dataclass
class Item:
    """One focal stack. frames: S frames (H, W, 3) float32 linear RGB, or functions that decode them (decoded when
    the runtime asks, one at a time), sorted near to far; focus_m (S,) metres, ascending (placeholders where the
    dataset has none, `info["focus"]` says); gt (Hg, Wg) float in the dataset's unit covering the frames' field of
    view, NaN/0 = unknown, or None; mask (Hg, Wg) bool of valid ground truth or None (all finite > 0)."""

    name: str
    frames: list
    focus_m: np.ndarray
    gt: np.ndarray | None = None
    mask: np.ndarray | None = None
    info: dict = field(default_factory=dict)


class Dataset:
    """A reader: `name`, `conventions`, `describe()` (a dict for the report), `items()` (an iterator of Item),
    `__len__`. Problems with one item raise DatasetError from items() when that item is reached."""

    name = ""
    conventions: Conventions

    def items(self) -> Iterator[Item]:
        raise NotImplementedError

    def __len__(self) -> int:
        raise NotImplementedError

    def describe(self) -> dict:
        return {"dataset": self.name, "unit": self.conventions.unit, "clip": self.conventions.clip,
                "conventions": self.conventions.text}


def depth_unit(depth_m: np.ndarray) -> np.ndarray:
    return depth_m


def need(module: str, what: str):
    """Import an optional reader dependency, or a one-line DatasetError naming the extra."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise DatasetError(f"{what} needs the Python package {module!r}: {EXTRA}") from None


def select_frames(n: int, frames: list[int] | None, where: str) -> list[int]:
    """The frame indices to use of a stack of n: all, or the given ones (ascending, distinct, in range)."""
    if frames is None:
        return list(range(n))
    if len(frames) < 2 or sorted(set(frames)) != list(frames) or frames[0] < 0 or frames[-1] >= n:
        raise DatasetError(f"{where}: frames {frames} must be at least two distinct ascending indices in 0..{n - 1}")
    return list(frames)


def open_dataset(name: str, path, *, split: str | None = None, frames: list[int] | None = None,
                 aperture: float | None = None) -> Dataset:
    """The reader of dataset `name` (one of NAMES) at `path`; split, frames (indices into each stack), aperture
    (ZEDD's f-number) as that dataset takes them (docs/datasets.md)."""
    from pathlib import Path

    from . import ddff12, fod500, mobile_depth, zedd

    readers = {"ddff12": ddff12.DDFF12, "fod500": fod500.FoD500, "zedd": zedd.ZEDD,
               "mobile_depth": mobile_depth.MobileDepth}
    if name not in readers:
        raise DatasetError(f"unknown dataset {name!r} (one of {', '.join(NAMES)})")
    kw = {"frames": frames}
    if split is not None:
        kw["split"] = split
    if aperture is not None:
        if name != "zedd":
            raise DatasetError("--aperture belongs to --dataset zedd")
        kw["aperture"] = aperture
    return readers[name](Path(path), **kw)


NAMES = ("ddff12", "fod500", "zedd", "mobile_depth")
