"""Checkpoints: written atomically (temporary file, then rename), so a run killed mid-write keeps the previous
one; `last.pt` holds everything to resume, `model.pt` the final weights and config. Tensors are stored on the
CPU and loaded onto `map_location` (the CPU by default), so a checkpoint written on a GPU opens anywhere."""

from __future__ import annotations

from pathlib import Path

import torch

from aat_deploy.io.atomic import atomic_file
from training.devices.select import to_cpu  # noqa: F401 (re-exported: what checkpoints store)


def save_atomic(obj: dict, path: Path) -> None:
    with atomic_file(path) as tmp:
        torch.save(obj, tmp)


def load(path: Path, map_location: str | torch.device = "cpu") -> dict:
    return torch.load(Path(path), map_location=map_location, weights_only=False)
