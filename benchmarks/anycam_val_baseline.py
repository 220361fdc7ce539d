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

    OMP_NUM_THREADS=1 python -m benchmarks.anycam_val_baseline --frames-set [configs/anycam/val_frames256.json]
        [--render] --checkpoint REFERENCE.pt OTHER.pt MODEL.onnx ... [--out results/anycam_val_frames256.json]

`--frames-set`: the comparison of nets that resolves about 20 %: the set's own items (configs/anycam/
val_frames256.json: 256 validation draws of the fourth and fifth runs' distribution, sweeps of under 9 px of total
blur change left out: they carry no depth signal), each net (.pt checkpoint or exported .onnx) scored per item in
frame spacings (`aat_deploy.metrics.frame_error`, the loss's units, pixels inside each pixel's frame range) and in
metres (pixels inside the nominal focus range), the classical method with the map beside them; paired ratios
against the first `--checkpoint` (the reference) with 95 % bootstrap intervals over the items. `--render` renders
the set's missing items into its cache (cache/stacks) and stops. Per-item scores go to `--out` (merged: a model
already scored there, same file content, is not scored again).
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
    ap.add_argument("--frames-set", nargs="?", const=str(ROOT / "configs" / "anycam" / "val_frames256.json"),
                    default=None, help="score on this validation set's config instead (see the module docstring)")
    ap.add_argument("--render", action="store_true", help="with --frames-set: render its missing items and stop")
    ap.add_argument("--out", default=str(ROOT / "results" / "anycam_val_frames256.json"),
                    help="with --frames-set: the per-item scores (JSON, merged)")
    ap.add_argument("--curve", default=None,
                    help="with --frames-set: also a PNG of each run's checkpoints (same folder, a step each) against "
                         "the reference in frame spacings, by step")
    a = ap.parse_args(argv)
    if a.frames_set:
        return frames_set_main(Path(a.frames_set), a.checkpoint, a.render, Path(a.out),
                               Path(a.curve) if a.curve else None)
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


def frames_set(path: Path):
    """(config dict, AnyCamDataset, selected indices) of a --frames-set config: of its data's first n_items draws,
    the first `items` whose dense sweep changes the blur by at least `min_span_px` (decided from the draw alone)."""
    import json

    import numpy as np

    from training.data.anycam import AnyCamConfig, AnyCamDataset

    try:
        spec = json.loads(path.read_text())
        ds = AnyCamDataset(AnyCamConfig(**spec["data"]))
        n, floor = int(spec["items"]), float(spec["min_span_px"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SystemExit(f"{path}: not a validation-set config ({e})") from None
    if not ds.cfg.fixed_subsets:
        raise SystemExit(f"{path}: data.fixed_subsets must be true (validation items)")
    keep = [i for i in range(ds.cfg.n_items)
            if ds.draw_sweep(np.random.default_rng([ds.cfg.seed, i, 35]), i).span_px() >= floor]
    if len(keep) < n:
        raise SystemExit(f"{path}: only {len(keep)} of {ds.cfg.n_items} draws reach {floor:g} px; raise n_items")
    return spec, ds, keep[:n]


def load_net(path: Path):
    """(predict(item) -> depth_m (H, W), step) of a .pt checkpoint (training.train.loop.load_trained; or a bare
    state dict of the dfvaat net, as the fine-tune probe saves) or an exported any-camera .onnx."""
    import numpy as np

    if path.suffix == ".onnx":
        import onnxruntime as ort

        so = ort.SessionOptions()
        so.intra_op_num_threads = so.inter_op_num_threads = 1
        sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])

        def run_onnx(it):
            fd = it["focus_diopters"].numpy()
            order = np.argsort(-fd.mean((1, 2)), kind="stable")  # near -> far, as the runtime feeds it
            feeds = {"stack": it["stack"].numpy()[order][None].astype(np.float32),
                     "focus_diopters": fd[order][None].astype(np.float32),
                     "defocus_px_per_d": it["defocus_px_per_d"].numpy()[None].astype(np.float32)}
            return sess.run(None, feeds)[0][0]
        return run_onnx, "onnx"
    import torch

    from training.nets.dfvaat import NET_NAME, predict
    from training.nets.model import build_model
    from training.train.checkpoint import load
    from training.train.loop import load_trained

    state = load(path)
    if "config" in state:
        model, _ = load_trained(path)
    else:
        model = build_model(NET_NAME, "small", 0)
        model.load_state_dict(state["model"])
    model.eval()

    def run_pt(it):
        with torch.no_grad():
            return predict(model, it["stack"][None], it["focus_diopters"][None],
                           it["defocus_px_per_d"][None])["depth_m"][0].numpy()
    return run_pt, state.get("step", state.get("steps"))


def score_items(predict_fn, ds, indices: list[int], desc: str) -> list[dict]:
    """Per item of `indices`: frames_l1 (aat_deploy.metrics.frame_error), mae and delta1 in metres over the pixels
    inside the nominal focus range, frames (S as read) and span_px (blur change over the frames read)."""
    import numpy as np
    from tqdm import tqdm

    from aat_deploy.metrics import depth_metrics, frame_error

    rows = []
    for i in tqdm(indices, desc=desc, unit="item", file=sys.stderr):
        it = ds[ds.items.index(i)]
        d = np.asarray(predict_fn(it), np.float64)
        gt, fd, focus = it["depth_m"].numpy(), it["focus_diopters"].numpy(), it["focus_m"].numpy()
        m = depth_metrics(d, gt, (float(focus.min()), float(focus.max())))
        f = frame_error(d, gt, fd)
        rows.append({"index": i, "frames_l1": f["frames_l1"], "n_frames_px": f["n_valid"], "mae": m["mae"],
                     "delta1": m["delta1"], "frames": int(fd.shape[0]),
                     "span_px": float(it["defocus_px_per_d"].mean() * (fd.mean((1, 2)).max() - fd.mean((1, 2)).min()))})
    return rows


def frames_set_main(path: Path, models: list[str], render: bool, out: Path, curve: Path | None = None) -> int:
    import hashlib
    import json

    import numpy as np
    import torch
    from tqdm import tqdm

    from aat_deploy.eval.stats import paired_ratio
    from aat_deploy.focus import classical_depth
    from aat_deploy.io.atomic import write_text_atomic

    torch.set_num_threads(1)
    spec, ds, idx = frames_set(path)
    if render:
        for i in tqdm(idx, desc=f"{spec['name']}: render", unit="item", file=sys.stderr):
            if not ds.is_cached(i):
                ds.load_or_render(i)
        print(f"{ds.cache}: {sum(ds.is_cached(i) for i in idx)} of {len(idx)} items cached")
        return 0
    if not models:
        raise SystemExit("--frames-set: give the nets to score with --checkpoint (the first is the reference)")
    res = json.loads(out.read_text()) if out.is_file() else {}
    if res.get("set") not in (None, spec["name"]) or res.get("indices") not in (None, idx):
        raise SystemExit(f"{out}: holds scores of another set; choose another --out")
    res.update({"set": spec["name"], "config": str(path), "cache": str(ds.cache), "indices": idx})
    scores = res.setdefault("models", {})

    def save():
        out.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out, json.dumps(res, separators=(",", ":")))  # ~20 nets x 256 items

    if "classical, per-pixel map" not in scores:
        scores["classical, per-pixel map"] = {"rows": score_items(
            lambda it: classical_depth(it["stack"].numpy(), it["focus_m"].numpy(),
                                       frame_diopters=it["focus_diopters"].numpy()).depth_m, ds, idx, "classical")}
        save()
    labels = []
    for m in models:
        p = Path(m)
        sha = hashlib.sha256(p.read_bytes()).hexdigest()[:16]
        label = f"{p.parent.name}/{p.name}"
        labels.append(label)
        if scores.get(label, {}).get("sha256") == sha:
            continue
        fn, step = load_net(p)
        scores[label] = {"path": str(p), "sha256": sha, "step": step, "rows": score_items(fn, ds, idx, label)}
        save()
    ref = labels[0]
    print(f"\n#### {spec['name']}: {len(idx)} validation items (sweeps of >= {spec['min_span_px']:g} px of blur "
          f"change), reference {ref}\n")
    print("| net | step | frames L1 (frame spacings) | / reference [95 %] | MAE (m) | / reference [95 %] | δ1 |")
    print("|---|---|---|---|---|---|---|")
    for label in [*labels, "classical, per-pixel map"]:
        rows, rrows = scores[label]["rows"], scores[ref]["rows"]
        cells = []
        for key in ("frames_l1", "mae"):
            both = [(x, y) for x, y in zip(rows, rrows) if np.isfinite(x[key]) and np.isfinite(y[key])]
            mean = float(np.mean([x[key] for x, _ in both]))
            r = paired_ratio([x for x, _ in both], [y for _, y in both], key)
            cells += [f"{mean:.3f}", f"{r[0]:.2f} [{r[1]:.2f}, {r[2]:.2f}] ({len(both)})"]
        d1 = np.nanmean([x["delta1"] for x in rows])
        print(f"| {label} | {scores[label].get('step', '')} | " + " | ".join(cells) + f" | {d1:.3f} |")
    print("\n(items) = items scored by both; " + metre_spread(scores[ref]["rows"], ref))
    if curve is not None:
        plot_curves(scores, labels, curve)
        print(f"curve: {curve}")
    return 0


def plot_curves(scores: dict, labels: list[str], path: Path) -> dict:
    """PNG: per folder of checkpoints with integer steps (a run's copies), the paired ratio of frame spacings
    against labels[0] with its 95 % interval, by step; 1 = the reference, and the classical method's ratio.
    Returns {folder: [(step, ratio, low, high), ...]} as drawn."""
    import math

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aat_deploy.eval.stats import paired_ratio

    ref = scores[labels[0]]["rows"]

    def ratio(rows):
        both = [(x, y) for x, y in zip(rows, ref) if math.isfinite(x["frames_l1"]) and math.isfinite(y["frames_l1"])]
        return paired_ratio([x for x, _ in both], [y for _, y in both], "frames_l1")

    runs: dict[str, list] = {}
    for label in labels[1:]:
        step = scores[label].get("step")
        if isinstance(step, int):
            runs.setdefault(label.split("/")[0], []).append((step, *ratio(scores[label]["rows"])))
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for run, pts in runs.items():
        pts.sort()
        st, r, lo, hi = zip(*pts)
        ax.errorbar(st, r, yerr=[[a - b for a, b in zip(r, lo)], [b - a for a, b in zip(r, hi)]], marker="o",
                    capsize=3, label=run)
    ax.axhline(1.0, color="k", lw=1, label=f"reference: {labels[0]}")
    ax.axhline(ratio(scores["classical, per-pixel map"]["rows"])[0], color="grey", ls="--",
               label="classical, per-pixel map")
    ax.set_xlabel("step")
    ax.set_ylabel("frame spacings / reference (95 % interval)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return runs


def metre_spread(rows: list[dict], label: str) -> str:
    """How the metres and the frame spacings weigh items: the share of the summed MAE and of the summed frame error
    carried by the worst 5 % of items, and the rank correlation of the two over the items."""
    import numpy as np

    ok = [r for r in rows if np.isfinite(r["mae"]) and np.isfinite(r["frames_l1"])]
    mae, fr = np.array([r["mae"] for r in ok]), np.array([r["frames_l1"] for r in ok])
    k = max(1, int(round(0.05 * len(ok))))
    share = lambda v: float(np.sort(v)[::-1][:k].sum() / v.sum())  # noqa: E731
    rank = lambda v: np.argsort(np.argsort(v))  # noqa: E731
    rho = float(np.corrcoef(rank(mae), rank(fr))[0, 1])
    return (f"{label}: the worst {k} of {len(ok)} items carry {share(mae):.0%} of the summed MAE (m) and "
            f"{share(fr):.0%} of the summed frame error; Spearman rank correlation of the two over items {rho:.2f}")


if __name__ == "__main__":
    sys.exit(main())
