"""Work split by index across processes or machines: shard i of n takes the items i, i + n, i + 2n, ...

Strided rather than in blocks, so every shard gets the same mix of cheap and costly items. The shard comes from
`--shard i/n` (independent jobs: array jobs, separate machines) or from torchrun's RANK / WORLD_SIZE. Torch-free.
"""

from __future__ import annotations

import argparse
import os
import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Shard:
    index: int = 0
    count: int = 1

    def __post_init__(self):
        if not (self.count >= 1 and 0 <= self.index < self.count):
            raise ValueError(f"shard {self.index}/{self.count}: need 0 <= i < n")

    @property
    def name(self) -> str:
        return f"{self.index}/{self.count}"

    def items(self, n_items: int) -> range:
        """This shard's item indices among 0 .. n_items - 1."""
        return range(self.index, n_items, self.count)


def parse_shard(text: str) -> Shard:
    """'i/n' -> Shard(i, n) (0-based i); argparse type: one-line errors."""
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text or "")
    if not m:
        raise argparse.ArgumentTypeError(f"--shard {text!r}: expected i/n, e.g. 0/4 (shard i of n, 0-based)")
    try:
        return Shard(int(m[1]), int(m[2]))
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"--shard {text!r}: {e}") from None


def shard_from_env() -> Shard:
    """torchrun's world as a shard (rank of world size); Shard(0, 1) outside torchrun."""
    return Shard(int(os.environ.get("RANK", "0")), int(os.environ.get("WORLD_SIZE", "1")))


def add_shard_argument(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--shard", type=parse_shard, metavar="i/n",
                    help="render only shard i of n (items i, i+n, ...; 0-based) so that n jobs fill one cache "
                         "together (default: torchrun's rank/world size, else everything)")
