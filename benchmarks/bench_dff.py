"""The paper's Table 2 on our models: AAT vs thin-lens training, tested on stacks rendered through the real lens.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_dff [--n 12] [--figures DIR] [--threads 2] [MODEL.onnx ...]

Test sets (never seen in training; all rendered with the RF50's PSFs, the `aat` simulator; fixed schedule of
8 focus distances even in diopters over 0.5-10 m, the training schedule, never derived from the depth):
- procedural: `--n` held-out procedural scenes (seed 777777) at the full 640 x 960 sensor;
- middlebury: the real Middlebury 2014 Motorcycle scene (2.1-5.0 m) scaled to cover the sensor.
Models are the shipped ONNX files, run with onnxruntime exactly as `aat-infer` runs them. Metrics per image,
then averaged (aat_deploy.metrics); depth in metres from the sensor. Also MAE by field zone (field radius
< 0.33 centre, > 0.66 outer: aat_deploy.eval.stats) and a figure of the mean error over the field per model. The evaluation code is
`training/train/heldout.py` (shared with `aat-train --lens`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmarks import FIGURES

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ["dff_aifnet_thin", "dff_aifnet_aat", "dff_dfvnet_thin", "dff_dfvnet_aat"]  # in models/reproduce/


def test_sets(n: int) -> dict:
    from training.data.rgbd import load_middlebury_motorcycle
    from training.data.stacks import FocalStackDataset, StackDataConfig
    from training.train.heldout import procedural_items, rgbd_item

    cfg = StackDataConfig(simulator="aat", height=640, width=960, stack_size=8, n_items=n, seed=777777,
                          margin_px=0, cell_px=64)
    ds = FocalStackDataset(cfg)
    return {"procedural": procedural_items(ds, n), "middlebury": [rgbd_item(ds, *load_middlebury_motorcycle())]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("models", nargs="*")
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--figures", default=str(FIGURES))
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime threads per model")
    args = ap.parse_args()
    from training.train.heldout import evaluate_model, plot_error_over_field, table

    paths = [Path(m) for m in args.models] or [ROOT / "models" / "reproduce" / f"{n}.onnx" for n in DEFAULT]
    sets = test_sets(args.n)
    results: dict[str, list] = {s: [] for s in sets}
    for path in paths:
        for sname, items in sets.items():
            results[sname].append(evaluate_model(path, items, threads=args.threads))
        print(f"done {path.name}", flush=True)

    for sname, items in sets.items():
        print(f"\n### Test set: {sname} ({len(items)} stack{'s' if len(items) > 1 else ''}, RF50 PSFs)\n")
        print(table(results[sname]))
    out = plot_error_over_field(results["procedural"], Path(args.figures) / "dff_error_over_field.png")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
