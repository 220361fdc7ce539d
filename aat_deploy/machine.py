"""What this machine offers the runtime: its CPU cores, and thread counts bounded by them."""

from __future__ import annotations

import os
import threading
from contextlib import contextmanager


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


_BLAS_LOCK = threading.Lock()
_BLAS_DEPTH = 0
_BLAS_LIMITER = None


@contextmanager
def one_blas_thread():
    """numpy's BLAS and LAPACK (OpenBLAS) at one thread inside (a context manager, or a decorator with `()`),
    restored on leaving the outermost one; nesting costs nothing more.

    For loops of many small solves, such as the calibration's ~1,000 least-squares fits (~1,300 x 60) per model
    choice: OpenBLAS splits each of LAPACK's many small steps across all cores and makes its threads meet after
    each, so when another process holds a core the threads wait for it. One model choice took 50 s so on 2 cores
    (one held by a training run) against 3.2 s on one thread, and CI's test of 8 of them 30 minutes."""
    global _BLAS_DEPTH, _BLAS_LIMITER
    from threadpoolctl import threadpool_limits

    with _BLAS_LOCK:
        if _BLAS_DEPTH == 0:
            _BLAS_LIMITER = threadpool_limits(limits=1, user_api="blas")
        _BLAS_DEPTH += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _BLAS_DEPTH -= 1
            if _BLAS_DEPTH == 0:
                _BLAS_LIMITER.restore_original_limits()
                _BLAS_LIMITER = None
