"""Depth and all-in-focus metrics (numpy only; the runtime never imports torch).

Depth metrics are computed per image over valid ground-truth pixels (g > 0 and finite, optionally also inside
the stack's focus range) and then averaged over images, so the mean RMSE is not sqrt(mean MSE):
MAE = mean|p - g|, MSE = mean (p - g)^2, RMSE = sqrt(MSE), AbsRel = mean |p - g| / g, SqRel = mean (p - g)^2 / g,
RMSE-log = sqrt(mean (ln p - ln g)^2) (p clipped to >= 1e-6), delta_k = fraction with max(p/g, g/p) < 1.25^k.
Units are those of the inputs (metres for our depth maps).

All-in-focus: PSNR and SSIM (Wang et al. 2004: 11x11 Gaussian window, sigma 1.5, K1 0.01, K2 0.03, population
statistics, mean over the 'valid' region away from the border and over channels; equals
skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)) on float
images with a given data range (1 for our normalised units), unmasked.
"""

from __future__ import annotations

import numpy as np

DEPTH_KEYS = ("mae", "mse", "rmse", "abs_rel", "sq_rel", "rmse_log", "delta1", "delta2", "delta3")


def valid_mask(gt_m: np.ndarray, focus_range_m: tuple[float, float] | None = None) -> np.ndarray:
    """(H, W) bool: g > 0 and finite [and near <= g <= far]."""
    g = np.asarray(gt_m, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        m = np.isfinite(g) & (g > 0)
        if focus_range_m is not None:
            near, far = focus_range_m
            m &= (g >= near) & (g <= far)
    return m


def depth_metrics(pred_m: np.ndarray, gt_m: np.ndarray, focus_range_m: tuple[float, float] | None = None,
                  mask: np.ndarray | None = None) -> dict[str, float]:
    """Metrics of one depth map. pred_m, gt_m (H, W); mask (H, W) bool, combined with the validity mask.
    Returns DEPTH_KEYS plus 'n_valid'; NaN metrics if no pixel is valid."""
    p = np.asarray(pred_m, dtype=np.float64)
    g = np.asarray(gt_m, dtype=np.float64)
    if p.shape != g.shape:
        raise ValueError(f"depth_metrics: prediction {p.shape} and ground truth {g.shape} differ in shape")
    m = valid_mask(g, focus_range_m)
    if mask is not None:
        m &= np.asarray(mask, dtype=bool)
    n = int(m.sum())
    if n == 0:
        return {**{k: float("nan") for k in DEPTH_KEYS}, "n_valid": 0}
    p, g = p[m], g[m]
    if not np.isfinite(p).all():
        raise ValueError("depth_metrics: the prediction has NaN or inf at valid pixels")
    d = p - g
    mse = float(np.mean(d * d))
    pc = np.maximum(p, 1e-6)
    ratio = np.maximum(pc / g, g / pc)
    lg = np.log(pc) - np.log(g)
    return {
        "mae": float(np.mean(np.abs(d))),
        "mse": mse,
        "rmse": float(np.sqrt(mse)),
        "abs_rel": float(np.mean(np.abs(d) / g)),
        "sq_rel": float(np.mean(d * d / g)),
        "rmse_log": float(np.sqrt(np.mean(lg * lg))),
        "delta1": float(np.mean(ratio < 1.25)),
        "delta2": float(np.mean(ratio < 1.25**2)),
        "delta3": float(np.mean(ratio < 1.25**3)),
        "n_valid": n,
    }


def frame_error(pred_m: np.ndarray, gt_m: np.ndarray, frame_diopters: np.ndarray,
                mask: np.ndarray | None = None) -> dict[str, float]:
    """Depth error in frame spacings (the any-camera net's loss units, training.train.loss.focus_map_loss): per
    pixel |1/p - 1/g| / ((max_s D_s - min_s D_s) / (S - 1)), D_s the in-focus diopters of frame s at that pixel
    (frame_diopters (S, H, W), 1/m from the sensor plane; spacing at least 1e-3 D as in the loss), averaged over the
    valid pixels whose true diopters lie inside that pixel's own frame range (what depth from focus can reach; pass
    `mask` (H, W) bool to use another set of pixels instead). Returns {"frames_l1", "n_valid"} (NaN, 0 when no
    pixel counts)."""
    p = np.asarray(pred_m, np.float64)
    g = np.asarray(gt_m, np.float64)
    fd = np.asarray(frame_diopters, np.float64)
    if p.shape != g.shape or fd.shape[1:] != g.shape:
        raise ValueError(f"frame_error: prediction {p.shape}, ground truth {g.shape} and maps {fd.shape} differ")
    m = valid_mask(g)
    inv_g = 1.0 / np.where(m, g, 1.0)
    if mask is None:
        m &= (inv_g >= fd.min(0)) & (inv_g <= fd.max(0))
    else:
        m &= np.asarray(mask, bool)
    if not m.any():
        return {"frames_l1": float("nan"), "n_valid": 0}
    spacing = np.maximum((fd.max(0) - fd.min(0)) / max(fd.shape[0] - 1, 1), 1e-3)
    err = np.abs(1.0 / np.maximum(p, 1e-9) - inv_g) / spacing
    return {"frames_l1": float(err[m].mean()), "n_valid": int(m.sum())}


def psnr(pred: np.ndarray, ref: np.ndarray, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB over all pixels and channels (inf for identical images)."""
    p = np.asarray(pred, dtype=np.float64)
    r = np.asarray(ref, dtype=np.float64)
    if p.shape != r.shape:
        raise ValueError(f"psnr: shapes {p.shape} and {r.shape} differ")
    mse = float(np.mean((p - r) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(data_range**2 / mse))


def _gaussian_window(size: int = 11, sigma: float = 1.5) -> np.ndarray:
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def _filter_valid(img: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Separable correlation of (H, W) with the 1-D window w along both axes, 'valid' region only."""
    k = len(w)
    h, wd = img.shape
    rows = sum(w[i] * img[i:h - k + 1 + i, :] for i in range(k))
    return sum(w[j] * rows[:, j:wd - k + 1 + j] for j in range(k))


def ssim(pred: np.ndarray, ref: np.ndarray, data_range: float = 1.0, channel_axis: int | None = None) -> float:
    """Mean SSIM of two images (H, W) or with channels on `channel_axis` (mean over channels); both sides >= 11."""
    p = np.asarray(pred, dtype=np.float64)
    r = np.asarray(ref, dtype=np.float64)
    if p.shape != r.shape:
        raise ValueError(f"ssim: shapes {p.shape} and {r.shape} differ")
    if channel_axis is not None:
        p, r = np.moveaxis(p, channel_axis, 0), np.moveaxis(r, channel_axis, 0)
        return float(np.mean([ssim(a, b, data_range) for a, b in zip(p, r)]))
    if p.ndim != 2:
        raise ValueError(f"ssim: expected (H, W) or a channel_axis, got shape {p.shape}")
    if min(p.shape) < 11:
        raise ValueError(f"ssim: images must be at least 11x11, got {p.shape}")
    w = _gaussian_window()
    mu_p, mu_r = _filter_valid(p, w), _filter_valid(r, w)
    var_p = _filter_valid(p * p, w) - mu_p * mu_p
    var_r = _filter_valid(r * r, w) - mu_r * mu_r
    cov = _filter_valid(p * r, w) - mu_p * mu_r
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    s = ((2 * mu_p * mu_r + c1) * (2 * cov + c2)) / ((mu_p**2 + mu_r**2 + c1) * (var_p + var_r + c2))
    return float(s.mean())


class MetricAccumulator:
    """Accumulates per-image metrics and a per-pixel mean absolute depth error map over a test set.

    add(pred_m (H, W), gt_m (H, W), aif_pred (3, H, W) | None, aif_ref (3, H, W) | None) per image;
    result() -> means over images (depth metrics over images with >= 1 valid pixel; 'psnr', 'ssim' over
    images with an all-in-focus reference) plus 'n_images'; error_map() -> (H, W) mean |p - g| over the images
    where each pixel is valid (NaN where never valid). The map needs every image at one size: images of several
    sizes (e.g. renders no larger than each camera's sensor) still give every metric, and `has_error_map` is False.
    """

    def __init__(self, focus_range_mask: bool = False, data_range: float = 1.0):
        self.focus_range_mask = focus_range_mask
        self.data_range = data_range
        self.rows: list[dict[str, float]] = []
        self._err_sum: np.ndarray | None = None
        self._err_n: np.ndarray | None = None
        self._sizes: set[tuple[int, ...]] = set()

    @property
    def has_error_map(self) -> bool:
        """True when images were added and all had one size."""
        return len(self._sizes) == 1

    def add(self, pred_m: np.ndarray, gt_m: np.ndarray, aif_pred: np.ndarray | None = None,
            aif_ref: np.ndarray | None = None, focus_m: np.ndarray | None = None) -> dict[str, float]:
        """One image; focus_m (S,) gives the focus range when focus_range_mask is set. Returns its metrics."""
        rng = None
        if self.focus_range_mask:
            if focus_m is None:
                raise ValueError("MetricAccumulator: focus_range_mask needs focus_m")
            rng = (float(np.min(focus_m)), float(np.max(focus_m)))
        row = depth_metrics(pred_m, gt_m, rng)
        if aif_pred is not None and aif_ref is not None:
            row["psnr"] = psnr(aif_pred, aif_ref, self.data_range)
            row["ssim"] = ssim(aif_pred, aif_ref, self.data_range, channel_axis=0 if np.ndim(aif_pred) == 3 else None)
        self.rows.append(row)
        m = valid_mask(gt_m, rng)
        err = np.where(m, np.abs(np.asarray(pred_m, np.float64) - np.where(m, gt_m, 0)), 0.0)
        self._sizes.add(err.shape)
        if self._err_sum is None:
            self._err_sum, self._err_n = np.zeros(err.shape), np.zeros(err.shape)
        if self.has_error_map:  # a per-pixel mean has no meaning across sizes: stop the map, keep the metrics
            self._err_sum += err
            self._err_n += m
        return row

    def result(self) -> dict[str, float]:
        out: dict[str, float] = {"n_images": len(self.rows)}
        for k in DEPTH_KEYS + ("psnr", "ssim"):
            vals = [r[k] for r in self.rows if k in r and np.isfinite(r[k]) and r.get("n_valid", 0) > 0]
            if k in ("psnr", "ssim"):
                vals = [r[k] for r in self.rows if k in r and not np.isnan(r[k])]
            if vals:
                out[k] = float(np.mean(vals))
        return out

    def error_map(self) -> np.ndarray:
        if self._err_sum is None:
            raise ValueError("MetricAccumulator: no images added")
        if not self.has_error_map:
            raise ValueError(f"MetricAccumulator: no error map: image sizes differ ({sorted(self._sizes)})")
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self._err_n > 0, self._err_sum / np.maximum(self._err_n, 1), np.nan)
