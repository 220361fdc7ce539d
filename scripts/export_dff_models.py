"""Export the trained DfF runs to the ONNX models shipped in models/ (metadata per docs/contracts.md).

    python -m scripts.export_dff_models [--runs runs] [--force] [NAME ...]
    python -m scripts.export_dff_models --runs cache/runs/table2 paper50_dfvnet_aat ...   (scripts/train_table2.sh)

NAME defaults to the four runs of scripts/train_dff_models.sh; each RUNS/NAME/model.pt -> OUT/NAME.onnx (OUT: models/,
or models/reproduce/ for baselines, ablations and superseded models; see models/README.md) with an
onnxruntime-vs-torch parity check at three shapes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NAMES = ["dff_dfvnet_aat", "dff_dfvnet_thin", "dff_aifnet_aat", "dff_aifnet_thin"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("names", nargs="*", default=NAMES)
    ap.add_argument("--runs", default=str(ROOT / "runs"))
    ap.add_argument("--force", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "models"), help="folder of the .onnx files (default models/)")
    args = ap.parse_args()
    from training.train.export import export_checkpoint

    for name in args.names:
        ckpt = Path(args.runs) / name / "model.pt"
        if not ckpt.is_file():
            print(f"{name}: no {ckpt} (train it first)")
            continue
        dst = Path(args.out) / f"{name}.onnx"
        _, err = export_checkpoint(ckpt, dst, force=args.force)
        print(f"{name}: {dst}, ORT vs torch {err:.2e} relative")


if __name__ == "__main__":
    main()
