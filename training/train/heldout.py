"""Held-out evaluation of exported DfF models (the paper's Table 2 layout): shared by benchmarks/bench_dff.py and
the lens-to-model chain (`aat-train --lens`, training/chain).

Test stacks are whole-sensor renders of scenes never seen in training (procedural scenes from their own seed, or
a real RGB-D scene scaled to cover the sensor), normalised as the runtime normalises. Models run with
onnxruntime exactly as `aat-infer` runs them (aat_deploy.infer.model.DfFModel). Metrics per image, then averaged
(aat_deploy.metrics), depth in metres from the sensor; MAE by field zone and MAE per bin of the field radius (error
vs field radius), both as `aat_deploy.eval.stats` defines them (circular radius, 1 = sensor corner; centre < 0.33,
outer > 0.66).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aat_deploy.eval.stats import ZONES, field_radius, zone_masks
from aat_deploy.infer.normalise import normalise_stack
from aat_deploy.io.atomic import atomic_file

COLS = ("mae", "mse", "rmse", "abs_rel", "sq_rel", "delta1", "delta2", "delta3")
HEADER = ("| model | MAE | MSE | RMSE | AbsRel | SqRel | δ1 | δ2 | δ3 | MAE centre | MAE outer |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|")

# One test item: (stack (S, 3, H, W) normalised, focus_m (S,), ground-truth depth (H, W) metres, 0 = unknown).
Item = tuple[np.ndarray, np.ndarray, np.ndarray]


def procedural_items(dataset, n: int, progress: bool = True) -> list[Item]:
    """Items 0..n-1 of a FocalStackDataset (whole-sensor crops, margin 0) as test items."""
    out = []
    for i in range(n):
        it = dataset.render(i)
        out.append((it["stack"], it["focus_m"], it["depth_m"]))
        if progress:
            print(f"procedural {i + 1}/{n}", flush=True)
    return out


def rgbd_item(dataset, rgb: np.ndarray, gt_m: np.ndarray) -> Item:
    """A real RGB-D scene (rgb (H', W', 3) linear, depth (H', W') metres, 0 = unknown) scaled to cover the
    dataset's sensor, rendered with its simulator and fixed schedule."""
    import torch

    from aat_deploy.gt.holes import fill_holes
    from aat_deploy.infer.geometry import fit_rgbd_to_sensor

    rgb, gt = fit_rgbd_to_sensor(rgb, gt_m, dataset.sensor_hw)
    st = dataset.sim.render_stack(torch.from_numpy(rgb.transpose(2, 0, 1).copy()), torch.from_numpy(fill_holes(gt)),
                                  dataset.schedule.distances())
    return normalise_stack(st.frames.numpy()), st.focus_m.astype(np.float32), gt


@dataclass
class ModelResult:
    """Metrics of one model on one test set: `metrics` (means over images, incl. mae_centre / mae_middle / mae_outer),
    `error_map` (H, W) mean |error| in metres, `radial_mae` MAE (m) per bin of `radial_edges` (normalised radius)."""

    label: str
    metrics: dict
    error_map: np.ndarray
    radial_edges: np.ndarray
    radial_mae: np.ndarray
    meta: dict = field(default_factory=dict)


def model_label(meta: dict, path: Path) -> str:
    """'AAT DFVNet' / 'Baseline AiFNet' from a model's metadata (net from aat.net, else the file name)."""
    from training.nets.registry import NETS

    spec = NETS.get(str(meta.get("aat.net")))
    net = spec.label if spec else path.stem.split("_")[1]
    return f"{'AAT' if meta.get('aat.simulator') == 'aat' else 'Baseline'} {net}"


def evaluate_model(path, items: list[Item], threads: int = 2, n_bins: int = 10, label: str | None = None,
                   ) -> ModelResult:
    """Run the ONNX model at `path` on `items` with onnxruntime; metrics, zone MAE and error vs field radius."""
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.metrics import MetricAccumulator

    path = Path(path)
    model = DfFModel(path, threads=threads)
    acc = MetricAccumulator()
    zones: dict[str, list[float]] = {z: [] for z in ZONES}
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    per_bin: list[np.ndarray] = []
    for stack, focus, gt in items:
        out = model.infer(stack, focus)
        acc.add(out.depth_m, gt)
        valid = np.isfinite(gt) & (gt > 0)
        err = np.abs(out.depth_m - np.where(valid, gt, 0))
        for z, m in zone_masks(*gt.shape).items():
            v = m & valid
            zones[z].append(float(err[v].mean()) if v.any() else float("nan"))
        r = field_radius(*gt.shape)
        row = np.full(n_bins, np.nan)
        for b in range(n_bins):
            v = valid & (r >= edges[b]) & ((r < edges[b + 1]) if b < n_bins - 1 else (r <= 1.0))
            if v.any():
                row[b] = float(err[v].mean())
        per_bin.append(row)
    res = acc.result()
    res.update({f"mae_{z}": float(np.nanmean(v)) if v else float("nan") for z, v in zones.items()})
    with np.errstate(all="ignore"):
        radial = np.nanmean(np.stack(per_bin), 0) if per_bin else np.full(n_bins, np.nan)
    return ModelResult(label or model_label(model.meta, path), res, acc.error_map(), edges, radial,
                       dict(model.meta))


def table(results: list[ModelResult]) -> str:
    """Markdown table (HEADER columns) of results on one test set."""
    rows = [HEADER]
    for r in results:
        m = r.metrics
        rows.append(f"| {r.label} | " + " | ".join(f"{m[c]:.4f}" for c in COLS)
                    + f" | {m['mae_centre']:.4f} | {m['mae_outer']:.4f} |")
    return "\n".join(rows)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_error_over_field(results: list[ModelResult], path) -> Path:
    """One panel per model: the mean |error| map over the sensor (metres), shared colour scale."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(results), figsize=(4.2 * len(results), 3.4))
    vmax = np.nanpercentile(np.stack([r.error_map for r in results]), 98)
    im = None
    for ax, r in zip(np.atleast_1d(axes), results):
        im = ax.imshow(r.error_map, cmap="magma", vmin=0, vmax=vmax)
        ax.set_title(f"{r.label}\nmean |error| (m)", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes, shrink=0.8)
    return _save(fig, plt, path)


def plot_error_vs_radius(results: list[ModelResult], path, title: str = "") -> Path:
    """MAE (m) per normalised field-radius bin, one line per model."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 3.4))
    for r in results:
        centres = 0.5 * (r.radial_edges[:-1] + r.radial_edges[1:])
        ax.plot(centres, r.radial_mae, marker="o", label=r.label)
    ax.set_xlabel("normalised field radius (0 centre, 1 corner)")
    ax.set_ylabel("MAE (m)")
    ax.set_xlim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return _save(fig, plt, path)


def _save(fig, plt, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return path


def result_dict(r: ModelResult) -> dict:
    """JSON-ready form (metrics, radial profile, model metadata subset)."""
    return {"label": r.label, "metrics": r.metrics,
            "radial_edges": [float(e) for e in r.radial_edges],
            "radial_mae_m": [None if not np.isfinite(v) else float(v) for v in r.radial_mae],
            "simulator": r.meta.get("aat.simulator"), "net": r.meta.get("aat.net"),
            "effects": r.meta.get("aat.effects")}
