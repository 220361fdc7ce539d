"""Render a training config's stacks once into its content-hashed cache (training/data/stacks.py), so every
training run that uses the same data reads them instead of rendering again.

    OMP_WAIT_POLICY=PASSIVE nice python scripts/render_training_stacks.py configs/paper50/dfv_aat.json [...] \
        [--workers 2] [--split train|val|both]

Resumable: items already in the cache are skipped (a killed run loses at most the items being rendered). Several
configs that share their data (the AAT and thin-lens configs of one experiment differ only in the simulator, so
they have two caches; the AiFNet and DFVNet configs share them) are rendered once. Prints, per cache, how many
items it holds.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import queue
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _datasets(config_paths: list[str], split: str) -> dict:
    """{cache key: (data dict, simulator, lens, effects)} over the configs, one entry per distinct cache."""
    from training.train.config import load_config
    from training.train.data import make_dataset

    out = {}
    for p in config_paths:
        cfg = load_config(p)
        parts = [("train", cfg.data), ("val", cfg.val_data)]
        for name, data in parts:
            if data is None or (split != "both" and name != split):
                continue
            ds = make_dataset(data, cfg.simulator, cfg.lens, cfg.effects)
            if ds.cache is None:
                raise SystemExit(f"{p}: {name} data has no cache_dir: nothing to render into")
            out.setdefault(str(ds.cache), (dict(data), cfg.simulator, cfg.lens, list(cfg.effects), len(ds)))
    return out


def _work(args) -> int:
    """Render the uncached items i with i % n == k of one dataset (a worker process, one torch thread)."""
    (data, simulator, lens, effects, n_items), k, n, queue = args
    import torch

    torch.set_num_threads(1)
    from training.train.data import make_dataset

    ds = make_dataset(data, simulator, lens, effects)
    done, parent = 0, os.getppid()
    for i in range(k, n_items, n):
        if os.getppid() != parent:
            return done  # the main process was killed: stop rather than render on as an orphan
        if not ds.is_cached(i):
            ds.load_or_render(i)
            done += 1
        queue.put(1)
    return done


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("configs", nargs="+", help="training configs (JSON)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--split", choices=("train", "val", "both"), default="both")
    a = ap.parse_args(argv)
    from tqdm import tqdm

    sets = _datasets(a.configs, a.split)
    ctx = mp.get_context("spawn")
    for cache, spec in sets.items():
        t0 = time.time()
        with ctx.Manager() as mgr:
            q = mgr.Queue()
            with ctx.Pool(a.workers) as pool:
                res = pool.map_async(_work, [(spec, k, a.workers, q) for k in range(a.workers)])
                with tqdm(total=spec[4], desc=Path(cache).name, unit="stack") as bar:
                    while not res.ready():  # a failing worker ends the wait: res.get() raises its error
                        try:
                            q.get(timeout=1.0)
                            bar.update(1)
                        except queue.Empty:
                            pass
                rendered = sum(res.get())
        held = len(list(Path(cache).glob("*.npz")))
        print(f"{cache}: {held} stacks cached ({rendered} rendered now, {time.time() - t0:.0f} s; "
              f"{spec[1]}, {spec[4]} items)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
