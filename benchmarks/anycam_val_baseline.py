"""The any-camera run's validation set scored by the classical method beside the net: the reference line of its
validation curve (same items, same metrics, same mask as the run's validation).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.anycam_val_baseline [--config configs/anycam/dfv_aat.json]
        [--checkpoint RUN/last.pt ...] [--n 64]

The validation items (training.data.anycam, fixed_subsets: each item's frames and camera processing fixed) carry
per-pixel in-focus diopters; the classical method (`aat_deploy.focus.classical_depth`) is given the same map
(`frame_diopters`) and, for comparison, only the nominal focus distances. Metrics as the run's validation:
aat_deploy.metrics over pixels inside each stack's focus range, averaged over items. Prints a markdown table, and
with checkpoints the paired ratios (each later checkpoint against the first, each against the classical method
with the map) with 95 % bootstrap intervals over the items: a new run's gain over an earlier net on the same items.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "anycam" / "dfv_aat.json"))
    ap.add_argument("--checkpoint", nargs="*", default=[], help="the net's checkpoints (last.pt, model.pt) to score too")
    ap.add_argument("--n", type=int, default=64)
    ap.add_argument("--per-item", action="store_true",
                    help="also each item's MAE per method, and its map's least in-focus diopters (a map past infinity, "
                         "< 0, makes the classical estimate 1 km where a far frame is sharpest)")
    a = ap.parse_args(argv)
    import numpy as np
    import torch

    from aat_deploy.focus import classical_depth
    from aat_deploy.metrics import MetricAccumulator
    from training.nets.dfvaat import predict
    from training.train.config import load_config
    from training.train.data import make_dataset
    from training.train.loop import load_trained

    torch.set_num_threads(1)
    cfg = load_config(a.config)
    val = make_dataset(cfg.val_data, cfg.simulator, cfg.lens)
    nets = {}
    for p in a.checkpoint:
        model, _ = load_trained(p)
        step = torch.load(p, map_location="cpu", weights_only=False).get("step")
        nets[f"dfv_aat (step {step})"] = model.eval()
    accs = {k: MetricAccumulator(focus_range_mask=True) for k in
            ("Classical, per-pixel map", "Classical, nominal focus", *nets)}
    n = min(a.n, len(val))
    rows = []
    for i in range(n):
        it = val[i]
        stack, fd = it["stack"].numpy(), it["focus_diopters"].numpy()
        focus, gt = it["focus_m"].numpy(), it["depth_m"].numpy()
        preds = {"Classical, per-pixel map": classical_depth(stack, focus, frame_diopters=fd).depth_m,
                 "Classical, nominal focus": classical_depth(stack, focus).depth_m}
        for label, model in nets.items():
            preds[label] = predict(model, it["stack"][None], it["focus_diopters"][None],
                                   it["defocus_px_per_d"][None])["depth_m"][0].numpy()
        for label, d in preds.items():
            accs[label].add(d, gt, focus_m=focus)
        if a.per_item:
            inside = (gt >= focus.min()) & (gt <= focus.max())
            rows.append((i, len(focus), float(fd.min()), [float(np.abs(d - gt)[inside].mean()) if inside.any()
                                                           else float("nan") for d in preds.values()]))
        print(f"item {i + 1}/{n}", file=sys.stderr, flush=True)
    print(f"\n#### {cfg.name} validation set: {n} items, pixels inside each stack's focus range\n")
    print("| method | MAE (m) | AbsRel | δ1 |\n|---|---|---|---|")
    for label, acc in accs.items():
        r = acc.result()
        print(f"| {label} | {r['mae']:.3f} | {r['abs_rel']:.3f} | {r['delta1']:.3f} |")
    ratios = paired_ratios(accs, [*nets])
    if ratios:
        print("\n| paired ratio of MAE over the items both score (95 % bootstrap over items) | ratio |\n|---|---|")
        for label, (r, lo, hi) in ratios.items():
            print(f"| {label} | {r:.2f} [{lo:.2f}, {hi:.2f}] |")
    if rows:
        print("\n| item | frames | least map diopters | " + " | ".join(f"{k} MAE (m)" for k in accs) + " |")
        print("|---" * (3 + len(accs)) + "|")
        for i, s_, lo, maes in rows:
            print(f"| {i} | {s_} | {lo:.3f} | " + " | ".join(f"{v:.3f}" for v in maes) + " |")
    return 0


def paired_ratios(accs: dict, nets: list[str]) -> dict[str, list[float]]:
    """{'B / A': [ratio, low, high]}: every net after the first against the first net, and every net against the
    classical method with the same map; MAE over the items both score (pixels inside the focus range), items
    resampled together (aat_deploy.eval.stats.paired_ratio). A ratio whose interval holds 1 is no difference."""
    from aat_deploy.eval.stats import paired_ratio

    pairs = [(b, nets[0]) for b in nets[1:]] + [(b, "Classical, per-pixel map") for b in nets]
    out = {}
    for b, a in pairs:
        both = [(x, y) for x, y in zip(accs[b].rows, accs[a].rows)
                if x.get("n_valid", 0) > 0 and y.get("n_valid", 0) > 0]
        if both:
            out[f"{b} / {a}"] = paired_ratio([x for x, _ in both], [y for _, y in both], "mae")
    return out


if __name__ == "__main__":
    sys.exit(main())
