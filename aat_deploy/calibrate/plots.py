"""The picture of a calibration (matplotlib, Agg canvas only): what the camera has in focus across the field at the
near, middle and far end of the measured range, the reported focus's error, the blur growth, the bootstrap spread
and the tiles' residuals."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.atomic import atomic_file
from .format import CameraCalibration, field_grid, in_focus_diopters, on_axis_diopters


def calibration_png(cal: CameraCalibration, path: str | Path, observations=None, residual_d=None) -> Path:
    """Write the maps to `path` (PNG, atomically). observations / residual_d: the fit's tiles (optional panel)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    w, h = cal.size_px
    s = 240 / max(w, h)
    gw, gh = max(2, round(w * s)), max(2, round(h * s))
    lo, hi = cal.best_focus.focus_range_d
    ts = [hi, 0.5 * (lo + hi), lo]  # near, middle, far on-axis focus (diopters)
    fig = Figure(figsize=(15, 8.4), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 4)
    x, y = field_grid(gh, gw)
    shifts = [cal.best_focus(x, y, [t])[0] for t in ts]
    lim = max(float(np.max(np.abs(m))) for m in shifts) or 0.01
    for ax, t, m in zip(axes[0, :3], ts, shifts):
        im = ax.imshow(m, cmap="RdBu_r", vmin=-lim, vmax=lim, extent=(-1, 1, -1, 1))
        ax.set_title(f"in focus minus centre (D)\non-axis focus {1 / t if t > 0 else np.inf:.3g} m", fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.8)
    ax = axes[0, 3]
    fe = cal.focus_error
    rep = np.linspace(max(lo - 0.2, 0.0), hi + 0.2, 100)
    true = fe.true_diopters(rep)
    ax.plot(rep, true - rep, "k-", label=f"{fe.family}")
    ax.axhline(0, color="grey", lw=0.5)
    ax.axvspan(*np.interp([lo, hi], true, rep), color="C0", alpha=0.1, label="measured range")
    ax.set_xlabel("reported focus (D)")
    ax.set_ylabel("true minus reported (D)")
    ci = "; ".join(f"{k} [{v[0]:.4g}, {v[1]:.4g}]" for k, v in fe.intervals.items())
    ax.set_title("reported-focus error" + (f"\n95 %: {ci}" if ci else ""), fontsize=9)
    ax.legend(fontsize=8)
    ax = axes[1, 0]
    if cal.blur is not None:
        k = cal.blur(x, y, [0.5 * (lo + hi)])[0]
        im = ax.imshow(k, cmap="viridis", extent=(-1, 1, -1, 1))
        fig.colorbar(im, ax=ax, shrink=0.8)
        ax.set_title(f"blur growth (px per D at {w}x{h} px)", fontsize=9)
    else:
        ax.set_axis_off()
        ax.set_title("no measured blur growth", fontsize=9)
    ax = axes[1, 1]
    u = cal.uncertainty
    if u.get("sd_d"):
        sd = np.asarray(u["sd_d"], np.float64)
        im = ax.imshow(sd, cmap="magma", extent=(-1, 1, -1, 1))
        fig.colorbar(im, ax=ax, shrink=0.8)
        ax.set_title("bootstrap SD of the map (D)", fontsize=9)
    else:
        ax.set_axis_off()
    ax = axes[1, 2]
    if observations is not None and residual_d is not None and len(residual_d):
        lim_r = max(float(np.quantile(np.abs(residual_d), 0.99)), 1e-3)
        sc = ax.scatter(observations.x, observations.y, c=residual_d, s=6, cmap="RdBu_r", vmin=-lim_r, vmax=lim_r)
        fig.colorbar(sc, ax=ax, shrink=0.8)
        ax.set_xlim(-1, 1)
        ax.set_ylim(-1, 1)
        ax.set_title(f"tile residuals (D), RMS {np.sqrt(np.mean(residual_d ** 2)):.4f}", fontsize=9)
    else:
        ax.set_axis_off()
    ax = axes[1, 3]
    row = in_focus_diopters(cal, [1 / max(t, 1e-3) for t in ts], gh, gw)[:, gh // 2]
    xs = np.linspace(-1, 1, gw)
    for t, r_ in zip(ts, row):
        ax.plot(xs, r_ - float(on_axis_diopters(cal, [1 / max(t, 1e-3)])[0]), label=f"{1 / t:.3g} m")
    ax.set_xlabel("field x (centre row)")
    ax.set_ylabel("in focus minus centre (D)")
    ax.legend(fontsize=8)
    c = cal.camera
    fig.suptitle(f"{c.make} {c.model} · {c.lens} · {c.focal_length_mm or '?'} mm f/{c.f_number or '?'} · "
                 f"residual RMS {cal.residuals.get('rms_d', float('nan')):.4f} D", fontsize=11)
    fig.tight_layout()
    path = Path(path)
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
    return path
