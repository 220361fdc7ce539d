"""Does averaging the any-camera run's late weights beat its last checkpoint? (exploratory, validation only)

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_swa WEIGHTS_DIR --from-step A [--to-step B]
        --stacks cache/stacks [--bn-batches 200] [--out results/anycam_swa_v9.json] [--save DIR]

WEIGHTS_DIR holds a run's weights at its checkpoints, one `step_NNNNN.pt` each ({"model", "config", "step"}, the
format `load_trained` reads). The probe averages the weights of the steps in [A, B] (training.train.average),
recomputes batch norm's statistics over the first --bn-batches training batches (training.train.precise_bn: the
mean net's statistics are not the mean of the checkpoints'), and scores the run's own validation items against the
last checkpoint in the window, as saved and with its statistics recomputed the same way (so the comparison isolates
the weights). --save writes the averaged net as DIR/<run>_swa<A>-<B>_pbn<N>.pt (model.pt format, for the export).
Validation items and training renders only: no held-out lens or test scene.
"""

from __future__ import annotations

import argparse
import json
import re
import tempfile
from pathlib import Path

import torch

STEP_FILE = re.compile(r"step_(\d+)\.pt$")


def window(weights_dir: Path, first: int, last: int | None) -> list[Path]:
    """The step_NNNNN.pt files of weights_dir with first <= step <= last, in step order."""
    got = sorted((int(m.group(1)), p) for p in weights_dir.glob("step_*.pt") if (m := STEP_FILE.search(p.name)))
    return [p for s, p in got if s >= first and (last is None or s <= last)]


def averaged_checkpoint(paths: list[Path]) -> dict:
    """One checkpoint ({"model", "config", "step", "averaged_steps"}) holding the mean of `paths`' weights."""
    from training.train.average import average_state_dicts
    from training.train.checkpoint import load

    states = [load(p) for p in paths]
    names = {s["config"]["name"] for s in states}
    if len(names) != 1:
        raise ValueError(f"{paths[0].parent}: weights of more than one run: {sorted(names)}")
    steps = [int(s["step"]) for s in states]
    return {"model": average_state_dicts([s["model"] for s in states]), "config": states[-1]["config"],
            "step": steps[-1], "averaged_steps": steps}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("weights_dir", type=Path, help="folder of step_NNNNN.pt weights of one run")
    ap.add_argument("--from-step", type=int, required=True, help="first step averaged")
    ap.add_argument("--to-step", type=int, help="last step averaged (default: the last there)")
    ap.add_argument("--stacks", required=True, help="the run's render cache (its config's cache_dir)")
    ap.add_argument("--bn-batches", type=int, default=200, help="training batches batch norm is recomputed over")
    ap.add_argument("--out", type=Path, help="JSON of the rows")
    ap.add_argument("--save", type=Path, help="folder for the averaged net (model.pt format)")
    a = ap.parse_args(argv)
    if not a.weights_dir.is_dir():
        ap.error(f"{a.weights_dir}: no such folder")
    if a.bn_batches < 1:
        ap.error(f"--bn-batches: at least 1, got {a.bn_batches}")
    if a.out and a.out.exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    paths = window(a.weights_dir, a.from_step, a.to_step)
    if len(paths) < 2:
        ap.error(f"{a.weights_dir}: {len(paths)} step_*.pt files in steps [{a.from_step}, {a.to_step}]; need 2")
    avg = averaged_checkpoint(paths)
    steps = avg["averaged_steps"]
    dst = a.save / f"{avg['config']['name']}_swa{steps[0]}-{steps[-1]}_pbn{a.bn_batches}.pt" if a.save else None
    if dst is not None and dst.exists():
        ap.error(f"{dst}: exists (never overwritten)")

    from benchmarks.probes.anycam_precise_bn import score
    from training.train.checkpoint import save_atomic

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td) / f"swa{steps[0]}-{steps[-1]}.pt"  # the plain mean; score() names its save after this stem
        save_atomic(avg, tmp)
        single = score(paths[-1], a.stacks, [0, a.bn_batches])
        mean = score(tmp, a.stacks, [0, a.bn_batches], a.save)
    out = {"weights_dir": str(a.weights_dir), "averaged_steps": steps, "bn_batches": a.bn_batches,
           "last_checkpoint": single, "average": mean}
    print(f"steps {steps[0]}-{steps[-1]} ({len(steps)} checkpoints): validation MAE last "
          f"{single['rows'][0]['mae_m']:.4f} m (BN recomputed {single['rows'][1]['mae_m']:.4f}), average "
          f"{mean['rows'][1]['mae_m']:.4f} m (BN recomputed)")
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(a.out, json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
