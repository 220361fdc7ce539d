"""A distributed, resumable sampler: epoch e shuffles with seed + e, rank r takes every world-th index (equal
counts, the remainder dropped), and an epoch can start part-way, so a resumed run reads exactly the items an
uninterrupted one would without loading the skipped ones."""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch.utils.data import Sampler


class ResumableSampler(Sampler[int]):
    def __init__(self, n_items: int, rank: int = 0, world: int = 1, seed: int = 0, shuffle: bool = True):
        if n_items < world:
            raise ValueError(f"dataset has {n_items} items, fewer than {world} processes")
        self.n, self.rank, self.world, self.seed, self.shuffle = n_items, rank, world, seed, shuffle
        self.epoch, self.start = 0, 0

    @property
    def per_rank(self) -> int:
        return self.n // self.world

    def set_epoch(self, epoch: int, start: int = 0) -> None:
        """Next iteration yields epoch `epoch` from this rank's item `start` on."""
        self.epoch, self.start = epoch, start

    def __iter__(self) -> Iterator[int]:
        if self.shuffle:
            g = torch.Generator().manual_seed(self.seed + self.epoch)
            order = torch.randperm(self.n, generator=g).tolist()
        else:
            order = list(range(self.n))
        mine = order[self.rank:: self.world][: self.per_rank]
        return iter(mine[self.start:])

    def __len__(self) -> int:
        return self.per_rank - self.start
