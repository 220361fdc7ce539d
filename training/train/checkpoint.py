"""Checkpoints: written atomically (temporary file, then rename), so a run killed mid-write keeps the previous
one; `last.pt` holds everything to resume, `model.pt` the final weights and config."""

from __future__ import annotations

import os
from pathlib import Path

import torch


def save_atomic(obj: dict, path: Path) -> None:
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def load(path: Path) -> dict:
    return torch.load(Path(path), map_location="cpu", weights_only=False)
