"""The sensor's full well from the capture's own RAW mosaic by photon transfer (issue 32; docs/diagnosis.md, "The
full well by photon transfer"): the textbook way a sensor's gain is measured (EMVA 1288's photon-transfer curve:
temporal variance against mean signal, var = mean / full well + (read / full well)^2 in white-level units), done
on one image's flat patches instead of a flat-field series, as single-image Poisson-Gaussian estimators do (Foi et
al. 2008, "Practical Poissonian-Gaussian noise modeling and fitting for single-image raw-data").

- Each CFA plane (one colour's photosites: independent noise, no demosaicking) is cut into 2 x 2 cells; a cell's
  Haar details h (columns), v (rows) and d (diagonal) each have the noise's variance (their taps +-1/2, squares
  summing to 1) and remove a constant signal; d removes a linear ramp too.
- Cells are grouped into blocks of BLOCK_CELLS x BLOCK_CELLS; a block's noise variance is the mean of its d^2, its
  level the mean of its photosites. A block with a photosite at or over CLIP_LEVEL is left out (clipped noise has
  less variance).
- Blocks are pooled into N_LEVEL_BINS bins of equal count by level; each bin's point is its median level and its
  median variance (what texture is left only adds variance, and the median ignores a minority of it), corrected for
  the median of a chi-square's downward bias (a bin's mean level with its median variance read a dark scene, whose
  levels are skewed, 50 % high); var = a * level + b by least squares over the bins, weighted by each bin's
  block count over its variance squared. full well = 1 / a, read noise = sqrt(max(b, 0)) / a.
- Texture raises h^2 and v^2 (first differences) far more than d^2: a block whose mean h^2 or v^2 exceeds the
  curve's variance at its level by MAX_HV_RATIO is rejected as textured, and the curve fitted again (REFITS times).
  The test compares h and v with the curve, never with the block's own d: for pure noise the three details are
  independent, so the rejection cannot select blocks by their d^2 (testing h^2 / d^2 kept the blocks whose d^2 came
  out high by chance: 6 % low on flat synthetic patches).

Pure functions over arrays; `photon_transfer` is the estimate, `cfa_planes` the layout.
"""

from __future__ import annotations

import numpy as np

BLOCK_CELLS = 8  # a block is 8 x 8 cells of 2 x 2 photosites of one colour (a 32 x 32 px patch of the mosaic)
# a block whose column or row detail energy exceeds the curve's noise variance by this is textured: the larger of two
# means of 64 squared normals exceeds 1.6 with probability ~2 % (false rejections lose data, they bias nothing)
MAX_HV_RATIO = 1.6
REFITS = 3
CLIP_LEVEL = 0.95  # a block with a photosite at or over this (white = 1) is left out: clipping cuts its noise
N_LEVEL_BINS = 8  # the photon-transfer curve's points (blocks pooled by level, equal counts)
MIN_BLOCKS = 40  # fewer flat blocks than this: no estimate


def cfa_planes(mosaic: np.ndarray) -> list[np.ndarray]:
    """(H, W) mosaic -> the 2 x 2 pattern's four planes (H/2, W/2), one per photosite position whatever its colour
    (the two greens stay apart: each plane's neighbours are one colour, so a flat patch is flat in it)."""
    h, w = (s - s % 2 for s in mosaic.shape)
    return [mosaic[i:h:2, j:w:2] for i in (0, 1) for j in (0, 1)]


def block_stats(plane: np.ndarray, block_cells: int = BLOCK_CELLS) -> tuple[np.ndarray, ...]:
    """One plane (white = 1) -> per block (level, noise variance from d^2, the larger of the mean h^2 and v^2,
    largest photosite)."""
    p = np.asarray(plane, np.float64)
    n = 2 * block_cells
    hb, wb = p.shape[0] // n, p.shape[1] // n
    p = p[:hb * n, :wb * n]
    a, b, c, e = p[0::2, 0::2], p[0::2, 1::2], p[1::2, 0::2], p[1::2, 1::2]
    h = (a - b + c - e) / 2  # across columns
    v = (a + b - c - e) / 2  # across rows
    d = (a - b - c + e) / 2  # diagonal

    def per_block(x):
        return x.reshape(hb, block_cells, wb, block_cells).mean(axis=(1, 3)).ravel()

    hv = np.maximum(per_block(h * h), per_block(v * v))
    level = p.reshape(hb, n, wb, n).mean(axis=(1, 3)).ravel()
    top = p.reshape(hb, n, wb, n).max(axis=(1, 3)).ravel()
    return level, per_block(d * d), hv, top


def transfer_curve(level: np.ndarray, var: np.ndarray, m: int, n_bins: int = N_LEVEL_BINS) -> tuple[float, float, list]:
    """Blocks' (level, variance of m squared details) -> (slope, intercept, [[level, variance, blocks], ...]) of
    var = slope * level + intercept over bins of equal count (each bin's median level and median variance, the latter corrected to a mean)."""
    order = np.argsort(level)
    bias = (1.0 - 2.0 / (9.0 * m)) ** 3  # a chi-square's median over its mean (Wilson-Hilferty), 0.99 at m = 64
    rows = [[float(np.median(level[i])), float(np.median(var[i])) / bias, int(i.size)] for i in np.array_split(order, n_bins)]
    x, y, k = (np.array(c, np.float64) for c in zip(*rows))
    sw = np.sqrt(k) / np.maximum(y, 1e-30)  # each bin's weight: its count over its variance squared
    slope, icpt = np.linalg.lstsq(np.stack([x, np.ones_like(x)], 1) * sw[:, None], y * sw, rcond=None)[0]
    return float(slope), float(icpt), rows


def photon_transfer(planes: list[np.ndarray], block_cells: int = BLOCK_CELLS, max_hv: float = MAX_HV_RATIO,
                    clip: float = CLIP_LEVEL, n_bins: int = N_LEVEL_BINS) -> dict | None:
    """Planes of independent photosites (white = 1, black = 0) -> {"full_well_e", "read_noise_e", "n_blocks" (the
    blocks the returned curve was fitted on), "curve": [[level, variance, blocks], ...]}; None when fewer than
    MIN_BLOCKS flat blocks or no positive slope."""
    level, var, hv, top = (np.concatenate(x) for x in zip(*(block_stats(p, block_cells) for p in planes)))
    ok = (top < clip) & (level > 0) & np.isfinite(var) & np.isfinite(hv)
    level, var, hv = level[ok], var[ok], hv[ok]
    m = block_cells * block_cells
    keep = np.ones(level.size, bool)
    for _ in range(REFITS + 1):
        if keep.sum() < max(MIN_BLOCKS, n_bins):
            return None
        slope, icpt, rows = transfer_curve(level[keep], var[keep], m, n_bins)
        if not slope > 0:
            return None
        n_fitted = int(keep.sum())  # the blocks this curve was fitted on (the next pass's rejection is not used)
        keep = hv <= max_hv * np.maximum(slope * level + icpt, 1e-30)
    return {"full_well_e": 1.0 / slope, "read_noise_e": float(np.sqrt(max(icpt, 0.0)) / slope),
            "n_blocks": n_fitted, "curve": rows}
