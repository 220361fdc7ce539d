"""Keep a training run's weights at every checkpoint it saves, for weight averaging after the run
(benchmarks.probes.anycam_swa; training.train.average).

    python -m scripts.keep_run_weights cache/runs/dfv_aat_v9/last.pt cache/runs/dfv_aat_v9_weights [--every-s 20]

A run keeps only its latest `last.pt`. This watcher, started beside the run, copies the weights of each new one
(model state, config and step only: a few MB) to DEST/step_NNNNN.pt, atomically and never over an existing file. It
polls the file's modification time every --every-s seconds (a run saves every `checkpoint_every` steps, about
2 min on 2 cores for the any-camera runs) and stops by itself when the run has written model.pt beside last.pt.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def keep_once(src: Path, dest: Path) -> Path | None:
    """Copy src's weights to dest/step_NNNNN.pt unless that file exists; returns the file written, else None."""
    from training.train.checkpoint import load, save_atomic

    state = load(src)
    out = dest / f"step_{int(state['step']):05d}.pt"
    if out.exists():
        return None
    dest.mkdir(parents=True, exist_ok=True)
    save_atomic({"model": state["model"], "config": state["config"], "step": int(state["step"])}, out)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("last", type=Path, help="the run's last.pt")
    ap.add_argument("dest", type=Path, help="folder for step_NNNNN.pt")
    ap.add_argument("--every-s", type=float, default=20.0, help="seconds between looks at last.pt")
    a = ap.parse_args(argv)
    if a.dest.exists() and not a.dest.is_dir():
        ap.error(f"{a.dest}: exists and is not a folder")
    seen = None
    while True:
        try:
            mtime = a.last.stat().st_mtime
            if mtime != seen:
                written = keep_once(a.last, a.dest)
                if written:
                    print(f"kept {written}", flush=True)
                seen = mtime
        except FileNotFoundError:
            pass  # the run has not saved yet
        except (EOFError, RuntimeError) as e:  # a file being replaced under us: look again next round
            print(f"{a.last}: not readable now ({e}); trying again", flush=True)
        if (a.last.parent / "model.pt").exists():
            return 0
        time.sleep(a.every_s)


if __name__ == "__main__":
    raise SystemExit(main())
