"""Pictures of a lens: a 2-D layout with ray fans, and spot diagrams (matplotlib, headless)."""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from aat_deploy.lens.schema import Lens  # noqa: E402
from aat_deploy.optics.paraxial import paraxial_data  # noqa: E402
from training.optics.focus import focus  # noqa: E402
from training.optics.spot import Spot, field_rays  # noqa: E402
from training.optics.trace import trace  # noqa: E402


def _profile(lens: Lens, i: int, n: int = 64) -> tuple[np.ndarray, np.ndarray]:
    s, zv = lens.surfaces[i], lens.vertex_z_mm[i]
    y = np.linspace(-s.semi_diameter_mm, s.semi_diameter_mm, n)
    return zv + np.array([s.sag(v * v) for v in y]), y


def draw_layout(lens: Lens, path, fields_deg=None, focus_m: float = math.inf, n_rays: int = 7) -> None:
    """Meridional section: surfaces, element edges, stop, sensor, and ray fans for a few fields."""
    p = paraxial_data(lens)
    if fields_deg is None:
        fields_deg = [0.0, 0.7 * p.hfov_v_deg, p.hfov_v_deg]
    zs = focus(lens, focus_m)
    fig, ax = plt.subplots(figsize=(10, 4.5))
    media = lens.materials()
    for i, s in enumerate(lens.surfaces):
        z, y = _profile(lens, i)
        if i == lens.stop_index and s.curvature_per_mm == 0 and media[i].is_air and media[i + 1].is_air:
            ax.plot([z[0]] * 2, [s.semi_diameter_mm, s.semi_diameter_mm * 1.3], "k", lw=2)
            ax.plot([z[0]] * 2, [-s.semi_diameter_mm, -s.semi_diameter_mm * 1.3], "k", lw=2)
            continue
        ax.plot(z, y, "k", lw=1)
        if not media[i + 1].is_air and i + 1 < len(lens.surfaces):  # close the element at its edges
            z2, y2 = _profile(lens, i + 1)
            for k in (0, -1):
                ax.plot([z[k], z[k], z2[k]], [y[k], y2[k], y2[k]], "k", lw=1)
    colors = plt.cm.viridis(np.linspace(0, 0.85, len(fields_deg)))
    py = torch.linspace(-1, 1, n_rays, dtype=torch.float64)
    pupil = torch.stack([torch.zeros_like(py), py], -1)
    for f, col in zip(fields_deg, colors):
        rays = field_rays(lens, pupil, f, focus_m, zs)
        res = trace(lens, rays, sensor_z_mm=zs, record=True)
        pts = torch.stack([rays.o] + res.hits + [res.rays.o], 0).numpy()  # (S, N, 3)
        for k in range(pts.shape[1]):
            if bool(res.rays.valid[k]):
                ax.plot(pts[:, k, 2], pts[:, k, 1], color=col, lw=0.6)
        ax.plot([], [], color=col, label=f"{f:.1f}°")
    h = lens.sensor.height_mm / 2
    ax.plot([zs, zs], [-h, h], "r", lw=2, label="sensor")
    ax.set_aspect("equal")
    ax.set_xlabel("z (mm, from the first vertex)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"{lens.name}\nEFL {p.efl_mm:.2f} mm, F/{p.fno:.2f}, focused at {focus_m} m")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def draw_spot(sp: Spot, path, title: str = "") -> None:
    """Spot diagram in micrometres about the centroid, with the RMS circle."""
    xy = (sp.xy_mm.numpy() - np.array(sp.centroid_mm)) * 1000.0
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.scatter(xy[:, 0], xy[:, 1], s=2)
    t = np.linspace(0, 2 * np.pi, 200)
    ax.plot(sp.rms_um * np.cos(t), sp.rms_um * np.sin(t), "r--", lw=1, label=f"RMS {sp.rms_um:.2f} µm")
    ax.set_aspect("equal")
    ax.set_xlabel("x (µm, about the centroid)")
    ax.set_ylabel("y (µm)")
    ax.set_title(title + f"\n{sp.n_valid}/{sp.n_rays} rays pass")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def draw_focus_map(fmap, path, title: str = "", n_lines: int = 6) -> None:
    """A best-focus map (`aat_deploy.focus.bestfocus.BestFocusMap`): where a frame is in focus against the field
    radius, as object diopters minus the frame's nominal diopters, for `n_lines` of its focus settings (even in
    diopters); solid the calibrated map, dashed the traced one (only the traced one without a calibration)."""
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    cols = np.unique(np.rint(np.linspace(0, fmap.focus_diopters.size - 1, n_lines)).astype(int))
    colours = plt.cm.viridis(np.linspace(0, 0.9, cols.size))
    traced = fmap.shift_diopters(calibrated=False)
    calibrated = fmap.shift_diopters(calibrated=True) if fmap.offset_diopters is not None else None
    for c, j in zip(colours, cols):
        f = fmap.focus_diopters[j]
        label = f"frame at {1 / f:.3g} m" if f > 0 else "frame at infinity"
        if calibrated is not None:
            ax.plot(fmap.radius, calibrated[:, j], "-", color=c, label=label)
            ax.plot(fmap.radius, traced[:, j], "--", color=c, lw=0.8)
        else:
            ax.plot(fmap.radius, traced[:, j], "-", color=c, label=label)
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xlabel("field radius (0 centre, 1 sensor corner)")
    ax.set_ylabel("best focus − nominal focus (diopters)")
    kind = "calibrated (solid) and traced (dashed)" if calibrated is not None else "traced, not calibrated"
    ax.set_title((title + "\n" if title else "") + f"best-focus map, {kind}", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
