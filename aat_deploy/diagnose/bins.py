"""Per-pixel covariates the gap is broken down by, and their bins.

All maps are (H, W) at the model's sensor geometry. Distances in metres from the sensor, defocus in diopters."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from aat_deploy.eval.stats import field_radius
from aat_deploy.optics.focus_table import diopter_grid

RADIUS_EDGES = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0001)  # field radius (aat_deploy.eval.stats.field_radius)
DEFOCUS_EDGES_D = (0.0, 0.05, 0.1, 0.2, 0.4, np.inf)  # distance from the nearest focus setting, diopters
MAP_GRID = (4, 6)  # rows x cols of the 2-D map


@dataclass
class Binning:
    """One way of cutting the pixels: `index` (H, W) int, -1 = not binned; `labels` one per bin."""

    name: str
    index: np.ndarray
    labels: list[str]
    unit: str


def texture(aif_linear: np.ndarray) -> np.ndarray:
    """Local contrast of the all-in-focus image (3, H, W): mean gradient magnitude of log luminance in 9x9."""
    lum = np.log(np.maximum(aif_linear.mean(0), 1e-4)).astype(np.float32)
    gx = cv2.Sobel(lum, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(lum, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.blur(np.sqrt(gx * gx + gy * gy), (9, 9))


def _digitize(x: np.ndarray, edges, valid: np.ndarray) -> np.ndarray:
    idx = np.digitize(x, edges[1:-1]).astype(np.int32)
    return np.where(valid & np.isfinite(x), idx, -1)


def _edge_labels(edges, fmt: str) -> list[str]:
    return [f"{fmt.format(a)}-{fmt.format(b)}" if np.isfinite(b) else f">{fmt.format(a)}" for a, b in zip(edges[:-1], edges[1:])]


def make_binnings(gt_m: np.ndarray, focus_m: np.ndarray, aif_linear: np.ndarray, depth_edges_m: np.ndarray,
                  texture_edges: np.ndarray) -> list[Binning]:
    """All binnings for one capture. depth_edges_m and texture_edges are shared over captures (quantiles of
    the whole set) so that bins mean the same thing in every capture."""
    h, w = gt_m.shape
    valid = np.isfinite(gt_m) & (gt_m > 0)
    inv = np.where(valid, 1.0 / np.where(valid, gt_m, 1.0), np.nan)
    focus_d = 1.0 / np.asarray(focus_m, np.float64)
    dist = np.abs(inv[None] - focus_d[:, None, None])  # (S, H, W) diopters
    nearest = np.where(valid, np.argmin(np.where(np.isfinite(dist), dist, np.inf), axis=0), -1)
    defocus = np.where(valid, np.min(np.where(np.isfinite(dist), dist, np.inf), axis=0), np.nan)
    rows, cols = MAP_GRID
    cell = (np.minimum((np.arange(h) * rows) // h, rows - 1)[:, None] * cols
            + np.minimum((np.arange(w) * cols) // w, cols - 1)[None, :])
    d_idx = _digitize(np.where(valid, gt_m, np.nan), np.asarray(depth_edges_m), valid)  # bin 0 = nearest
    depth_labels = _edge_labels(np.asarray(depth_edges_m), "{:.2f}")
    return [
        Binning("field_radius", _digitize(field_radius(h, w).astype(np.float32), RADIUS_EDGES, valid), _edge_labels(RADIUS_EDGES, "{:.1f}"),
                "field radius / half-diagonal"),
        Binning("field_map", np.where(valid, cell, -1).astype(np.int32),
                [f"r{r}c{c}" for r in range(rows) for c in range(cols)], f"{rows}x{cols} grid cell (row, col from top left)"),
        Binning("depth", d_idx, depth_labels, "scene depth, m from the sensor"),
        Binning("defocus", _digitize(defocus, DEFOCUS_EDGES_D, valid), _edge_labels(DEFOCUS_EDGES_D, "{:.2f}"),
                "diopters from the nearest focus setting"),
        Binning("frame", nearest.astype(np.int32), [f"frame {i}" for i in range(len(focus_m))],
                "stack position of the frame focused nearest to the scene point (0 = nearest focus)"),
        Binning("texture", _digitize(texture(aif_linear), texture_edges, valid),
                [f"q{i + 1}" for i in range(len(texture_edges) - 1)], "texture quintile of the all-in-focus image (q1 = flattest)"),
    ]


def shared_edges(gts: list[np.ndarray], aifs: list[np.ndarray], n: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Depth edges (m, ascending, even in diopters between the set's 1st and 99th percentile) and texture
    quantile edges over all captures."""
    inv = np.concatenate([1.0 / g[np.isfinite(g) & (g > 0)] for g in gts])
    lo_d, hi_d = np.percentile(inv, [1, 99])
    d_edges = diopter_grid(1.0 / hi_d, 1.0 / lo_d, n + 1)  # ascending metres, near to far
    d_edges[0], d_edges[-1] = 0.0, np.inf
    tex = np.concatenate([texture(a).ravel() for a in aifs])
    t_edges = np.quantile(tex, np.linspace(0, 1, n + 1))
    t_edges[0], t_edges[-1] = -np.inf, np.inf
    return d_edges, t_edges
