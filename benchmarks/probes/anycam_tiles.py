"""How the any-camera model's error depends on the size of the images it runs on (exploratory).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_tiles --model models/reproduce/dfv_aat_v1.onnx
        [--lens paper50] [--n 8] [--tiles 0,256,128] [--split test|validation]

Runs the model (given the lens's best-focus map, as `bench_anycam`'s "dfv_aat, lens map") on the first --n stacks of
a lens's fixed-protocol held-out set (cached by bench_anycam) on whole frames (tile 0) and in overlapping tiles of
each size (`FocusMapModel.infer(tile=T)`, a quarter of the tile overlapping), beside the classical method with the
same map. Prints each stack's MAE (m) and the means. The test stacks are test scenes, so on them this probe chooses
nothing: it showed that the first run's net, trained on 128 px images, is worse the larger the image
(docs/training.md). `--split validation` scores validation stacks instead (training photographs, their own seed
benchmarks.select_focus_noise.VAL_SEED; rendered on first use): what may choose a setting, on the RF50 only (the
held-out lenses choose nothing).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from benchmarks.bench_anycam import LENSES, test_spec

ROOT = Path(__file__).resolve().parents[2]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--lens", choices=sorted(LENSES), default="paper50")
    ap.add_argument("--n", type=int, default=8)
    ap.add_argument("--tiles", default="0,256,128", help="tile sides (px; 0 = whole frames), comma-separated")
    ap.add_argument("--split", choices=("test", "validation"), default="test")
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"))
    a = ap.parse_args(argv)
    if a.split == "validation" and a.lens != "rf50":
        ap.error("--split validation: the RF50 only (the held-out lenses choose nothing)")
    from aat_deploy.anycam.model import FocusMapModel, mapping_from_args
    from aat_deploy.focus import classical_depth
    from aat_deploy.focus.bestfocus import for_lens
    from training.train.testsets import load_test_set

    tiles = [int(t) for t in a.tiles.split(",")]
    lens = ROOT / LENSES[a.lens]["lens"]
    spec = test_spec(a.lens, "fixed", a.n, real=False)
    if a.split == "validation":
        from dataclasses import replace

        from benchmarks.select_focus_noise import VAL_SEED

        spec = replace(spec, seed=VAL_SEED, photo_split="train")
    items = load_test_set(spec, a.cache, progress=False)["procedural"]
    model = FocusMapModel(a.model, threads=2, mapping=mapping_from_args(lens=lens))
    fmap, _ = for_lens(lens, compute=False)
    labels = ["whole frame" if t == 0 else f"tiles of {t} px" for t in tiles] + ["classical, lens map"]
    rows = []
    for it in items:
        bound = model.bound(model.mapping_optics(it.stack.shape[-1]), it.focus_m)
        ok = it.depth_m > 0
        preds = [bound.infer(it.stack, it.focus_m, tile=t, overlap=t // 4).depth_m for t in tiles]
        preds.append(classical_depth(it.stack, it.focus_m, fmap).depth_m)
        rows.append([float(np.abs(d - it.depth_m)[ok].mean()) for d in preds])
        print(" ".join(f"{v:.3f}" for v in rows[-1]), file=sys.stderr, flush=True)
    what = "held-out" if a.split == "test" else "validation"
    print(f"\n#### {a.model.name} on {a.lens}, fixed protocol, first {len(items)} {what} stacks: MAE (m)\n")
    print("| " + " | ".join(labels) + " |\n" + "|---" * len(labels) + "|")
    print("| " + " | ".join(f"{v:.3f}" for v in np.mean(rows, 0)) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
