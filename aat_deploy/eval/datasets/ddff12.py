"""DDFF-12 (Hazirbas et al., "Deep Depth From Focus", ACCV 2018) as HDF5: the DDFF release's
`ddff-dataset-trainval.h5` / `ddff-dataset-test.h5`, or DFV's re-split `my_ddff_trainVal.h5` (Yang et al. 2022).

Format (the published files): datasets `stack_<split>` of shape (N, 10, H, W, 3), 8-bit sRGB focal stacks refocused
from Lytro light fields (383 x 552), and `disp_<split>` (N, H, W) float ground-truth disparity from a registered
RGB-D sensor, 0 = unknown; the test file has no `disp_test` (hidden ground truth). Splits: "train", "val", "test".
The 10 slices are focused at disparities linspace(BF / 0.5, BF / 7, 10) = 0.2825 ... 0.0202 (0.5 ... 7 m, near to
far, even in diopters; DFV rounds them to 0.28 ... 0.02) with disparity = BF / depth, BF = 0.14124.

Scoring as the field does (DDFF-12's and DFV's evaluation): in disparity, over pixels with ground truth > 0, per
stack then the mean over stacks. The runtime takes metres: focus_m = BF / disparity, and its depth is scored as
BF / depth. DFV evaluates 5 of the 10 slices (`--frames 0,2,4,6,9`); the default is all 10.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...io.color import srgb_codes_to_linear, srgb_to_linear
from .base import Conventions, Dataset, DatasetError, Item, need, select_frames

BF = 0.14124  # disparity x depth (m) of DDFF-12's light-field camera
SLICES = 10
FOCUS_DISPARITY = np.linspace(BF / 0.5, BF / 7.0, SLICES)  # near to far
SPLITS = ("train", "val", "test")


def to_disparity(depth_m: np.ndarray) -> np.ndarray:
    """BF / depth; unknown (NaN, not positive) stays unknown (NaN)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.isfinite(depth_m) & (depth_m > 0), BF / depth_m, np.nan)


CONVENTIONS = Conventions(
    unit="disparity", to_unit=to_disparity, clip=None,
    text="DDFF-12: metrics in disparity (BF / depth, BF = 0.14124; MSE and RMSE in disparity units, not metres), "
         "over pixels whose ground-truth disparity is > 0, per stack then the mean over stacks (DDFF-12's and "
         "DFV's protocol). Focus positions: disparities linspace(0.2825, 0.0202, 10), given to the runtime as "
         "BF / disparity metres.")


def stack_frame(codes: np.ndarray) -> np.ndarray:
    """One slice (H, W, 3) of 8-bit sRGB codes (uint8, or floats 0..255 as DFV's files store them) -> linear."""
    if codes.dtype == np.uint8:
        return srgb_codes_to_linear(np.ascontiguousarray(codes))
    x = np.asarray(codes, np.float32)
    return srgb_to_linear(np.clip(x / (255.0 if x.max() > 1.5 else 1.0), 0.0, 1.0))


class DDFF12(Dataset):
    name = "ddff12"
    conventions = CONVENTIONS

    def __init__(self, path: Path, split: str = "val", frames: list[int] | None = None):
        if split not in SPLITS:
            raise DatasetError(f"{path}: DDFF-12 split {split!r} (one of {', '.join(SPLITS)})")
        h5py = need("h5py", "reading DDFF-12's .h5 files")
        self.path, self.split = Path(path), split
        if not self.path.is_file():
            raise DatasetError(f"{self.path}: not a file (DDFF-12 is read from its .h5 file)")
        try:
            self.h5 = h5py.File(self.path, "r")
        except OSError as e:
            raise DatasetError(f"{self.path}: not a readable HDF5 file ({str(e).splitlines()[0][:120]})") from None
        key = f"stack_{split}"
        if key not in self.h5:
            have = ", ".join(sorted(k for k in self.h5.keys() if k.startswith("stack_"))) or "none"
            raise DatasetError(f"{self.path}: no dataset {key!r} (stacks in this file: {have})")
        self.stacks = self.h5[key]
        if self.stacks.ndim != 5 or self.stacks.shape[-1] != 3 or self.stacks.shape[1] < 2:
            raise DatasetError(f"{self.path}: {key} has shape {self.stacks.shape}, (N, S, H, W, 3) expected")
        self.disp = self.h5.get(f"disp_{split}")
        n, s, h, w, _ = self.stacks.shape
        if self.disp is not None and tuple(self.disp.shape) not in ((n, h, w), (n, h, w, 1)):
            raise DatasetError(f"{self.path}: disp_{split} has shape {self.disp.shape}, {(n, h, w)} expected")
        if s != SLICES:
            raise DatasetError(f"{self.path}: {key} has {s} slices per stack; DDFF-12's focus positions are "
                               f"known for {SLICES}")
        self.frames = select_frames(s, frames, str(self.path))

    def __len__(self) -> int:
        return int(self.stacks.shape[0])

    def describe(self) -> dict:
        return {**super().describe(), "path": str(self.path), "split": self.split, "frames": self.frames,
                "focus_disparity": FOCUS_DISPARITY[self.frames].round(5).tolist(),
                "ground_truth": self.disp is not None}

    def items(self):
        focus_m = (BF / FOCUS_DISPARITY[self.frames]).astype(np.float64)
        for i in range(len(self)):
            stack = self.stacks[i]
            frames = [stack_frame(stack[k]) for k in self.frames]
            gt = None
            if self.disp is not None:
                gt = np.asarray(self.disp[i], np.float32).reshape(stack.shape[1:3])
                gt = np.where(np.isfinite(gt) & (gt > 0), gt, np.nan).astype(np.float32)
            yield Item(f"{self.split}_{i:04d}", frames, focus_m, gt, None,
                       {"focus": "BF / the published slice disparities"})
