"""Why every fine-tune of the any-camera net from the first run's weights validates worse at once (issue 35).

    OMP_NUM_THREADS=1 nice -n 15 python -m benchmarks.probes.anycam_finetune [--config configs/anycam/dfv_aat_v4.json]
        [--init checkpoints/dfv_aat_v1/last.pt] [--tuned cache/runs/dfv_aat_v4/best.pt] [--only ROW,ROW]
        [--train-config CONFIG] [--mosaic P] [--steps 120] [--batches 40] [--train-items 32]
    ... --compare CHECKPOINT ... [--compare-split val|train]      # per item: which items carry a change

The fourth run (lr 1e-4) scores 0.536 m on its 64 validation items after 500 steps where its starting weights score
0.442 m. Each row is the validation of `--config` (`training.train.evaluate`, pixels inside each focus range) of:
- `init`: the starting weights as they are;
- `init_bn_*`: the starting weights with only their BatchNorm running statistics moved: forward passes in train
  mode (no gradient, i.e. lr 0) over `--batches` training batches made as the run makes them
  (`AnyCamDataset.collate`, with the config's mosaics, and without);
- `tuned`, `tuned_v1_bn`: the fine-tuned weights (`--tuned`) as they are, and with the starting weights' running
  statistics put back;
- `init_on_train`: the starting weights on `--train-items` training renders read as validation items;
- `ft_*`: the starting weights after `--steps` Adam steps of the run's loss and clipping on the same training
  batches (lr 1e-4 or 1e-5, constant; fresh Adam moments as an `init` run starts, or `_adam` the starting
  checkpoint's own; `_bnfrozen` BatchNorm in eval mode; the data of `--config` or of `--train-config`, `--mosaic`
  overriding its mosaic chance). Their weights go to cache/probes/anycam_finetune/ for `--compare`.
`--compare` scores per validation item the starting weights and each checkpoint, in metres and in the loss's units
(|interpolated diopters - true| / frame spacing, pixels inside the focus range), and gives paired ratios with 95 %
bootstrap intervals over the items and the five items that change most.
Results: results/anycam_finetune.json (rows, written after each) and results/anycam_finetune_items.json (--compare).
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


def bn_buffers(model) -> dict:
    """The BatchNorm running statistics of `model` (name -> tensor copy)."""
    return {k: v.clone() for k, v in model.state_dict().items()
            if k.endswith(("running_mean", "running_var", "num_batches_tracked"))}


def move_bn_stats(model, dataset, batches: int, mosaic: float, seed: int = 1):
    """A copy of `model` whose BatchNorm running statistics took `batches` training batches of 4 in train mode (as
    the run's steps do), with no weight change. mosaic: the chance a batch is laid out 2 x 2 (the config's, or 0)."""
    import numpy as np
    import torch

    from training.nets.dfvaat import train_levels

    m = copy.deepcopy(model).train()
    ds = copy.copy(dataset)
    ds.cfg = dataclasses.replace(dataset.cfg, mosaic=mosaic)
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    with torch.no_grad():
        for _ in range(batches):
            pos = rng.choice(len(ds), 4, replace=False)
            train_levels(m, ds.collate([ds[int(p)] for p in pos]))
    return m.eval()


def fine_tune(model, dataset, steps: int, lr: float, freeze_bn: bool, grad_clip: float, loss_cfg, seed: int = 2,
              adam_state: dict | None = None):
    """A copy of `model` after `steps` Adam steps (constant `lr`, the run's clipping and loss) on training batches of
    4 made as the run makes them; freeze_bn: BatchNorm layers in eval mode (running statistics used and kept);
    adam_state: the starting checkpoint's optimizer state (its moments), else fresh moments as an `init` run starts.
    The batches depend on `seed` only, so variants see the same data."""
    import numpy as np
    import torch

    from training.nets.dfvaat import train_levels
    from training.train.loss import focus_map_loss

    m = copy.deepcopy(model).train()
    if freeze_bn:
        for mod in m.modules():
            if isinstance(mod, torch.nn.modules.batchnorm._BatchNorm):
                mod.eval()
    opt = torch.optim.Adam(m.parameters(), lr=lr)
    if adam_state is not None:
        opt.load_state_dict(adam_state)
        for g in opt.param_groups:
            g["lr"] = lr
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    losses = []
    for _ in range(steps):
        pos = rng.choice(len(dataset), 4, replace=False)
        batch = dataset.collate([dataset[int(p)] for p in pos])
        loss, parts = focus_map_loss(train_levels(m, batch), batch, loss_cfg)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(m.parameters(), grad_clip)
        opt.step()
        losses.append(parts["frames_l1"])
    return m.eval(), float(np.mean(losses))


def per_item(model, dataset, n: int) -> list[tuple[float, float]]:
    """Per validation item: (MAE in metres, L1 of the interpolated diopters in frame spacings), both over the pixels
    inside the stack's focus range (the validation's mask; the second is the run's loss `frames_l1_in_range`)."""
    import numpy as np
    import torch

    from training.nets.dfvaat import predict

    out = []
    with torch.no_grad():
        for i in range(n):
            it = dataset[i]
            fd = it["focus_diopters"].numpy().astype(np.float64)
            gt = it["depth_m"].numpy().astype(np.float64)
            focus = it["focus_m"].numpy()
            d = predict(model.eval(), it["stack"][None], it["focus_diopters"][None],
                        it["defocus_px_per_d"][None])["depth_m"][0].numpy().astype(np.float64)
            inside = (gt >= focus.min()) & (gt <= focus.max()) & np.isfinite(gt) & (gt > 0)
            spacing = np.maximum((fd.max(0) - fd.min(0)) / max(fd.shape[0] - 1, 1), 1e-3)
            out.append((float(np.abs(d - gt)[inside].mean()),
                        float((np.abs(1 / np.maximum(d, 1e-9) - 1 / np.where(inside, gt, 1)) / spacing)[inside].mean()))
                       if inside.any() else (float("nan"), float("nan")))
    return out


def compare_items(a_: list, b_: list) -> dict:
    """How the change of validation MAE between two nets spreads over the items, and whether the loss agrees."""
    import numpy as np

    from aat_deploy.eval.stats import paired_ratio

    a_, b_ = np.array(a_), np.array(b_)
    ok = np.isfinite(a_).all(1) & np.isfinite(b_).all(1)
    dm, dl = b_[ok, 0] - a_[ok, 0], b_[ok, 1] - a_[ok, 1]
    order = np.argsort(-np.abs(dm))
    top = np.flatnonzero(ok)[order[:5]]
    rank = lambda x: np.argsort(np.argsort(x))  # noqa: E731
    return {"items": int(ok.sum()), "mae_a": float(a_[ok, 0].mean()), "mae_b": float(b_[ok, 0].mean()),
            "frames_a": float(a_[ok, 1].mean()), "frames_b": float(b_[ok, 1].mean()),
            "items_worse_m": int((dm > 0).sum()), "items_worse_frames": int((dl > 0).sum()),
            "share_of_mae_change_top5": float(dm[order[:5]].sum() / dm.sum()) if dm.sum() else float("nan"),
            "top5_items": top.tolist(), "top5_delta_m": dm[order[:5]].round(3).tolist(),
            "top5_delta_frames": dl[order[:5]].round(3).tolist(),
            "spearman_dmae_dframes": float(np.corrcoef(rank(dm), rank(dl))[0, 1]),
            "ratio_mae_b_over_a": paired_ratio([{"v": v} for v in b_[ok, 0]], [{"v": v} for v in a_[ok, 0]], "v"),
            "ratio_frames_b_over_a": paired_ratio([{"v": v} for v in b_[ok, 1]], [{"v": v} for v in a_[ok, 1]], "v")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=ROOT / "configs/anycam/dfv_aat_v4.json")
    ap.add_argument("--init", type=Path, default=ROOT / "checkpoints/dfv_aat_v1/last.pt")
    ap.add_argument("--tuned", type=Path, default=ROOT / "cache/runs/dfv_aat_v4/best.pt")
    ap.add_argument("--batches", type=int, default=40)
    ap.add_argument("--train-config", type=Path, default=None,
                    help="the training batches' data from this config (default --config): e.g. the first run's")
    ap.add_argument("--mosaic", type=float, default=None,
                    help="the training batches' chance of a 2 x 2 mosaic (default: the config's)")
    ap.add_argument("--steps", type=int, default=120, help="fine-tune rows: Adam steps from the starting weights")
    ap.add_argument("--train-items", type=int, default=32)
    ap.add_argument("--val-items", type=int, default=64)
    ap.add_argument("--only", default="", help="comma-separated row keys to run (default all)")
    ap.add_argument("--compare", nargs="*", type=Path, default=[],
                    help="instead of the rows: per validation item, the starting weights against these checkpoints "
                         "(MAE in m and the loss in frame spacings; which items carry the change)")
    ap.add_argument("--compare-split", choices=("val", "train"), default="val",
                    help="--compare on the validation items or on --train-items training renders")
    ap.add_argument("--out", type=Path, default=ROOT / "results/anycam_finetune.json")
    a = ap.parse_args(argv)

    import torch
    from torch.utils.data import Subset

    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.nets.model import build_model
    from training.train.checkpoint import load
    from training.train.config import load_config
    from training.train.evaluate import evaluate

    cfg = load_config(a.config)
    val = AnyCamDataset(AnyCamConfig(**dict(cfg.val_data)))
    tcfg = load_config(a.train_config) if a.train_config else cfg
    tdata = {**dict(tcfg.data), "only_cached": True, **({} if a.mosaic is None else {"mosaic": a.mosaic})}
    train = AnyCamDataset(AnyCamConfig(**tdata))
    data_tag = ("_data-" + tcfg.name if a.train_config else "") + ("" if a.mosaic is None else f"_mosaic{a.mosaic:g}")

    def net(path: Path):
        m = build_model(cfg.net, cfg.size, cfg.field_channels)
        m.load_state_dict(load(path)["model"])
        return m.eval()

    def score(m, ds=val, n=a.val_items) -> dict:
        t = time.perf_counter()
        r = evaluate(m, ds, n, cfg.loss.mask_focus_range)[0]
        return {"mae": r["mae"], "abs_rel": r["abs_rel"], "delta1": r["delta1"], "n": r["n_images"],
                "s": round(time.perf_counter() - t, 1)}

    v1 = net(a.init)
    prev = json.loads(a.out.read_text()) if a.out.is_file() else {}
    rows: dict = {k: v for k, v in prev.items() if k != "meta"}
    rows_spec = {
        "init": ("starting weights, as they are", lambda: score(v1)),
        "init_bn_mosaic": (f"starting weights, BatchNorm stats after {a.batches} train-mode batches (lr 0), "
                           f"mosaics {cfg.data['mosaic']}",
                           lambda: score(move_bn_stats(v1, train, a.batches, cfg.data["mosaic"]))),
        "init_bn_plain": (f"starting weights, BatchNorm stats after {a.batches} train-mode batches (lr 0), "
                          "no mosaics", lambda: score(move_bn_stats(v1, train, a.batches, 0.0))),
    }
    if a.tuned.is_file():
        tuned_step = load(a.tuned).get("step")

        def tuned_with_v1_stats():
            m = net(a.tuned)
            m.load_state_dict({**m.state_dict(), **bn_buffers(v1)})
            return score(m)

        rows_spec["tuned"] = (f"fine-tuned weights ({a.tuned.name}, step {tuned_step}), as they are",
                              lambda: score(net(a.tuned)))
        rows_spec["tuned_v1_bn"] = (f"fine-tuned weights (step {tuned_step}), starting weights' BatchNorm stats",
                                    tuned_with_v1_stats)

    saved = ROOT / "cache/probes/anycam_finetune"

    def ft(lr: float, freeze_bn: bool, adam: bool = False):
        def run():
            m, loss = fine_tune(v1, train, a.steps, lr, freeze_bn, cfg.grad_clip, cfg.loss,
                                adam_state=load(a.init)["optimizer"] if adam else None)
            saved.mkdir(parents=True, exist_ok=True)
            torch.save({"model": m.state_dict(), "steps": a.steps, "lr": lr, "freeze_bn": freeze_bn, "adam": adam},
                       saved / (f"ft_{lr:g}{'_bnfrozen' if freeze_bn else ''}{'_adam' if adam else ''}"
                                f"_{tcfg.name}{data_tag}_{a.steps}.pt"))
            return {**score(m), "train_frames_l1": loss}
        return run

    for lr, fz in ((1e-4, False), (1e-4, True), (1e-5, False)):
        rows_spec[f"ft_{lr:g}{'_bnfrozen' if fz else ''}{data_tag}"] = (
            f"starting weights after {a.steps} Adam steps at lr {lr:g} (fresh moments, no warm-up) on "
            f"{a.train_config or a.config}'s data (mosaics {train.cfg.mosaic:g}), BatchNorm "
            + ("frozen (eval mode)" if fz else "in train mode, as the run"), ft(lr, fz))
    for lr in (1e-5, 1e-4):
        rows_spec[f"ft_{lr:g}_adam{data_tag}"] = (
            f"starting weights after {a.steps} Adam steps at lr {lr:g}, the starting checkpoint's Adam moments, on "
            f"{a.train_config or a.config}'s data (mosaics {train.cfg.mosaic:g}), BatchNorm in train mode",
            ft(lr, False, True))

    def train_items():
        return score(v1, train_sample(), a.train_items)

    rows_spec["init_on_train"] = (f"starting weights on {a.train_items} training renders (fixed frames, effects)",
                                  train_items)
    def train_sample():
        """--train-items training renders spread over the set, read as validation items (fixed frames, effects)."""
        tr = AnyCamDataset(AnyCamConfig(**{**dict(cfg.data), "only_cached": True, "fixed_subsets": True,
                                           "flips": False, "mosaic": 0.0}))
        step = max(len(tr) // a.train_items, 1)
        return Subset(tr, list(range(0, len(tr), step))[:a.train_items])

    if a.compare:
        ds, n = (val, a.val_items) if a.compare_split == "val" else (train_sample(), a.train_items)
        base = per_item(v1, ds, n)
        for path in a.compare:
            m = build_model(cfg.net, cfg.size, cfg.field_channels)
            m.load_state_dict(load(path)["model"])
            c = compare_items(base, per_item(m, ds, n))
            rows[f"items_{a.compare_split}_{path.stem}"] = c
            print(f"{path}: {c}", flush=True)
        a.out.write_text(json.dumps({"meta": {"config": str(a.config), "init": str(a.init)}, **rows}, indent=1))
        return 0
    only = {s for s in a.only.split(",") if s}
    for key, (label, fn) in rows_spec.items():
        if only and key not in only:
            continue
        rows[key] = {"label": label, **fn()}
        print(f"{key}: {rows[key]}", flush=True)
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({"meta": {"config": str(a.config), "init": str(a.init), "tuned": str(a.tuned),
                                              "batches": a.batches}, **rows}, indent=1))
    print("\n| row | weights, BatchNorm statistics, items | MAE (m) | AbsRel | δ1 | items |\n"
          "|---|---|---|---|---|---|")
    for key, r in rows.items():
        if "mae" not in r:
            continue
        print(f"| {key} | {r['label']} | {r['mae']:.3f} | {r['abs_rel']:.3f} | {r['delta1']:.3f} | {r['n']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
