"""The project's measurement vocabulary: where a pixel sits in the field, the field zones, and intervals.

Every table, plot and diagnosis measures with these (aat-eval, aat-diagnose, the held-out evaluation of
training/train/heldout.py, the classical method's best-focus map, benchmarks/), so "outer field" means one thing.

- **Field radius** (`field_radius`): the distance of a pixel centre from the optical axis (the frame's centre)
  over the half-diagonal: 0 at the centre, 1 at the corners; circular, so on a 3:2 frame the midpoints of the long
  edges (top, bottom) are at 0.55 and those of the short edges at 0.83. Measured on the sensor in mm when its size
  is given (the pixels need not be square); the radius in mm is this times the sensor's half-diagonal.
- **Zones** (`zone_masks`): centre r < 0.33, middle 0.33 <= r <= 0.66, outer r > 0.66.
- **Intervals**: percentile bootstrap, 95 % unless said. Over units with a per-unit score (`bootstrap_mean`:
  scenes, captures); paired over the same scenes (`paired_ratio` of means, `paired_diff`), and over scenes within groups
  (`nested_paired_ratio`: groups resampled, then their scenes); and for per-pixel
  quantities, whose neighbours are not independent, a two-level Poisson bootstrap over (capture, tile)
  (`binned_bootstrap`, `ratio_bootstrap`).

Pure numpy; no file is read or written here. Depth as 16-bit mm PNG: `aat_deploy.io.depth_png`; colour maps:
`aat_deploy.io.colorize`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

ZONE_EDGES = (0.33, 0.66)  # field radius: centre below the first, outer above the second
ZONES = ("centre", "middle", "outer")
N_BOOT = 2000  # replicates of the benchmark tables' intervals
TILE_PX = 16  # side of the pixel tiles resampled together by the per-pixel bootstraps


# -- where in the field --------------------------------------------------------------------------------------------
def field_radius(h: int, w: int, sensor_mm: tuple[float, float] | None = None) -> np.ndarray:
    """(H, W) float64 field radius of each pixel centre of an H x W frame: distance from the frame's centre over
    the half-diagonal (0 centre, 1 corner). sensor_mm (width, height): the frame spans a sensor of that size and
    distances are measured on it in mm; None = square pixels."""
    sw, sh = (float(w), float(h)) if sensor_mm is None else (float(sensor_mm[0]), float(sensor_mm[1]))
    y = ((np.arange(h) + 0.5) / h - 0.5) * sh
    x = ((np.arange(w) + 0.5) / w - 0.5) * sw
    return np.hypot(x[None, :], y[:, None]) / (0.5 * np.hypot(sw, sh))


def zone_masks(h: int, w: int, sensor_mm: tuple[float, float] | None = None) -> dict[str, np.ndarray]:
    """{"centre", "middle", "outer"}: (H, W) bool masks of the field zones (ZONE_EDGES of `field_radius`)."""
    r = field_radius(h, w, sensor_mm)
    lo, hi = ZONE_EDGES
    return {"centre": r < lo, "middle": (r >= lo) & (r <= hi), "outer": r > hi}


# -- intervals over units (scenes, captures) -----------------------------------------------------------------------
def _quantiles(reps: np.ndarray, level: float) -> tuple[float, float]:
    a = (1 - level) / 2
    return float(np.quantile(reps, a)), float(np.quantile(reps, 1 - a))


def bootstrap_mean(values, weights=None, n_boot: int = 400, seed: int = 0,
                   level: float = 0.95) -> tuple[float, float, float]:
    """(mean, low, high): the weighted mean of per-unit scores (N,) and its bootstrap interval, units resampled.
    With one unit the interval is the mean itself."""
    x = np.asarray(values, np.float64)
    w = np.ones_like(x) if weights is None else np.asarray(weights, np.float64)
    mean = float(np.sum(w * x) / np.sum(w))
    if len(x) < 2:
        return mean, mean, mean
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(x), size=(n_boot, len(x)))
    reps = np.sum(w[idx] * x[idx], 1) / np.sum(w[idx], 1)
    return (mean, *_quantiles(reps, level))


def summarise(per_scene: Sequence[Mapping[str, float]], keys=None, n_boot: int = N_BOOT,
              seed: int = 1) -> dict[str, list[float]]:
    """{key: [mean, low, high]} over scenes of per-scene scores (one mapping per scene; keys default to the first
    scene's); non-finite scores are left out, NaN for a key with none."""
    out = {}
    for k in (per_scene[0].keys() if keys is None else keys):
        v = np.array([s[k] for s in per_scene], np.float64)
        v = v[np.isfinite(v)]
        out[k] = list(bootstrap_mean(v, n_boot=n_boot, seed=seed)) if v.size else [float("nan")] * 3
    return out


def paired_ratio(a: Sequence[Mapping[str, float]], b: Sequence[Mapping[str, float]], key: str = "mae",
                 n_boot: int = N_BOOT, seed: int = 2, level: float = 0.95) -> list[float]:
    """[ratio, low, high]: mean over scenes of a[key] / mean of b[key], a and b the same scenes in the same order,
    with a paired bootstrap interval (scenes resampled together); NaN interval with one scene."""
    x = np.array([s[key] for s in a], np.float64)
    y = np.array([s[key] for s in b], np.float64)
    est = float(x.mean() / y.mean())
    if len(x) < 2:
        return [est, float("nan"), float("nan")]
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(x), size=(n_boot, len(x)))
    return [est, *_quantiles(x[idx].mean(1) / y[idx].mean(1), level)]


def nested_paired_ratio(a: Sequence[Sequence[Mapping[str, float]]], b: Sequence[Sequence[Mapping[str, float]]],
                        key: str = "mae", n_boot: int = N_BOOT, seed: int = 4, level: float = 0.95,
                        crossed: bool = False) -> list[float]:
    """[ratio, low, high]: mean of a[key] over every group's scenes / the same of b[key], where a[g] and b[g] are
    the same scenes of group g (e.g. one lens copy) in the same order, with a two-level paired bootstrap: groups
    resampled, then scenes within each resampled group (both mappings together). crossed: every group holds the
    same scenes in the same order (each lens copy renders the same held-out scenes), so one draw of scene indices
    per replicate serves every group: a scene hard for every copy stays one scene (independent draws per group
    would average its weight out and narrow the interval). With one group the interval is over its scenes alone
    (`paired_ratio`'s); NaN interval with one scene in all."""
    xs = [np.array([s[key] for s in g], np.float64) for g in a]
    ys = [np.array([s[key] for s in g], np.float64) for g in b]
    if [len(x) for x in xs] != [len(y) for y in ys]:
        raise ValueError("nested_paired_ratio: a and b must hold the same scenes per group")
    if crossed and len({len(x) for x in xs}) > 1:
        raise ValueError("nested_paired_ratio: crossed needs the same scenes in every group")
    est = float(np.concatenate(xs).mean() / np.concatenate(ys).mean())
    if sum(len(x) for x in xs) < 2:
        return [est, float("nan"), float("nan")]
    rng = np.random.default_rng(seed)
    reps = np.empty(n_boot)
    for i in range(n_boot):
        groups = rng.integers(0, len(xs), len(xs)) if len(xs) > 1 else [0]
        shared = rng.integers(0, len(xs[0]), len(xs[0])) if crossed else None
        sx = sy = 0.0
        for g in groups:
            j = shared if crossed else rng.integers(0, len(xs[g]), len(xs[g]))
            sx, sy = sx + xs[g][j].sum(), sy + ys[g][j].sum()
        reps[i] = sx / sy
    return [est, *_quantiles(reps, level)]


def paired_diff(a: Sequence[Mapping[str, float]], b: Sequence[Mapping[str, float]], key: str = "psnr",
                n_boot: int = N_BOOT, seed: int = 3, level: float = 0.95) -> list[float]:
    """[difference, low, high]: mean over the scenes where both are finite of a[key] - b[key], with a paired
    bootstrap interval (e.g. all-in-focus PSNR in dB, the paper's Table 3 comparison)."""
    d = np.array([x[key] - y[key] for x, y in zip(a, b)], np.float64)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return [float("nan")] * 3
    est = float(d.mean())
    if d.size < 2:
        return [est, float("nan"), float("nan")]
    rng = np.random.default_rng(seed)
    return [est, *_quantiles(d[rng.integers(0, d.size, size=(n_boot, d.size))].mean(1), level)]


def fmt_interval(v: Sequence[float], digits: int = 3) -> str:
    """'m [lo, hi]' of a [mean, low, high]; 'm' without a real interval, '–' without a value."""
    m, lo, hi = v
    if not np.isfinite(m):
        return "–"
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo == hi:
        return f"{m:.{digits}f}"
    return f"{m:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


# -- intervals of per-pixel quantities: tiles of neighbouring pixels resampled together ---------------------------
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


def _poisson_weights(rng: np.random.Generator, cap: np.ndarray, n_boot: int) -> np.ndarray:
    """(n_boot, U) weights: Poisson(1) per capture (when there are several) times Poisson(1) per tile."""
    n_caps = int(cap.max()) + 1 if cap.size else 0
    wc = rng.poisson(1.0, size=(n_boot, n_caps)) if n_caps > 1 else np.ones((n_boot, max(n_caps, 1)))
    return rng.poisson(1.0, size=(n_boot, len(cap))) * wc[:, cap]


def binned_bootstrap(values: list[np.ndarray], index: list[np.ndarray], n_bins: int, n_boot: int = 400,
                     seed: int = 0, level: float = 0.95) -> BinnedStats:
    """Mean of a per-pixel quantity per bin over all captures, with a two-level (capture, tile) Poisson bootstrap
    interval of sum(weight * value) / sum(weight * count). values[c], index[c] (H, W) as `unit_sums`."""
    cap, s, k = unit_sums(values, index, n_bins)
    total_k = k.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s.sum(0) / total_k
    wt = _poisson_weights(np.random.default_rng(seed), cap, n_boot)
    with np.errstate(invalid="ignore", divide="ignore"):
        reps = (wt @ s) / (wt @ k)  # (n_boot, n_bins)
    a = (1 - level) / 2
    lo, hi = np.full(n_bins, np.nan), np.full(n_bins, np.nan)
    seen = np.isfinite(reps).any(0)  # empty bins keep NaN
    lo[seen] = np.nanquantile(reps[:, seen], a, axis=0)
    hi[seen] = np.nanquantile(reps[:, seen], 1 - a, axis=0)
    return BinnedStats(mean, lo, hi, total_k.astype(np.int64))


def ratio_bootstrap(num: list[np.ndarray], den: list[np.ndarray], n_boot: int = 400, seed: int = 0,
                    level: float = 0.95) -> tuple[float, float, float]:
    """sum(num) / sum(den) over all captures' valid pixels, with a two-level (capture, tile) Poisson bootstrap
    interval; num[c], den[c] (H, W), NaN = skip (in either)."""
    idx = [np.where(np.isfinite(n) & np.isfinite(d), 0, -1) for n, d in zip(num, den)]
    cap, sn, _ = unit_sums(num, idx, 1)
    _, sd, _ = unit_sums(den, idx, 1)
    est = float(sn.sum() / sd.sum()) if sd.sum() != 0 else float("nan")
    w = _poisson_weights(np.random.default_rng(seed), cap, n_boot)
    with np.errstate(invalid="ignore", divide="ignore"):
        reps = (w @ sn[:, 0]) / (w @ sd[:, 0])
    a = (1 - level) / 2
    return est, float(np.nanquantile(reps, a)), float(np.nanquantile(reps, 1 - a))
