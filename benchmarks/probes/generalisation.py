"""Why does a DfF net score worse on the held-out test set than on its validation set? One factor at a time.

The training runs validate on 192² renders textured with photographs from the *training* pool, under the mixed
focus schedule; the Table 2 test set (training/train/testsets.py) is whole-sensor renders textured with the
*held-out* photographs, under one protocol. This probe renders the validation set of a training config again with
one factor changed at a time (photo pool: train / test; schedule: mixed / fixed / scene) and scores the given
ONNX models on every variant, through onnxruntime as `aat-infer` runs them:

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.generalisation configs/table2/paper50_aifnet_aat.json \
        --models models/reproduce/paper50_aifnet_aat.onnx models/paper50_dfvnet_aat.onnx [--n 48] [--out R.json]

A gap that opens with the held-out photographs (same schedule) is texture over-fitting; one that opens with the
fixed schedule is the focus schedule. Depth MAE in metres from the sensor, mean over images with a 95 %
bootstrap interval over images. Variants are cached under cache/stacks like any training data.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

VARIANTS = {  # name: overrides of the config's val_data
    "val (train photos, mixed)": {},
    "held-out photos, mixed": {"photo_split": "test"},
    "train photos, fixed": {"schedule": "fixed"},
    "held-out photos, fixed": {"photo_split": "test", "schedule": "fixed"},
    "held-out photos, scene": {"photo_split": "test", "schedule": "scene"},
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("config", help="a training config (its val_data, lens and simulator are used)")
    ap.add_argument("--models", nargs="+", required=True, help="ONNX DfF models to score")
    ap.add_argument("--n", type=int, default=48, help="images per variant")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", help="write the results as JSON here")
    a = ap.parse_args(argv)
    from tqdm import tqdm

    from aat_deploy.eval.stats import bootstrap_mean
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.metrics import depth_metrics
    from aat_deploy.optics.field import pixel_fields
    from training.train.config import load_config
    from training.train.data import make_dataset

    cfg = load_config(a.config)
    models = {Path(m).name: DfFModel(Path(m), threads=a.threads) for m in a.models}
    res: dict[str, dict[str, list[float]]] = {}
    for vname, over in VARIANTS.items():
        data = {**cfg.val_data, **over, "n_items": a.n}
        ds = make_dataset(data, cfg.simulator, cfg.lens, cfg.effects)
        per = {m: [] for m in models}
        for i in tqdm(range(a.n), desc=vname, unit="stack", file=sys.stderr):
            it = ds.load_or_render(i)
            for m, model in models.items():
                fxy = None
                if model.field_aware:  # the item's true place on the sensor
                    h, w = it["depth_m"].shape
                    fxy = np.stack(pixel_fields(h, w, ds.sensor_hw, tuple(int(v) for v in it["origin"])))
                out = model.infer(it["stack"], it["focus_m"], field_xy=fxy)
                per[m].append(depth_metrics(out.depth_m, it["depth_m"])["mae"])
        res[vname] = {m: list(bootstrap_mean(v, n_boot=2000, seed=1)) for m, v in per.items()}
    print(f"\nDepth MAE (m), {a.n} images of {cfg.val_data['height']}x{cfg.val_data['width']} px per variant, "
          f"simulator {cfg.simulator}, 95 % bootstrap over images\n")
    print("| variant | " + " | ".join(models) + " |\n|---|" + "---|" * len(models))
    for vname, row in res.items():
        print(f"| {vname} | " + " | ".join(f"{m:.3f} [{lo:.3f}, {hi:.3f}]" for m, lo, hi in row.values()) + " |")
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(Path(a.out), json.dumps({"config": a.config, "n": a.n, "mae_m": res}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
