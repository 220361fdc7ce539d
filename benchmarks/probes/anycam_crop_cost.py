"""What larger training crops cost the any-camera net (issue 35): seconds per render at larger render sizes and
seconds per training step at larger (or per-batch variable) crop sides, to plan a run on larger single scenes.

    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 nice -n 10 python -m benchmarks.probes.anycam_crop_cost \\
        [--config configs/anycam/dfv_aat_v7.json] [--sides 128 256 384] [--items 8] \\
        [--crops 128 256 384 128,192,256] [--steps 30] [--skip 3]

Renders: the config's training data (`data`) at each render side of `--sides` (height = width = side, its margin
kept), items 0 .. items - 1, one thread, into cache/probes/anycam_crop_cost/ (resumable: an item's time is kept in
the results file as soon as it is rendered; cached items are not timed again). Steps: the config trained from
scratch on the largest side's renders of the full side (fit_sensor cuts those of small sensors) with
`data.crop_sizes` = each `--crops` entry (one side, or a list drawn per batch), no validation, no loader worker
(data and step run one after the other: an upper bound for a run whose worker prepares the next batch meanwhile),
into a temporary folder that is removed; the first `--skip` steps are not timed. Each row: wall seconds per step
(data included) and the loop's own seconds per step (the net's forward, backward and update only). Results:
results/anycam_crop_cost.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _save(path: Path, res: dict) -> None:
    from aat_deploy.io.atomic import write_text_atomic

    write_text_atomic(path, json.dumps(res, indent=1) + "\n")


def render_times(data: dict, side: int, items: int, cache: Path, res: dict, out: Path) -> list[float]:
    """Seconds per render of items 0 .. items - 1 at side x side px (rendered now or timed before)."""
    from training.data.anycam import AnyCamConfig, AnyCamDataset

    cfg = AnyCamConfig(**{**data, "height": side, "width": side, "n_items": items, "only_cached": False,
                          "cache_dir": str(cache)})
    ds = AnyCamDataset(cfg)
    times = res.setdefault("render_s", {}).setdefault(str(side), {})
    for i in range(items):
        if str(i) in times and ds.is_cached(i):
            continue
        t0 = time.perf_counter()
        ds.load_or_render(i)
        times[str(i)] = round(time.perf_counter() - t0, 3)
        _save(out, res)
    return [times[str(i)] for i in range(items)]


def step_times(cfg, data: dict, side: int, items: int, cache: Path, crops: list[int], steps: int,
               skip: int) -> tuple[float, float]:
    """(wall s per step incl. data, the loop's s per step) of `cfg` from scratch on the side-px renders."""
    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.train.loop import train

    d = {**data, "height": side, "width": side, "n_items": items, "only_cached": True, "cache_dir": str(cache),
         "crop": 0, "crop_sizes": crops}
    ds = AnyCamDataset(AnyCamConfig(**d))
    # only renders of the full side (fit_sensor cuts those of small sensors), so every batch is of the side drawn
    ds.items = [i for i in ds.items if min(ds.load_or_render(i)["depth_m"].shape) >= max(crops)]
    if len(ds.items) < cfg.batch_size:
        raise SystemExit(f"{len(ds.items)} renders of {side} px: too few for a batch of {cfg.batch_size}; more --items")
    run = dataclasses.replace(cfg, data=d, val_data=None, val_every=0, num_workers=0, checkpoint_every=10**6,
                              log_every=1)
    with tempfile.TemporaryDirectory(prefix="anycam_crop_cost_") as tmp:
        out = Path(tmp) / "run"
        train(run, out, train_set=ds, stop_at_step=skip, progress=False)
        t0 = time.perf_counter()
        r = train(run, out, train_set=ds, resume=True, stop_at_step=skip + steps, progress=False)
        wall = (time.perf_counter() - t0) / steps
    return wall, float(r.seconds_per_step)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=ROOT / "configs/anycam/dfv_aat_v7.json")
    ap.add_argument("--sides", type=int, nargs="+", default=[128, 256, 384], help="render sides (px)")
    ap.add_argument("--items", type=int, default=8, help="renders per side (default 8)")
    ap.add_argument("--crops", nargs="+", default=["128", "256", "384", "128,192,256"],
                    help="crop sides to time training at, each one side or a comma list drawn per batch")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--skip", type=int, default=3, help="steps not timed (the first batches' start-up)")
    ap.add_argument("--out", type=Path, default=ROOT / "results/anycam_crop_cost.json")
    a = ap.parse_args(argv)

    import torch

    from training.train.config import load_config

    torch.set_num_threads(1)
    cfg = load_config(a.config)
    cache = ROOT / "cache/probes/anycam_crop_cost"
    res = json.loads(a.out.read_text()) if a.out.is_file() else {}
    res.update({"config": str(a.config.relative_to(ROOT)) if a.config.is_relative_to(ROOT) else str(a.config),
                "items": a.items, "threads": 1, "loader_workers": 0})
    print("| render side (px) | items | s per render mean | min | max |\n|---|---|---|---|---|")
    for side in a.sides:
        t = render_times(cfg.data, side, a.items, cache, res, a.out)
        print(f"| {side} | {len(t)} | {sum(t) / len(t):.2f} | {min(t):.2f} | {max(t):.2f} |", flush=True)
    side = max(a.sides)
    print(f"\n| crop sides (renders {side} px, batch {cfg.batch_size}) | wall s per step (data included) "
          f"| the loop's s per step |\n|---|---|---|")
    rows = res.setdefault("steps", {})
    for spec in a.crops:
        crops = [int(v) for v in spec.split(",")]
        wall, loop = step_times(cfg, cfg.data, side, a.items, cache, crops, a.steps, a.skip)
        rows[spec] = {"wall_s_per_step": round(wall, 3), "loop_s_per_step": round(loop, 3), "steps": a.steps,
                      "render_side": side, "batch_size": cfg.batch_size, "mosaic": cfg.data.get("mosaic", 0.0)}
        _save(a.out, res)
        print(f"| {spec} | {wall:.2f} | {loop:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
