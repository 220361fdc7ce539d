"""Scoring one prediction against ground truth: optional scale/shift fit (`--align`), the shared depth metrics
(`aat_deploy.metrics`), all-in-focus PSNR/SSIM, a test scene's scores by field zone (`scene_scores`, the DfF
tables') and error profiles over field radius and depth.

Metric depth is scored as it is. `--align` fits, over the valid pixels, p' = s·p + t to the ground truth:
- "scale-shift": least squares in depth (s, t);
- "scale": least squares in depth with t = 0;
- "median": s = median(g) / median(p), t = 0.
The fitted s, t are reported with the metrics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io.color import linear_to_srgb, srgb_to_linear
from ..metrics import depth_metrics, psnr, ssim
from .stats import zone_masks

ALIGN_MODES = ("scale-shift", "scale", "median")


def fit_alignment(pred_m: np.ndarray, gt_m: np.ndarray, mode: str) -> tuple[float, float]:
    """(scale, shift) minimising the mode's criterion over pixels where gt is finite and > 0.
    pred_m, gt_m (H, W) metres."""
    ok = np.isfinite(gt_m) & (gt_m > 0) & np.isfinite(pred_m)
    p, g = pred_m[ok].astype(np.float64), gt_m[ok].astype(np.float64)
    if p.size == 0:
        return 1.0, 0.0
    if mode == "median":
        return float(np.median(g) / max(np.median(p), 1e-12)), 0.0
    if mode == "scale":
        return float(np.dot(p, g) / max(np.dot(p, p), 1e-12)), 0.0
    if mode == "scale-shift":
        a = np.stack([p, np.ones_like(p)], 1)
        (s, t), *_ = np.linalg.lstsq(a, g, rcond=None)
        return float(s), float(t)
    raise ValueError(f"unknown alignment {mode!r} (one of {', '.join(ALIGN_MODES)})")


def aif_pair(aif_srgb8: np.ndarray, ref_linear: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The prediction and reference as uint8 sRGB (3, H, W) for PSNR/SSIM, and the exposure gain applied.

    aif_srgb8 (H, W, 3) uint8: the runtime's all-in-focus (normalised units, so its exposure is arbitrary);
    ref_linear (H, W, 3) linear RGB already fitted to the sensor. The prediction is scaled in linear light by
    the least-squares gain onto the reference, then both are encoded to 8-bit sRGB."""
    p = srgb_to_linear(aif_srgb8.astype(np.float32) / 255.0).astype(np.float64)
    r = np.clip(ref_linear.astype(np.float64), 0, 1)
    gain = float(np.sum(p * r) / max(np.sum(p * p), 1e-12))
    enc = lambda x: np.rint(linear_to_srgb(x) * 255).astype(np.uint8).transpose(2, 0, 1)
    return enc(np.clip(p * gain, 0, 1)), enc(r), gain


def scene_scores(depth_m: np.ndarray, gt_m: np.ndarray, aif: np.ndarray | None = None,
                 aif_ref: np.ndarray | None = None) -> dict[str, float]:
    """One test scene's scores in the DfF tables (benchmarks/): the depth metrics (`aat_deploy.metrics`) over valid
    ground truth, `mae_<zone>` per field zone (`aat_deploy.eval.stats.zone_masks`), and the all-in-focus image's
    `psnr` / `ssim` against the reference (clipped to [0, 1], data range 1; NaN without them).
    depth_m, gt_m (H, W) metres from the sensor (gt 0 / NaN = unknown); aif, aif_ref (3, H, W) normalised linear."""
    m = depth_metrics(depth_m, gt_m)
    for z, mask in zone_masks(*gt_m.shape).items():
        m[f"mae_{z}"] = depth_metrics(depth_m, gt_m, mask=mask)["mae"]
    if aif is not None and aif_ref is not None:
        a, r = np.clip(aif, 0, 1), np.clip(aif_ref, 0, 1)
        m["psnr"] = psnr(a, r)
        m["ssim"] = ssim(a, r, channel_axis=0)
    else:
        m["psnr"] = m["ssim"] = float("nan")
    return m


@dataclass
class ErrorProfile:
    """Binned error: per bin of a quantity (field radius, GT depth) the sum of |e|, of e, and the count.
    edges (B + 1,) ascending; values outside the edges are dropped."""

    name: str
    unit: str
    edges: np.ndarray

    def __post_init__(self):
        n = len(self.edges) - 1
        self.sum_abs, self.sum_err, self.count = np.zeros(n), np.zeros(n), np.zeros(n, np.int64)

    def add(self, x: np.ndarray, err: np.ndarray) -> None:
        """x, err: same shape; NaN err entries are skipped."""
        ok = np.isfinite(err) & np.isfinite(x)
        b = np.searchsorted(self.edges, x[ok], side="right") - 1
        keep = (b >= 0) & (b < len(self.count))
        e = err[ok][keep]
        b = b[keep]
        self.sum_abs += np.bincount(b, np.abs(e), len(self.count))
        self.sum_err += np.bincount(b, e, len(self.count))
        self.count += np.bincount(b, minlength=len(self.count))

    def as_dict(self) -> dict:
        """Bin centres, MAE and mean signed error (pred − GT) per bin (None where empty), counts."""
        n = np.maximum(self.count, 1)
        has = self.count > 0
        centre = 0.5 * (self.edges[:-1] + self.edges[1:])
        if self.name == "depth":
            centre = np.sqrt(self.edges[:-1] * self.edges[1:])
        nz = lambda a: [float(v) if h else None for v, h in zip(a, has)]
        return {"quantity": self.name, "unit": self.unit, "edges": self.edges.tolist(),
                "centre": centre.tolist(), "mae_m": nz(self.sum_abs / n), "bias_m": nz(self.sum_err / n),
                "count": self.count.tolist()}


def radius_profile(bins: int = 20) -> ErrorProfile:
    """Even bins of the field radius (`aat_deploy.eval.stats.field_radius`) from 0 to 1."""
    return ErrorProfile("field_radius", "fraction of the half diagonal", np.linspace(0, 1, bins + 1))


def depth_profile(near_m: float, far_m: float, bins: int = 24) -> ErrorProfile:
    """Geometric bins from near/2 to 2·far (metres)."""
    return ErrorProfile("depth", "m", np.geomspace(near_m / 2, far_m * 2, bins + 1))
