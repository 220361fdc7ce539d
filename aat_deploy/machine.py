"""What this machine offers the runtime: its CPU cores, and thread counts bounded by them."""

from __future__ import annotations

import os


def machine_cores() -> int:
    """The CPU cores this process may run on (its affinity mask, so a container's limit counts)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def bound_threads(threads: int) -> int:
    """A thread count for onnxruntime, at most the machine's cores: more only costs memory (`--threads 100000`
    took 16 GB and ran on after 5 minutes on 2 cores)."""
    return max(1, min(int(threads), machine_cores()))
