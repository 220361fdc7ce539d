"""Checkpoints: written atomically (temporary file, then rename), so a run killed mid-write keeps the previous
one; `last.pt` holds everything to resume, `model.pt` the final weights and config."""

from __future__ import annotations

from pathlib import Path

import torch

from aat_deploy.io.atomic import atomic_file


def save_atomic(obj: dict, path: Path) -> None:
    with atomic_file(path) as tmp:
        torch.save(obj, tmp)


def load(path: Path) -> dict:
    return torch.load(Path(path), map_location="cpu", weights_only=False)
