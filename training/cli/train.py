"""`aat-train`: train a DfF network from a config file (checkpoints, resume, DDP under torchrun).

    aat-train --config configs/dff_aifnet_aat.json [--out runs/NAME] [--resume] [--steps N]
    torchrun --nproc_per_node=2 -m training.cli.train --config configs/dff_dfvnet_aat.json --out runs/x

Re-running with --resume after a kill continues from the last checkpoint. Without --resume an existing run
directory is refused. The full lens-to-model flow (--lens, --effects, --init) will add options in
`build_parser` / `apply_overrides`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="aat-train", description="Train a depth-from-focus network (AiFNet / DFVNet).")
    p.add_argument("--config", required=True, help="training config JSON (configs/dff_*.json)")
    p.add_argument("--out", help="run directory (default: runs/<config name>)")
    p.add_argument("--resume", action="store_true", help="continue from <out>/last.pt if present")
    p.add_argument("--steps", type=int, help="override the config's number of optimizer steps")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def apply_overrides(cfg, args: argparse.Namespace):
    """Command-line overrides of config fields (returns a new, validated config)."""
    changes = {}
    if args.steps is not None:
        changes["steps"] = args.steps
    return dataclasses.replace(cfg, **changes).validate() if changes else cfg


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from training.train.config import ConfigError, load_config

    try:
        cfg = apply_overrides(load_config(args.config), args)
    except ConfigError as e:
        print(f"aat-train: {e}", file=sys.stderr)
        return 2
    from training.train.loop import train

    out = Path(args.out) if args.out else ROOT / "runs" / cfg.name
    try:
        res = train(cfg, out, resume=args.resume, progress=not args.no_progress)
    except (FileExistsError, ValueError, FileNotFoundError) as e:
        print(f"aat-train: {e}", file=sys.stderr)
        return 1
    if int(os.environ.get("RANK", "0")) == 0:
        state = "finished" if res.finished else "stopped"
        spd = f", {res.seconds_per_step:.3f} s/step" if res.seconds_per_step else ""
        print(f"{cfg.name}: {state} at step {res.step}/{cfg.steps}{spd}; run in {out}")
        if res.val_metrics:
            print(json.dumps(res.val_metrics))
    return 0


if __name__ == "__main__":
    sys.exit(main())
