"""Why the any-camera fine-tunes do not lower their own objective (issue 35): the pixels beyond their frames' range.

    OMP_NUM_THREADS=1 nice -n 10 python -m benchmarks.probes.anycam_loss_range [--config configs/anycam/dfv_aat_v4.json]
        [--init checkpoints/dfv_aat_v1/last.pt] [--only shares,modes,mosaic,ft] [--batches 24] [--steps 120]
        [--lr 1e-4] [--weights 1,0] [--seed 2] [--mosaic P]

A pixel whose true diopters lie outside its own frames' range (`training.train.loss.focus_map_loss`'s `inside`) has
an error no interpolation of the frames removes (at least its distance to the nearest end frame) and an L1 gradient
that never fades: it always pushes the softmax further onto the end frame. Rows (results/anycam_loss_range.json,
written after each):
- `shares`: on `--batches` training batches made as the run makes them (the config's data and mosaics), the starting
  weights in train mode as in a step: the share of valid pixels out of range, their share of the loss, and the
  gradient of the loss split into the in-range and the out-of-range pixels' parts (g = g_in + g_out, both
  normalised by all valid pixels as the loss): |g_out| / |g|, |g_in| / |g| and cos(g_in, g_out);
- `modes`: the loss on `--batches` held batches (another seed) in train mode (BatchNorm on the batch's statistics,
  what the optimiser sees) and in eval mode (running statistics, what validation and the runtime see), split into
  in-range and out-of-range pixels, with the out-of-range pixels' floor (their distance to the nearest end frame);
- `mosaic`: the same held batches' items laid out 2 x 2 (as 50 % of the run's batches) against one by one, eval
  mode, in-range loss: does a quadrant lose anything by its neighbours;
- `ft_w{W}`: the starting weights after `--steps` Adam steps (lr `--lr`, fresh moments, the run's clipping) with
  loss.out_of_range_weight W (1: the runs' loss, 0: out-of-range pixels left out), the same batches for every W
  (benchmarks.probes.anycam_finetune.fine_tune; `--seed` picks the batches, `--mosaic` their chance of a 2 x 2
  layout), and then the held batches' loss parts in eval mode. Their weights
  go to cache/probes/anycam_loss_range/ for `benchmarks.anycam_val_baseline --frames-set --checkpoint`.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def held_batches(dataset, n: int, seed: int = 5, mosaic: float | None = None) -> list[dict]:
    """n training batches of 4 made as the run makes them (the dataset's crops, flips, subsets and camera
    processing), fixed by `seed`; mosaic: override the dataset's mosaic chance (0 or 1 to force)."""
    import numpy as np
    import torch

    ds = copy.copy(dataset)
    if mosaic is not None:
        ds.cfg = dataclasses.replace(dataset.cfg, mosaic=mosaic)
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    out = []
    for _ in range(n):
        pos = rng.choice(len(ds), 4, replace=False)
        out.append(ds.collate([ds[int(p)] for p in pos]))
    return out


def loss_parts(model, batches: list[dict], train_mode: bool, loss_cfg) -> dict:
    """Mean over batches of the run's loss (all valid pixels, both levels) and of its finest level's L1 in frame
    spacings over the in-range and the out-of-range pixels; train_mode: BatchNorm on each batch's statistics (on a
    copy: the running statistics stay), else eval mode."""
    import numpy as np
    import torch

    from training.nets.dfvaat import train_levels
    from training.train.loss import focus_map_loss

    m = copy.deepcopy(model).train(train_mode)
    rows = []
    with torch.no_grad():
        for b in batches:
            levels = train_levels(m, b)
            total, parts = focus_map_loss(levels, b, loss_cfg)
            rows.append((float(total), parts["frames_l1"], *_split(levels[0][3], b)))
    r = np.array(rows, np.float64)
    return {"loss": float(np.nanmean(r[:, 0])), "frames_l1_all": float(np.nanmean(r[:, 1])),
            "frames_l1_in_range": float(np.nanmean(r[:, 2])), "frames_l1_out_of_range": float(np.nanmean(r[:, 3])),
            "out_of_range_pixel_share": float(np.nanmean(r[:, 4])), "out_of_range_floor": float(np.nanmean(r[:, 5]))}


def _split(diopters, batch) -> tuple[float, float, float, float]:
    """(in-range L1, out-of-range L1 in frame spacings, share of valid pixels out of range, the out-of-range
    pixels' floor: their mean distance to the nearest end of their frame range, in frame spacings) of one level's
    interpolated diopters, as focus_map_loss defines them."""
    import torch

    from training.train.loss import depth_mask, masked_l1

    gt, fd = batch["depth_m"], batch["focus_diopters"]
    mask = depth_mask(gt)
    spacing = ((fd.max(1).values - fd.min(1).values) / max(fd.shape[1] - 1, 1)).clamp_min(1e-3)
    inv_gt = 1.0 / torch.where(mask, gt, torch.ones_like(gt))
    inside = mask & (inv_gt <= fd.max(1).values) & (inv_gt >= fd.min(1).values)
    outside = mask & ~inside
    f = lambda sel: float(masked_l1(diopters / spacing, inv_gt / spacing, sel)) if sel.any() else float("nan")  # noqa: E731
    nearest_end = torch.minimum(torch.maximum(inv_gt, fd.min(1).values), fd.max(1).values)
    return (f(inside), f(outside), float(outside.sum() / mask.sum().clamp_min(1)),
            float(masked_l1(nearest_end / spacing, inv_gt / spacing, outside)) if outside.any() else float("nan"))


def gradient_shares(model, batches: list[dict], loss_cfg) -> dict:
    """Per batch, in train mode (a copy): the gradient of the run's loss split into its in-range and out-of-range
    pixels' parts (out_of_range_weight 0 and the rest), each scaled as in the whole loss; means over batches."""
    import numpy as np
    import torch

    from training.nets.dfvaat import train_levels
    from training.train.loss import focus_map_loss

    m = copy.deepcopy(model).train()
    params = [p for p in m.parameters() if p.requires_grad]
    only_in = dataclasses.replace(loss_cfg, out_of_range_weight=0.0)
    rows = []
    for b in batches:
        def grad(cfg):
            levels = train_levels(m, b)
            loss, _ = focus_map_loss(levels, b, cfg)
            return torch.cat([g.reshape(-1) for g in torch.autograd.grad(loss, params)]), levels
        g_all, levels = grad(loss_cfg)
        g_in_own, _ = grad(only_in)  # normalised by the in-range pixels only: rescale to all valid pixels
        share = _split(levels[0][3].detach(), b)[2]
        g_in = g_in_own * (1.0 - share)
        g_out = g_all - g_in
        n = float(g_all.norm())
        rows.append((float(g_out.norm()) / n, float(g_in.norm()) / n,
                     float(torch.nn.functional.cosine_similarity(g_in, g_out, 0)), share, n))
    r = np.array(rows, np.float64)
    return {"grad_out_over_all": float(r[:, 0].mean()), "grad_in_over_all": float(r[:, 1].mean()),
            "cos_in_out": float(r[:, 2].mean()), "cos_in_out_p10_p90": np.percentile(r[:, 2], [10, 90]).tolist(),
            "out_of_range_pixel_share": float(r[:, 3].mean()), "grad_norm_median": float(np.median(r[:, 4])),
            "batches": len(rows)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=ROOT / "configs/anycam/dfv_aat_v4.json")
    ap.add_argument("--init", type=Path, default=ROOT / "checkpoints/dfv_aat_v1/last.pt")
    ap.add_argument("--only", default="shares,modes,mosaic,ft")
    ap.add_argument("--batches", type=int, default=24)
    ap.add_argument("--steps", type=int, default=120)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--weights", default="1,0", help="out_of_range_weight of the fine-tune rows")
    ap.add_argument("--seed", type=int, default=2, help="the fine-tunes' batches (2: anycam_finetune's)")
    ap.add_argument("--mosaic", type=float, default=None, help="the fine-tunes' mosaic chance (default the config's)")
    ap.add_argument("--out", type=Path, default=ROOT / "results/anycam_loss_range.json")
    a = ap.parse_args(argv)

    import torch

    from benchmarks.probes.anycam_finetune import fine_tune
    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.nets.model import build_model
    from training.train.checkpoint import load
    from training.train.config import load_config

    torch.set_num_threads(1)
    cfg = load_config(a.config)
    train = AnyCamDataset(AnyCamConfig(**{**dict(cfg.data), "only_cached": True}))
    ft_data = copy.copy(train)
    if a.mosaic is not None:
        ft_data.cfg = dataclasses.replace(train.cfg, mosaic=a.mosaic)
    tag = ("" if a.seed == 2 else f"_seed{a.seed}") + ("" if a.mosaic is None else f"_mosaic{a.mosaic:g}")
    start = build_model(cfg.net, cfg.size, cfg.field_channels)
    start.load_state_dict(load(a.init)["model"])
    start.eval()
    rows = json.loads(a.out.read_text()) if a.out.is_file() else {}
    rows["meta"] = {"config": str(a.config), "init": str(a.init), "batches": a.batches, "steps": a.steps, "lr": a.lr}
    only = {s for s in a.only.split(",") if s}

    def put(key, value):
        rows[key] = value
        print(f"{key}: {json.dumps(value)}", flush=True)
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(rows, indent=1))

    held = held_batches(train, a.batches, seed=5)
    t = time.perf_counter()
    if "shares" in only:
        put("shares", {**gradient_shares(start, held_batches(train, a.batches, seed=6), cfg.loss),
                       "s": round(time.perf_counter() - t, 1)})
    if "modes" in only:
        put("modes", {"train_mode": loss_parts(start, held, True, cfg.loss),
                      "eval_mode": loss_parts(start, held, False, cfg.loss)})
    if "mosaic" in only:
        put("mosaic", {"one_by_one": loss_parts(start, held_batches(train, a.batches, 5, mosaic=0.0), False, cfg.loss),
                       "mosaics": loss_parts(start, held_batches(train, a.batches, 5, mosaic=1.0), False, cfg.loss)})
    if "ft" in only:
        saved = ROOT / "cache/probes/anycam_loss_range"
        saved.mkdir(parents=True, exist_ok=True)
        put("ft_start", {"eval_mode": loss_parts(start, held, False, cfg.loss)})
        for w in (float(x) for x in a.weights.split(",")):
            t = time.perf_counter()
            lc = dataclasses.replace(cfg.loss, out_of_range_weight=w)
            m, mean_loss = fine_tune(start, ft_data, a.steps, a.lr, False, cfg.grad_clip, lc, seed=a.seed)
            path = saved / f"ft_w{w:g}_lr{a.lr:g}_{a.steps}{tag}.pt"
            torch.save({"model": m.state_dict(), "steps": a.steps, "lr": a.lr, "out_of_range_weight": w}, path)
            put(f"ft_w{w:g}{tag}", {"seed": a.seed, "mosaic": ft_data.cfg.mosaic,
                                    "checkpoint": str(path.relative_to(ROOT)), "train_frames_l1_mean": mean_loss,
                                    "eval_mode": loss_parts(m, held, False, cfg.loss),
                                    "s": round(time.perf_counter() - t, 1)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
