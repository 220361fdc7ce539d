"""How the any-camera model's error depends on the size of the images it runs on (exploratory).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_tiles --model models/reproduce/dfv_aat_v1.onnx
        [--lens paper50] [--n 8] [--tiles 0,256,128] [--overlaps 32,16,0] [--split test|validation] [--json OUT]
        [--threads 2]

Runs the model (given the lens's best-focus map, as `bench_anycam`'s "dfv_aat, lens map") on the first --n stacks of
a lens's fixed-protocol held-out set (cached by bench_anycam) on whole frames (tile 0) and in overlapping tiles of
each size (`FocusMapModel.infer(tile=T)`, a quarter of the tile overlapping), beside the classical method with the
same map. Prints each stack's MAE (m) and the means. The test stacks are test scenes, so on them this probe chooses
nothing: it showed that the first run's net, trained on 128 px images, is worse the larger the image
(docs/training.md). `--split validation` scores validation stacks instead (training photographs, their own seed
benchmarks.select_focus_noise.VAL_SEED; rendered on first use): what may choose a setting, on the RF50 only (the
held-out lenses choose nothing). `--overlaps` runs every tile size at each of these overlaps (px; the runtime caps it
at a quarter of the tile) instead of a quarter of the tile; the table then also gives each setting's pixels run per
frame pixel (the tiling's cost, `aat_deploy.infer.model.tile_grid`) and its MAE over the first setting's, paired over
the stacks with a 95 % bootstrap interval (`aat_deploy.eval.stats.paired_ratio`); --json writes each stack's MAEs.
"""

from __future__ import annotations

import argparse
import json
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
    ap.add_argument("--overlaps", default=None,
                    help="overlaps (px) to run every tile size at, comma-separated (default: a quarter of the tile)")
    ap.add_argument("--split", choices=("test", "validation"), default="test")
    ap.add_argument("--json", type=Path, default=None, help="also write each stack's MAEs here")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime threads (1 in a heavy-job lane)")
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"))
    a = ap.parse_args(argv)
    if a.split == "validation" and a.lens != "rf50":
        ap.error("--split validation: the RF50 only (the held-out lenses choose nothing)")
    from aat_deploy.anycam.model import FocusMapModel, mapping_from_args
    from aat_deploy.focus import classical_depth
    from aat_deploy.focus.bestfocus import for_lens

    tiles = [int(t) for t in a.tiles.split(",")]
    settings = [(t, o) for t in tiles
                for o in ([t // 4] if a.overlaps is None or t == 0 else [int(v) for v in a.overlaps.split(",")])]
    lens = ROOT / LENSES[a.lens]["lens"]
    items = fixed_stacks(a.lens, a.split, a.n, a.cache)
    model = FocusMapModel(a.model, threads=a.threads, mapping=mapping_from_args(lens=lens))
    fmap, _ = for_lens(lens, compute=False)
    labels = [("whole frame" if t == 0 else f"tiles of {t} px" + (f", {o} overlapping" if a.overlaps else ""))
              for t, o in settings] + ["classical, lens map"]
    rows = []
    for it in items:
        bound = model.bound(model.mapping_optics(it.stack.shape[-1]), it.focus_m)
        ok = it.depth_m > 0
        preds = [bound.infer(it.stack, it.focus_m, tile=t, overlap=o).depth_m for t, o in settings]
        preds.append(classical_depth(it.stack, it.focus_m, fmap).depth_m)
        rows.append([float(np.abs(d - it.depth_m)[ok].mean()) for d in preds])
        print(" ".join(f"{v:.3f}" for v in rows[-1]), file=sys.stderr, flush=True)
    what = "held-out" if a.split == "test" else "validation"
    print(f"\n#### {a.model.name} on {a.lens}, fixed protocol, first {len(items)} {what} stacks: MAE (m)\n")
    print("| " + " | ".join(labels) + " |\n" + "|---" * len(labels) + "|")
    print("| " + " | ".join(f"{v:.3f}" for v in np.mean(rows, 0)) + " |")
    if a.overlaps is not None:
        from aat_deploy.eval.stats import fmt_interval, paired_ratio

        h, w = items[0].stack.shape[2:]
        cost = [px_run_per_px(h, w, t, o, model.size_multiple) for t, o in settings]
        per = [[{"mae": r[i]} for r in rows] for i in range(len(labels))]
        print("| " + " | ".join(f"{c:.2f} px run per px ({h} x {w})" for c in cost) + " | |")
        print("| " + " | ".join(fmt_interval(paired_ratio(p, per[0])) + " x the first" for p in per) + " |")
    if a.json is not None:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(a.json, json.dumps({"model": str(a.model), "lens": a.lens, "split": a.split,
                                              "labels": labels, "mae_m": rows}, indent=1))
    return 0


def fixed_stacks(lens_key: str, split: str, n: int, cache, stack_size: int | None = None) -> list:
    """The first n procedural stacks of a lens's fixed protocol: its held-out test scenes ("test"), or validation
    scenes of training photographs with their own seed ("validation", the RF50 only: what may choose a setting).
    stack_size: frames per stack over the protocol's range (default the lens's own, 8 for the RF50)."""
    from training.train.testsets import load_test_set

    spec = test_spec(lens_key, "fixed", n, stack_size=stack_size, real=False)
    if split == "validation":
        from dataclasses import replace

        from benchmarks.select_focus_noise import VAL_SEED

        spec = replace(spec, seed=VAL_SEED, photo_split="train")
    return load_test_set(spec, cache, progress=False)["procedural"]


def px_run_per_px(h: int, w: int, tile: int, overlap: int, multiple: int) -> float:
    """Pixels the net runs per frame pixel in tiles (`DfFModel.infer`'s layout; 1 for whole frames, tile 0)."""
    from aat_deploy.infer.model import tile_grid

    if tile == 0 or (h <= tile and w <= tile):
        return 1.0
    side, _, ys, xs = tile_grid(h, w, tile, overlap, multiple)
    return len(ys) * len(xs) * side * side / (h * w)


if __name__ == "__main__":
    sys.exit(main())
