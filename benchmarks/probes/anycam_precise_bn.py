"""Do the any-camera runs' validation swings come from batch norm's running statistics? (exploratory, validation only)

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_precise_bn CHECKPOINT [CHECKPOINT ...]
        --stacks cache/stacks [--batches 0,50,200] [--out results/anycam_precise_bn.json] [--save DIR]

The runs' validation MAE jumps from one 500-step evaluation to the next (the sixth run: 0.46 m, 0.56, 0.83 ...)
and the eighth run ended 1.3x worse than its best. Each BatchNorm's running statistics are an exponential average
of the last ~10 training batches of 4 stacks (training.train.precise_bn), a noisy sample when batches mix stack
sizes, schedules and mosaics. For each checkpoint this probe scores the run's own validation items (its config's
val_data, the first `val_items`) with the statistics as saved (0 batches) and recomputed over the first N batches of
its training data (fixed order, seed 0; the run's batch size, collate and mosaics); --save writes the checkpoint
with the last N's statistics as DIR/<run>_<stem>_pbn<N>.pt (model.pt format, for the export). Validation items and
training renders only: no held-out lens or test scene.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch


def _train_batches(cfg, stacks: str, n: int):
    """The first n training batches of cfg's data in a fixed order (seed 0), as the loop collates them."""
    from torch.utils.data import DataLoader

    from training.train.data import make_dataset

    ds = make_dataset({**cfg.data, "cache_dir": stacks}, cfg.simulator, cfg.lens, cfg.effects)
    gen = torch.Generator().manual_seed(0)
    loader = DataLoader(ds, batch_size=cfg.batch_size, shuffle=True, generator=gen, drop_last=True,
                        collate_fn=getattr(ds, "collate", None), num_workers=0)
    for i, batch in enumerate(loader):
        if i >= n:
            return
        yield batch


def score(checkpoint: Path, stacks: str, batches: list[int], save: Path | None = None) -> dict:
    from training.nets import registry
    from training.train.checkpoint import load, save_atomic
    from training.train.data import make_dataset
    from training.train.evaluate import evaluate
    from training.train.loop import load_trained
    from training.train.precise_bn import recompute_bn_stats

    model, cfg = load_trained(checkpoint)
    step = int(load(checkpoint).get("step", -1))
    val = make_dataset({**cfg.val_data, "cache_dir": stacks}, cfg.simulator, cfg.lens, cfg.effects)
    if registry.get(cfg.net).focus_maps:
        from training.nets.dfvaat import train_levels as forward_levels

        def forward(m, b):
            return forward_levels(m, b)
    else:
        from training.nets.model import train_levels

        def forward(m, b):
            return train_levels(m, b["stack"].float(), b["focus_m"].float(), m.size_multiple,
                                b["field_xy"].float() if cfg.field_channels else None)
    rows = []
    saved = {k: v.clone() for k, v in model.state_dict().items()}
    for n in batches:
        model.load_state_dict(saved)
        t0 = time.perf_counter()
        got = recompute_bn_stats(model, _train_batches(cfg, stacks, n), forward) if n else 0
        metrics, _ = evaluate(model, val, cfg.val_items, cfg.loss.mask_focus_range)
        rows.append({"batches": got, "mae_m": metrics["mae"], "rmse_m": metrics["rmse"],
                     "abs_rel": metrics["abs_rel"], "seconds": round(time.perf_counter() - t0, 1)})
        print(f"{checkpoint} step {step}: BN over {got:4d} batches -> validation MAE {metrics['mae']:.4f} m",
              flush=True)
    if save is not None and batches[-1]:
        save.mkdir(parents=True, exist_ok=True)
        dst = save / f"{cfg.name}_{checkpoint.stem}_pbn{batches[-1]}.pt"
        if dst.exists():
            raise FileExistsError(f"{dst}: exists (never overwritten)")
        save_atomic({"model": model.state_dict(), "config": cfg.to_dict(), "config_hash": cfg.hash(),
                     "step": step, "precise_bn_batches": batches[-1]}, dst)  # a stopped run leaves no half file
        print(f"wrote {dst}", flush=True)
    return {"checkpoint": str(checkpoint), "run": cfg.name, "step": step, "val_items": cfg.val_items, "rows": rows}


def refuse_missing_or_existing(ap: argparse.ArgumentParser, checkpoints: list[Path], out: Path | None) -> None:
    """The checkpoint probes' argument checks, made before any work: every checkpoint a file, --out not there yet."""
    missing = [str(c) for c in checkpoints if not c.is_file()]
    if missing:
        ap.error(f"no such checkpoint: {', '.join(missing)}")
    if out and out.exists():
        ap.error(f"{out}: exists (choose another --out)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoints", type=Path, nargs="+", help="runs' model.pt, last.pt or best.pt")
    ap.add_argument("--stacks", required=True, help="the runs' render cache (their config's cache_dir)")
    ap.add_argument("--batches", default="0,50,200", help="training batches to average over (0 = as saved)")
    ap.add_argument("--out", type=Path, help="JSON of the rows")
    ap.add_argument("--save", type=Path, help="write each checkpoint with the last --batches value's statistics")
    a = ap.parse_args(argv)
    batches = [int(b) for b in a.batches.split(",")]
    if any(b < 0 for b in batches):
        ap.error(f"--batches: counts >= 0, got {batches}")
    refuse_missing_or_existing(ap, a.checkpoints, a.out)
    torch.set_num_threads(1)
    out = [score(c, a.stacks, batches, a.save) for c in a.checkpoints]
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(a.out, json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
