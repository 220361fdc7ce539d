"""Does an any-camera run fit its training renders better than new renders of the same kind? (exploratory)

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_fit_gap CHECKPOINT [CHECKPOINT ...]
        --stacks cache/stacks [--n 64] [--out results/anycam_fit_gap_v9.json]

For each checkpoint (model.pt, last.pt, or a kept step_NNNNN.pt): the validation MAE (m) on the first N items of its
config's training renders (the ones it trained on, drawn as its validation items are: fixed sweeps, no flips or
mosaics) and on the first N of its validation renders (the same generator with their own seed, never trained on),
one item at a time as the run's own validation scores them (with its focus-range mask); and each item's MAE over
all its pixels, unmasked: their median, mean, largest, the share of the sum the worst 5 % hold, and the worst
item's sweep. A gap that grows over a run while the validation error stalls says the net fits its renders rather
than the task. Training and validation renders only: no held-out lens or test scene.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch


@torch.no_grad()
def per_item_mae(model, ds, n: int) -> tuple[np.ndarray, dict]:
    """(n,) each item's mean |depth - truth| (m) over all its pixels (no focus-range mask), a focus-map net's
    prediction as `evaluate` makes it; and the worst item's particulars (index, its frames' mean in-focus diopters,
    the truth's depth range and the prediction's median, m)."""
    from training.nets.dfvaat import predict

    out, worst = [], {}
    for i in range(min(n, len(ds))):
        it = ds[i]
        pred = predict(model, it["stack"][None].float(), it["focus_diopters"][None].float(),
                       it["defocus_px_per_d"][None].float())["depth_m"][0].numpy()
        gt = np.asarray(it["depth_m"])
        out.append(float(np.abs(pred - gt).mean()))
        if out[-1] == max(out):
            worst = {"index": i, "mae_m": out[-1], "frames_mean_diopters": [
                round(float(v), 4) for v in np.asarray(it["focus_diopters"]).mean((1, 2))],
                "truth_m": [float(gt.min()), float(gt.max())], "predicted_median_m": float(np.median(pred))}
    return np.array(out), worst


def item_spread(e: np.ndarray) -> dict:
    """How a mean of per-item MAEs is made: median, mean, the largest, and the share of the sum the worst 5 % hold."""
    top = np.sort(e)[::-1][:max(1, len(e) // 20)]
    return {"n": len(e), "median_m": float(np.median(e)), "mean_m": float(e.mean()), "max_m": float(e.max()),
            "worst_5pct_share": float(top.sum() / e.sum())}


def gap(checkpoint: Path, stacks: str, n: int, n_train: int | None = None) -> dict:
    from training.train.checkpoint import load
    from training.train.data import make_dataset
    from training.train.evaluate import evaluate
    from training.train.loop import load_trained

    model, cfg = load_trained(checkpoint)
    row = {"checkpoint": str(checkpoint), "run": cfg.name, "step": int(load(checkpoint).get("step", -1)), "n": n,
           "n_train": n_train or n}
    # the training renders drawn as validation draws its items (fixed sweeps, no flips or mosaics): the same cache
    # folder as training reads, since what defines a render is the same
    train = {**cfg.val_data, "seed": cfg.data["seed"], "n_items": cfg.data["n_items"], "only_cached": True}
    for split, data in (("train", train), ("validation", cfg.val_data)):
        ds = make_dataset({**data, "cache_dir": stacks}, cfg.simulator, cfg.lens, cfg.effects)
        if split == "train" and getattr(ds, "cache", None) is not None and ds.cache.name != Path(
                make_dataset({**cfg.data, "cache_dir": stacks}, cfg.simulator, cfg.lens, cfg.effects).cache).name:
            raise ValueError(f"{checkpoint}: its training renders' cache is not what the validation form reads")
        k = (n_train or n) if split == "train" else n
        metrics, _ = evaluate(model, ds, k, cfg.loss.mask_focus_range)
        row[f"{split}_mae_m"] = metrics["mae"]
        e, worst = per_item_mae(model, ds, k)
        row[f"{split}_items"] = {**item_spread(e), "worst": worst}
    row["validation_over_train"] = row["validation_mae_m"] / row["train_mae_m"]
    print(f"{cfg.name} step {row['step']:6d}: MAE training renders {row['train_mae_m']:.4f} m, validation renders "
          f"{row['validation_mae_m']:.4f} m ({row['validation_over_train']:.2f}x); per item, unmasked: median "
          f"{row['train_items']['median_m']:.3f} / {row['validation_items']['median_m']:.3f} m, worst 5 % hold "
          f"{row['train_items']['worst_5pct_share']:.0%} / {row['validation_items']['worst_5pct_share']:.0%} of the "
          f"sum, largest {row['train_items']['max_m']:.1f} / {row['validation_items']['max_m']:.1f} m", flush=True)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoints", type=Path, nargs="+", help="runs' model.pt, last.pt or kept step_NNNNN.pt")
    ap.add_argument("--stacks", required=True, help="the runs' render cache (their config's cache_dir)")
    ap.add_argument("--n", type=int, default=64, help="items of each split (a run's validation has val_items)")
    ap.add_argument("--n-train", type=int, help="items of the training renders (default --n)")
    ap.add_argument("--out", type=Path, help="JSON of the rows")
    a = ap.parse_args(argv)
    if a.n < 1 or (a.n_train is not None and a.n_train < 1):
        ap.error(f"--n, --n-train: at least 1, got {a.n}, {a.n_train}")
    from benchmarks.probes.anycam_precise_bn import refuse_missing_or_existing

    refuse_missing_or_existing(ap, a.checkpoints, a.out)
    torch.set_num_threads(1)
    rows = [gap(c, a.stacks, a.n, a.n_train) for c in a.checkpoints]
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(a.out, json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
