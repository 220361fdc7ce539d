"""The start of an any-camera run at another peak learning rate (issue 35): the fifth run was meant to repeat the
first converged run's schedule, whose checkpoint and log say lr 1e-3 after 300 warm-up steps, and was launched at
3e-4 after 200 (the second run's, a fine-tune's).

    OMP_NUM_THREADS=1 nice -n 10 python -m benchmarks.probes.anycam_lr_start [--config configs/anycam/dfv_aat_v5.json]
        [--lr 1e-3] [--warmup 300] [--stop 800]

Trains `--config` from scratch with only lr and warmup_steps replaced (the same data, seed and sampler order, the same
24,000-step cosine) up to step `--stop` (training.train.loop.train(stop_at_step): checkpoint and log as the run's),
into cache/probes/anycam_lr_start/lr{LR}_w{WARMUP}/. Score its last.pt against the run's own checkpoint of the
same step with `python -m benchmarks.anycam_val_baseline --frames-set --checkpoint RUN_STEP.pt THIS/last.pt`.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=ROOT / "configs/anycam/dfv_aat_v5.json")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--warmup", type=int, default=300)
    ap.add_argument("--stop", type=int, default=800)
    a = ap.parse_args(argv)

    import torch

    from training.train.config import load_config
    from training.train.loop import train

    torch.set_num_threads(1)
    cfg = dataclasses.replace(load_config(a.config), lr=a.lr, warmup_steps=a.warmup, val_every=0)
    out = ROOT / "cache/probes/anycam_lr_start" / f"lr{a.lr:g}_w{a.warmup}"
    r = train(cfg, out, resume=True, stop_at_step=a.stop, progress=False)
    print(f"{out}: step {r.step}, last loss {r.last_loss:.3f}, {r.seconds_per_step:.2f} s per step")
    return 0


if __name__ == "__main__":
    sys.exit(main())
