"""Shared timing helpers for the benchmark scripts."""

from __future__ import annotations

import os
import subprocess
import time


def best_of(fn, repeat: int = 1):
    """(result of the last call, best wall time in seconds over `repeat` calls)."""
    out, best = None, float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def timed_process(cmd: list[str], cwd, env: dict) -> dict:
    """Run cmd as a child process (stdout discarded): its wall and CPU seconds (user + system, all its threads and
    children), peak resident memory (MB) and the 1-minute load average at its start and end. Raises with the end
    of its stderr when it fails."""
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace")
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}): {err[-800:]}")
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "rss_mb": usage.ru_maxrss / 1024,
            "load": load0, "load_end": os.getloadavg()[0]}
