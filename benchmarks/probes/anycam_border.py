"""Is the any-camera net right in small tiles because an image border is near? (exploratory, validation only)

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_border --model M.onnx [--n 12] [--crop 128]
        [--margin 128] [--threads 1] [--cache cache/heldout] [--json OUT]

On whole frames the nets put large weakly textured regions at the nearest focus; in 128 px tiles they get them
right (docs/training.md, the seventh run). Every pixel of a training image has an image border within reach of
the net's receptive field; the centre of a whole frame has none. This probe runs the same --crop px squares of the
RF50's validation stacks (training photographs, their own seed) three ways and scores only the square:
- alone, as a tile (its border --crop / 2 px away at most);
- mirrored outwards by --margin px on every side (np.pad "reflect", frames and focus maps alike): the same content
  statistics, the border --margin px further;
- inside its true surroundings, --margin px of the frame on every side.
If the mirrored run is as bad as the true surroundings, the border's distance is what matters; if it is as good as
the tile, the surrounding content is. Squares lie on a grid of --crop steps wherever the margin fits in the frame;
MAE (m) per way, and the paired ratios to the tile with 95 % bootstrap intervals over the stacks. Chooses nothing.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.bench_anycam import LENSES, test_spec

ROOT = Path(__file__).resolve().parents[2]
WAYS = ("tile alone", "mirrored margin", "true surroundings")


def squares(h: int, w: int, crop: int, margin: int) -> list[tuple[int, int]]:
    """Top-left corners of the crop x crop squares on a grid of crop steps with margin px of frame on every side."""
    return [(y, x) for y in range(margin, h - margin - crop + 1, crop)
            for x in range(margin, w - margin - crop + 1, crop)]


def three_ways(infer, stack: np.ndarray, maps: np.ndarray, y: int, x: int, crop: int, margin: int
               ) -> list[np.ndarray]:
    """Depth (crop, crop) of one square: alone, mirrored by margin px, inside margin px of the true frame.
    infer(stack (S, 3, h, w), maps (S + 1, h, w)) -> depth (h, w)."""
    sq = (slice(None), slice(None), slice(y, y + crop), slice(x, x + crop))
    msq = (slice(None), slice(y, y + crop), slice(x, x + crop))
    pad4 = ((0, 0), (0, 0), (margin, margin), (margin, margin))
    inner = (slice(margin, margin + crop), slice(margin, margin + crop))
    alone = infer(stack[sq], maps[msq])
    mirrored = infer(np.pad(stack[sq], pad4, mode="reflect"), np.pad(maps[msq], pad4[1:], mode="reflect"))[inner]
    big = (slice(None), slice(None), slice(y - margin, y + crop + margin), slice(x - margin, x + crop + margin))
    true = infer(stack[big], maps[big[1:]])[inner]
    return [alone, mirrored, true]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--crop", type=int, default=128, help="square side (px; a multiple of 32)")
    ap.add_argument("--margin", type=int, default=128, help="context added on every side (px; a multiple of 32)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"))
    ap.add_argument("--json", type=Path, default=None, help="also write each stack's MAEs here")
    a = ap.parse_args(argv)
    if a.crop % 32 or a.margin % 32 or a.margin > a.crop:
        ap.error("--crop and --margin: multiples of 32, the margin at most the crop (np.pad reflect)")
    from aat_deploy.anycam.model import FocusMapModel, mapping_from_args
    from aat_deploy.eval.stats import paired_ratio
    from aat_deploy.io.atomic import write_text_atomic
    from benchmarks.select_focus_noise import VAL_SEED
    from training.train.testsets import load_test_set

    lens = ROOT / LENSES["rf50"]["lens"]
    spec = replace(test_spec("rf50", "fixed", a.n, real=False), seed=VAL_SEED, photo_split="train")
    items = load_test_set(spec, a.cache, progress=False)["procedural"]
    model = FocusMapModel(a.model, threads=a.threads, mapping=mapping_from_args(lens=lens))
    rows = []
    for i, it in enumerate(items):
        bound = model.bound(model.mapping_optics(it.stack.shape[-1]), it.focus_m)
        h, w = it.stack.shape[2:]
        maps = bound.maps(it.focus_m, h, w)

        def infer(st, mp, bound=bound, focus=it.focus_m):
            return bound.infer(np.ascontiguousarray(st), focus, tile=0, field_xy=np.ascontiguousarray(mp)).depth_m

        err = np.zeros(len(WAYS))
        n_px = 0
        for y, x in squares(h, w, a.crop, a.margin):
            gt = it.depth_m[y:y + a.crop, x:x + a.crop]
            ok = gt > 0
            for k, d in enumerate(three_ways(infer, it.stack, maps, y, x, a.crop, a.margin)):
                err[k] += np.abs(d - gt)[ok].sum()
            n_px += int(ok.sum())
        rows.append((err / max(n_px, 1)).tolist())
        print(f"stack {i}: " + ", ".join(f"{n} {v:.3f}" for n, v in zip(WAYS, rows[-1])), flush=True)
    r = np.asarray(rows)
    print(f"\n#### {a.model.name}, RF50, {len(rows)} validation stacks, {a.crop} px squares, {a.margin} px margin: "
          "MAE (m) over the squares\n")
    print("| " + " | ".join(WAYS) + " |\n" + "|---" * len(WAYS) + "|")
    print("| " + " | ".join(f"{v:.3f}" for v in r.mean(0)) + " |")
    for k in (1, 2):
        est, lo, hi = paired_ratio([{"mae": v} for v in r[:, k]], [{"mae": v} for v in r[:, 0]])
        print(f"\n{WAYS[k]} / tile alone: {est:.3f} [{lo:.3f}, {hi:.3f}]")
    if a.json:
        write_text_atomic(a.json, json.dumps({"model": str(a.model), "crop": a.crop, "margin": a.margin,
                                              "ways": WAYS, "per_stack_mae_m": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
