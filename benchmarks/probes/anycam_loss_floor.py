"""The part of the any-camera training loss no net can remove (exploratory, issue 35).

    OMP_NUM_THREADS=1 python -m benchmarks.probes.anycam_loss_floor [--configs configs/anycam/dfv_aat.json
        configs/anycam/dfv_aat_v3.json] [--batches 50]

The net's head interpolates each pixel's in-focus diopters (depth = 1 / sum p_s D_s), so it cannot place a pixel
outside the range of the frames a stack shows; `training.train.loss.focus_map_loss` scores every pixel in units of
the stack's frame spacing there. Per item of training batches made as the run makes them (`AnyCamDataset.collate`,
no mosaics; cached renders only), this prints the mean over pixels of how far the ground truth lies outside the
stack's range, in frame spacings: a floor of the frame loss, per kind of item (wide sweeps or not).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def floors(config: Path, batches: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(per-item loss floor in frame spacings, whether each item is a wide sweep) over `batches` batches of 4."""
    import torch

    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.train.config import load_config

    cfg = load_config(config)
    ds = AnyCamDataset(AnyCamConfig(**{**dict(cfg.data), "mosaic": 0.0, "only_cached": True}))
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    out, wide = [], []
    for _ in range(batches):
        pos = rng.choice(len(ds), 4, replace=False)
        b = ds.collate([ds[int(p)] for p in pos])
        fd = b["focus_diopters"].numpy().astype(np.float64)  # (B, S, H, W)
        inv = 1.0 / b["depth_m"].numpy().astype(np.float64)
        lo, hi = fd.min(1), fd.max(1)
        spacing = np.maximum((hi - lo) / max(fd.shape[1] - 1, 1), 1e-3)  # as focus_map_loss
        beyond = np.maximum(lo - inv, 0.0) + np.maximum(inv - hi, 0.0)
        out.extend((beyond / spacing).mean(axis=(1, 2)).tolist())
        wide.extend(ds.is_wide(ds.items[int(p)]) for p in pos)
    return np.array(out), np.array(wide, bool)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configs", nargs="+", type=Path,
                    default=[ROOT / "configs/anycam/dfv_aat.json", ROOT / "configs/anycam/dfv_aat_v3.json"])
    ap.add_argument("--batches", type=int, default=50)
    a = ap.parse_args(argv)
    print("| config | items | loss floor (frame spacings) p50 / p90 / p99 / max | mean | mean, wide sweeps "
          "| mean, other items |\n|---|---|---|---|---|---|")
    for c in a.configs:
        f, w = floors(c, a.batches)
        mw = f"{f[w].mean():.2f} ({w.sum()})" if w.any() else "-"
        print(f"| {c.stem} | {f.size} | " + " / ".join(f"{v:.2f}" for v in np.percentile(f, [50, 90, 99]))
              + f" / {f.max():.1f} | {f.mean():.2f} | {mw} | {f[~w].mean():.2f} ({(~w).sum()}) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
