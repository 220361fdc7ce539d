"""Checkpoints: written atomically (temporary file, then rename), so a run killed mid-write keeps the previous
one; `last.pt` holds everything to resume, `model.pt` the final weights and config. Tensors are stored on the
CPU and loaded onto `map_location` (the CPU by default), so a checkpoint written on a GPU opens anywhere."""

from __future__ import annotations

from pathlib import Path

import torch

from aat_deploy.io.atomic import atomic_file


def save_atomic(obj: dict, path: Path) -> None:
    with atomic_file(path) as tmp:
        torch.save(obj, tmp)


def to_cpu(obj):
    """A state dict (nested dicts / lists of tensors, e.g. an optimizer's) with every tensor on the CPU."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu()
    if isinstance(obj, dict):
        return {k: to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(to_cpu(v) for v in obj)
    return obj


def load(path: Path, map_location: str | torch.device = "cpu") -> dict:
    return torch.load(Path(path), map_location=map_location, weights_only=False)
