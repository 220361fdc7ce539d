"""Traced rays per second through the RF50 (12 surfaces, 2 aspheres) on one and on two threads.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_trace [--rays 262144] [--repeats 5]

Prints a markdown table (paste into BENCHMARKS.md). Each configuration runs in a fresh process so the
thread count is really applied; the ratio column compares with one thread in the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def worker(threads: int, dtype_name: str, n: int, repeats: int) -> dict:
    import torch

    from aat_deploy.lens.io import load_lens
    from training.optics.focus import focus
    from training.optics.trace import Rays, rays_through_pupil, stratified_disk, trace

    torch.set_num_threads(threads)
    dtype = getattr(torch, dtype_name)
    lens = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
    zs = focus(lens, 2.0)
    pupil = stratified_disk(n, torch.Generator().manual_seed(0))
    r = rays_through_pupil(lens, pupil, None, (0.0, math.radians(12.0)))
    rays = Rays(r.o.to(dtype), r.d.to(dtype), None)
    trace(lens, rays, sensor_z_mm=zs)  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = trace(lens, rays, sensor_z_mm=zs)
        times.append(time.perf_counter() - t0)
    best = min(times)
    return {"threads": threads, "dtype": dtype_name, "rays": n, "seconds": best,
            "rays_per_s": n / best, "valid": float(res.rays.valid.float().mean())}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=262144)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--worker", nargs=2, metavar=("THREADS", "DTYPE"))
    a = ap.parse_args()
    if a.worker:
        print(json.dumps(worker(int(a.worker[0]), a.worker[1], a.rays, a.repeats)))
        return
    env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE", PYTHONPATH=str(ROOT))
    rows = []
    for dtype in ("float64", "float32"):
        for threads in (1, 2):
            out = subprocess.run([sys.executable, __file__, "--rays", str(a.rays), "--repeats", str(a.repeats),
                                  "--worker", str(threads), dtype], env=env, capture_output=True, text=True,
                                 check=True)
            rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(f"RF50 focused at 2 m, field 12 deg, {a.rays} rays per trace, best of {a.repeats}\n")
    print("| dtype | threads | time per trace (s) | rays / s | vs 1 thread |")
    print("|---|---|---|---|---|")
    for r in rows:
        base = next(x for x in rows if x["dtype"] == r["dtype"] and x["threads"] == 1)
        print(f"| {r['dtype']} | {r['threads']} | {r['seconds']:.4f} | {r['rays_per_s']:.3g} | "
              f"{r['rays_per_s'] / base['rays_per_s']:.2f}x |")


if __name__ == "__main__":
    main()
