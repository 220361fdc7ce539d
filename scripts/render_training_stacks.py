"""Render a training config's stacks once into its content-hashed cache (training/data/stacks.py, layout in
training/data/cache.py), so every training run that uses the same data reads them instead of rendering again.

    OMP_WAIT_POLICY=PASSIVE nice python -m scripts.render_training_stacks configs/paper50/dfv_aat.json [...] \
        [--workers 2] [--split train|val|both] [--shard i/n] [--device cpu|cuda|...]
    python -m scripts.render_training_stacks CONFIG --shard 3/8            # job 3 of 8 (array jobs, machines)
    torchrun --nproc_per_node=8 -m scripts.render_training_stacks CONFIG --workers 1   # shard = rank/world

Sharded: shard i of n renders items i, i+n, i+2n, ...; n jobs started anywhere (the cache folder shared) fill one
cache without collisions, and the files equal those one process writes, byte for byte. Resumable: items already
in the cache are skipped (a killed job loses at most the items being rendered); rerun the same command. Each
shard records what it did in <cache>/shards/; whichever job finds the cache complete writes <cache>/manifest.json
(every item's SHA-256). Several configs that share their data (the AAT and thin-lens configs of one experiment
differ only in the simulator, so they have two caches; the AiFNet and DFVNet configs share them) are rendered
once. Prints, per cache, how many items it holds. --device cuda renders on the GPU (default cpu: a GPU's float
rounding differs from the CPU's, so all shards of one cache should use one kind of device; each shard's record
names its device).
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing as mp
import os
import queue
import sys
import time
from pathlib import Path

from training.devices.shard import Shard, add_shard_argument, shard_from_env  # torch-free

ROOT = Path(__file__).resolve().parents[1]


def _datasets(config_paths: list[str], split: str) -> dict:
    """{cache path: (data dict, simulator, lens, effects, n_items)} over the configs, one entry per distinct cache."""
    from training.train.config import load_config
    from training.train.data import make_dataset

    out = {}
    for p in config_paths:
        cfg = load_config(p)
        parts = [("train", cfg.data), ("val", cfg.val_data)]
        for name, data in parts:
            if data is None or (split != "both" and name != split):
                continue
            # every item of the config: a run may read only those cached (the any-camera data's only_cached), the
            # renderer makes them all (and so starts on an empty cache)
            data = {**data, "only_cached": False} if data.get("only_cached") else dict(data)
            ds = make_dataset(data, cfg.simulator, cfg.lens, cfg.effects)
            if ds.cache is None:
                raise SystemExit(f"{p}: {name} data has no cache_dir: nothing to render into")
            out.setdefault(str(ds.cache), (data, cfg.simulator, cfg.lens, list(cfg.effects), ds.cfg.n_items))
    return out


def _work(args) -> int:
    """Render the uncached items of `indices` of one dataset (one torch thread: items do not depend on how the
    work is split). Reports each item with `report.put(1)` (a queue; or None)."""
    (data, simulator, lens, effects, _), indices, report, device = args
    import torch

    torch.set_num_threads(1)
    from training.train.data import make_dataset

    ds = make_dataset(data, simulator, lens, effects, device=device)
    done, parent = 0, os.getppid()
    for i in indices:
        if os.getppid() != parent:
            return done  # the main process was killed: stop rather than render on as an orphan
        if not ds.is_cached(i):
            ds.load_or_render(i)
            done += 1
        if report is not None:
            report.put(1)
    return done


def render_shard(spec: tuple, shard: Shard, workers: int, progress: bool = True, desc: str = "",
                 device: str = "cpu") -> int:
    """Render this shard's uncached items of one dataset with `workers` processes (1: in this process), on
    `device`. Returns how many were rendered."""
    from tqdm import tqdm

    from training.train.data import make_dataset

    ds = make_dataset(*spec[:4])
    todo = [i for i in shard.items(spec[4]) if not ds.is_cached(i)]
    todo.sort(key=getattr(ds, "render_priority", lambda i: 0))  # a dataset may rank its items (stable)
    if not todo:
        return 0
    if workers <= 1:
        import torch

        threads = torch.get_num_threads()
        with tqdm(total=len(todo), desc=desc, unit="stack", disable=not progress) as bar:
            class _Bar:
                def put(self, n: int) -> None:
                    bar.update(n)

            try:
                return _work((spec, todo, _Bar(), device))
            finally:
                torch.set_num_threads(threads)
    ctx = mp.get_context("spawn")
    with ctx.Manager() as mgr:
        q = mgr.Queue()
        with ctx.Pool(workers) as pool:
            res = pool.map_async(_work, [(spec, todo[k::workers], q, device) for k in range(workers)])
            with tqdm(total=len(todo), desc=desc, unit="stack", disable=not progress) as bar:
                while not res.ready():  # a failing worker ends the wait: res.get() raises its error
                    try:
                        q.get(timeout=1.0)
                        bar.update(1)
                    except queue.Empty:
                        pass
            return sum(res.get())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("configs", nargs="+", help="training configs (JSON)")
    ap.add_argument("--workers", type=int, default=2, help="processes of this job (default 2; 1 = this process)")
    ap.add_argument("--split", choices=("train", "val", "both"), default="both")
    add_shard_argument(ap)
    ap.add_argument("--device", default="cpu", metavar="cpu|cuda[:N]|mps|auto",
                    help="where the simulator renders (default cpu; under torchrun cuda means each rank's GPU)")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    a = ap.parse_args(argv)
    env = shard_from_env()
    if a.shard is not None and env.count > 1:
        ap.error(f"--shard {a.shard.name} under torchrun (world {env.count}): the rank already picks the shard")
    shard = a.shard or env
    from training.data.cache import missing_items, write_manifest, write_shard_record
    from training.train.data import make_dataset

    for cache, spec in _datasets(a.configs, a.split).items():
        t0 = time.time()
        tag = Path(cache).name + (f" shard {shard.name}" if shard.count > 1 else "")
        rendered = render_shard(spec, shard, a.workers, progress=not a.quiet, desc=tag, device=a.device)
        write_shard_record(Path(cache), shard, spec[4], rendered, time.time() - t0, device=a.device)
        data = dataclasses.asdict(make_dataset(*spec[:4]).cfg)
        manifest = write_manifest(Path(cache), data, spec[4])
        left = len(missing_items(Path(cache), spec[4]))
        state = "complete, manifest.json written" if manifest else f"{left} items still missing (other shards?)"
        print(f"{cache}: {tag}: {rendered} rendered now ({time.time() - t0:.0f} s); "
              f"{spec[4] - left} of {spec[4]} items held, {state} ({spec[1]})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
