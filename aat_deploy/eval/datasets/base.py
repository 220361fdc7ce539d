"""What every dataset reader shares: `Dataset`, `Item`, `Conventions`, `DatasetError`, the optional-dependency
import (`need`) and frame selection. The readers (one module per dataset) import this, never the package, so the
package's `open_dataset` can import them without a cycle."""


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
    max_megapixels: float | None = None  # the frame readers' pixel limit (aat-eval --max-megapixels), else the default

    def frame_loader(self, path) -> Callable[[], np.ndarray]:
        """A function that decodes the image file `path` as the runtime reads frames (kind from its content, the
        pixel limit checked on its header first) to linear RGB (H, W, 3) float32."""
        from ...capture.raw import load_frame

        return lambda: load_frame(path, self.max_megapixels)[0]

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
