"""Confidence intervals for binned means of a per-pixel quantity (the gap), over captures and pixels.

Neighbouring pixels are not independent, so pixels are resampled in tiles: a two-level Poisson bootstrap
(each capture and, inside it, each tile gets an independent Poisson(1) weight per replicate) of the ratio
sum(weight * value) / sum(weight * count) per bin."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TILE_PX = 16


@dataclass
class BinnedStats:
    mean: np.ndarray  # (n_bins,) NaN where a bin is empty
    ci_low: np.ndarray
    ci_high: np.ndarray
    pixels: np.ndarray  # (n_bins,) int


def unit_sums(values: list[np.ndarray], index: list[np.ndarray], n_bins: int, tile: int = TILE_PX):
    """Per (capture, tile) sums and counts per bin. values[c], index[c]: (H, W); index -1 or NaN value = skip.
    Returns capture id (U,), sums (U, n_bins), counts (U, n_bins)."""
    caps, sums, counts = [], [], []
    for c, (v, idx) in enumerate(zip(values, index)):
        h, w = v.shape
        ok = (idx >= 0) & np.isfinite(v)
        tid = (np.arange(h)[:, None] // tile) * ((w + tile - 1) // tile) + (np.arange(w)[None, :] // tile)
        n_t = int(tid.max()) + 1
        key = tid[ok] * n_bins + idx[ok]
        s = np.bincount(key, weights=v[ok], minlength=n_t * n_bins).reshape(n_t, n_bins)
        k = np.bincount(key, minlength=n_t * n_bins).reshape(n_t, n_bins)
        keep = k.sum(1) > 0
        caps.append(np.full(int(keep.sum()), c))
        sums.append(s[keep])
        counts.append(k[keep])
    return np.concatenate(caps), np.concatenate(sums), np.concatenate(counts)


def binned_bootstrap(values: list[np.ndarray], index: list[np.ndarray], n_bins: int, n_boot: int = 400,
                     seed: int = 0, level: float = 0.95) -> BinnedStats:
    cap, s, k = unit_sums(values, index, n_bins)
    total_k = k.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s.sum(0) / total_k
    rng = np.random.default_rng(seed)
    n_caps = int(cap.max()) + 1 if cap.size else 0
    wc = rng.poisson(1.0, size=(n_boot, n_caps)) if n_caps > 1 else np.ones((n_boot, max(n_caps, 1)))
    wt = rng.poisson(1.0, size=(n_boot, len(cap))) * wc[:, cap]
    with np.errstate(invalid="ignore", divide="ignore"):
        reps = (wt @ s) / (wt @ k)  # (n_boot, n_bins)
    a = (1 - level) / 2
    lo, hi = np.full(n_bins, np.nan), np.full(n_bins, np.nan)
    seen = np.isfinite(reps).any(0)  # empty bins keep NaN
    lo[seen] = np.nanquantile(reps[:, seen], a, axis=0)
    hi[seen] = np.nanquantile(reps[:, seen], 1 - a, axis=0)
    return BinnedStats(mean, lo, hi, total_k.astype(np.int64))


def capture_bootstrap(per_capture: np.ndarray, weights: np.ndarray | None = None, n_boot: int = 400,
                      seed: int = 0, level: float = 0.95) -> tuple[float, float, float]:
    """Weighted mean over captures of a per-capture score and its bootstrap interval (captures resampled)."""
    x = np.asarray(per_capture, np.float64)
    w = np.ones_like(x) if weights is None else np.asarray(weights, np.float64)
    mean = float(np.sum(w * x) / np.sum(w))
    if len(x) < 2:
        return mean, mean, mean
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(x), size=(n_boot, len(x)))
    reps = np.sum(w[idx] * x[idx], 1) / np.sum(w[idx], 1)
    a = (1 - level) / 2
    return mean, float(np.quantile(reps, a)), float(np.quantile(reps, 1 - a))


def ratio_bootstrap(num: list[np.ndarray], den: list[np.ndarray], n_boot: int = 400, seed: int = 0,
                    level: float = 0.95) -> tuple[float, float, float]:
    """sum(num) / sum(den) over all captures' valid pixels, with a two-level (capture, tile) Poisson bootstrap
    interval; num[c], den[c] (H, W), NaN = skip (in either)."""
    idx = [np.where(np.isfinite(n) & np.isfinite(d), 0, -1) for n, d in zip(num, den)]
    cap, sn, _ = unit_sums(num, idx, 1)
    _, sd, _ = unit_sums(den, idx, 1)
    est = float(sn.sum() / sd.sum()) if sd.sum() != 0 else float("nan")
    rng = np.random.default_rng(seed)
    n_caps = int(cap.max()) + 1
    wc = rng.poisson(1.0, size=(n_boot, n_caps)) if n_caps > 1 else np.ones((n_boot, 1))
    w = rng.poisson(1.0, size=(n_boot, len(cap))) * wc[:, cap]
    with np.errstate(invalid="ignore", divide="ignore"):
        reps = (w @ sn[:, 0]) / (w @ sd[:, 0])
    a = (1 - level) / 2
    return est, float(np.nanquantile(reps, a)), float(np.nanquantile(reps, 1 - a))
