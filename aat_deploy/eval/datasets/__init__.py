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

from .base import EXTRA, Conventions, Dataset, DatasetError, Item, depth_unit, need, select_frames

__all__ = ["EXTRA", "Conventions", "Dataset", "DatasetError", "Item", "depth_unit", "need", "select_frames",
           "open_dataset", "NAMES"]


def open_dataset(name: str, path, *, split: str | None = None, frames: list[int] | None = None,
                 aperture: float | None = None, max_megapixels: float | None = None) -> Dataset:
    """The reader of dataset `name` (one of NAMES) at `path`; split, frames (indices into each stack), aperture
    (ZEDD's f-number) as that dataset takes them (docs/datasets.md); max_megapixels: the pixel limit of its image
    files (default $AAT_MAX_MEGAPIXELS or 200, as every frame reader)."""
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
    ds = readers[name](Path(path), **kw)
    ds.max_megapixels = max_megapixels
    return ds


NAMES = ("ddff12", "fod500", "zedd", "mobile_depth")
