"""Where the any-camera net goes wrong on whole frames and not in tiles: a picture (exploratory, validation only).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_errmap --model M.onnx --stacks 3,4,9 --out FIG.png
        [--tile 128] [--threads 1] [--cache cache/heldout]

For each chosen RF50 validation stack (training photographs, their own seed, as `anycam_tiles --split validation`):
its middle frame, the true depth (m), the net's depth on the whole frame and in --tile px tiles (the runtime's
overlap, an eighth of the tile), and where the whole frame's absolute error exceeds the tiles' (m). Chooses nothing.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.bench_anycam import LENSES, test_spec

ROOT = Path(__file__).resolve().parents[2]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--stacks", default="3,4,9", help="indices of the RF50 validation stacks (comma-separated)")
    ap.add_argument("--tile", type=int, default=128)
    ap.add_argument("--out", type=Path, required=True, help="the PNG to write (refused if it exists)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"))
    a = ap.parse_args(argv)
    if a.out.exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aat_deploy.anycam.model import FocusMapModel, mapping_from_args, own_tiles
    from aat_deploy.io.atomic import write_bytes_atomic
    from benchmarks.select_focus_noise import VAL_SEED
    from training.train.testsets import load_test_set

    idx = [int(i) for i in a.stacks.split(",")]
    lens = ROOT / LENSES["rf50"]["lens"]
    spec = replace(test_spec("rf50", "fixed", max(idx) + 1, real=False), seed=VAL_SEED, photo_split="train")
    items = load_test_set(spec, a.cache, progress=False)["procedural"]
    model = FocusMapModel(a.model, threads=a.threads, mapping=mapping_from_args(lens=lens))
    tile, overlap = own_tiles(a.tile)
    fig, ax = plt.subplots(len(idx), 5, figsize=(20, 3.2 * len(idx)), squeeze=False)
    for r, i in enumerate(idx):
        it = items[i]
        bound = model.bound(model.mapping_optics(it.stack.shape[-1]), it.focus_m)
        whole = bound.infer(it.stack, it.focus_m, tile=0).depth_m
        tiled = bound.infer(it.stack, it.focus_m, tile=tile, overlap=overlap).depth_m
        gt, ok = it.depth_m, it.depth_m > 0
        lo, hi = np.percentile(gt[ok], [1, 99])
        mid = np.clip(it.stack[len(it.focus_m) // 2].transpose(1, 2, 0), 0, 1)
        ax[r, 0].imshow(mid)
        ax[r, 0].set_title(f"validation stack {i}: middle frame")
        ax[r, 1].imshow(gt, vmin=lo, vmax=hi)
        ax[r, 1].set_title(f"true depth, {lo:.1f}-{hi:.1f} m")
        ax[r, 2].imshow(whole, vmin=lo, vmax=hi)
        ax[r, 2].set_title(f"whole frame: MAE {np.abs(whole - gt)[ok].mean():.3f} m")
        ax[r, 3].imshow(tiled, vmin=lo, vmax=hi)
        ax[r, 3].set_title(f"{tile} px tiles: MAE {np.abs(tiled - gt)[ok].mean():.3f} m")
        im = ax[r, 4].imshow(np.where(ok, np.abs(whole - gt) - np.abs(tiled - gt), 0), cmap="RdBu_r", vmin=-2, vmax=2)
        ax[r, 4].set_title("|whole error| - |tile error| (m)")
        fig.colorbar(im, ax=ax[r, 4])
        print(f"stack {i}: whole {np.abs(whole - gt)[ok].mean():.3f} m, tiles {np.abs(tiled - gt)[ok].mean():.3f} m",
              flush=True)
    for x in ax.ravel():
        x.axis("off")
    fig.suptitle(f"{a.model.name} on RF50 validation stacks (960 x 640; dark = near)")
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=40)
    write_bytes_atomic(a.out, buf.getvalue())
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
