"""Pictures of an evaluation: per-capture panels and error profiles (matplotlib, Agg canvas only: no pyplot state,
no display needed). Colour-mapped error maps are `aat_deploy.io.colorize.colorize`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.images import imwrite


def write_rgb_png(path: Path, rgb: np.ndarray) -> None:
    if not imwrite(path, np.ascontiguousarray(rgb[..., ::-1])):
        raise OSError(f"{path}: could not write PNG")


def _figure(w_in: float, h_in: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w_in, h_in), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def capture_panel(path: Path, title: str, gt_m: np.ndarray, preds: dict[str, np.ndarray],
                  errors: dict[str, np.ndarray], depth_range: tuple[float, float], err_max: float) -> None:
    """One PNG per capture: a row per model with ground truth, prediction and |error| (shared colour scales).
    gt_m (H, W) metres, NaN = invalid; preds/errors: label → (H, W) metres (errors signed, NaN = invalid)."""
    n = len(preds)
    h, w = gt_m.shape
    fig = _figure(3 * 3.2, n * 3.2 * h / w + 0.6)
    axes = fig.subplots(n, 3, squeeze=False)
    for i, label in enumerate(preds):
        ims = []
        for j, (img, name, cmap, lo, hi) in enumerate((
                (gt_m, "ground truth (m)", "turbo", *depth_range),
                (preds[label], f"{label} (m)", "turbo", *depth_range),
                (np.abs(errors[label]), f"{label} |error| (m)", "inferno", 0.0, err_max))):
            ax = axes[i, j]
            ims.append(ax.imshow(np.ma.masked_invalid(img), cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest"))
            ax.set_title(name, fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
        fig.colorbar(ims[1], ax=axes[i, :2].tolist(), shrink=0.8)
        fig.colorbar(ims[2], ax=axes[i, 2], shrink=0.8)
    fig.suptitle(title, fontsize=9)
    fig.savefig(path)


def profile_plot(path: Path, profiles: dict[str, dict], xlabel: str, title: str, log_x: bool = False) -> None:
    """Mean |error| (solid) and mean signed error pred − GT (dashed) per bin, a curve pair per model.
    profiles: label → ErrorProfile.as_dict()."""
    fig = _figure(6.4, 4.0)
    ax = fig.add_subplot()
    for i, (label, p) in enumerate(profiles.items()):
        c = f"C{i}"
        x = np.array(p["centre"], float)
        mae = np.array([np.nan if v is None else v for v in p["mae_m"]], float)
        bias = np.array([np.nan if v is None else v for v in p["bias_m"]], float)
        ax.plot(x, mae, "-o", color=c, ms=3, label=f"{label} MAE")
        ax.plot(x, bias, "--", color=c, lw=1, label=f"{label} bias (pred − GT)")
    ax.axhline(0, color="grey", lw=0.5)
    if log_x:
        ax.set_xscale("log")
        lo, hi = ax.get_xlim()
        ticks = [t for t in (0.3, 0.5, 0.7, 1, 1.5, 2, 3, 5, 7, 10, 15, 20, 30, 50) if lo <= t <= hi]
        ax.minorticks_off()
        ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
    ax.set_xlabel(xlabel)
    ax.set_ylabel("error (m)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.savefig(path)
