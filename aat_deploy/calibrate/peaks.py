"""Per sensor tile, where the focus curve of a chart sweep peaks, and how fast blur grows away from it (numpy +
OpenCV, torch-free).

A sweep is one chart position shot at many focus settings. Each tile of the frame (`tile_px` square) sees a small
patch of the flat chart at a known distance (`pose.py`); its focus curve is the project's focus measure
(`aat_deploy.focus.measures`, the settings of `FocusConfig`: the calibration belongs to the measure it was made
with) averaged over the tile, across the frames. Its peak, with the project's estimator (`estimate.estimate_peak`,
`gauss` by default: on a dense sweep the three frames around the peak lie on the curve's core, where a Gaussian
fits; `ratio` is for coarse schedules), is the reported focus, in diopters, that has the tile's object in focus.

A tile counts when it lies wholly on the chart, its curve rises clearly above its floor (textured) and the peak is
not at the sweep's first or last frame (bracketed).

Blur growth: the frame whose tile is sharpest, blurred with Gaussians of increasing sigma, is compared with every
other frame's tile (squared difference over the tile); the sigma that matches best is that frame's blur relative
to the sharpest one. Against the frames' defocus (diopters between the frame's in-focus distance and the tile's
object, from the fitted model) sigma_rel^2 = k^2 (defocus^2 - defocus_sharpest^2): k is the Gaussian-equivalent
sigma per diopter; the blur-disk diameter per diopter is 4 k (a disk's second moment).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..focus.estimate import estimate_peak
from ..focus.measures import focus_volume, grey

TAU_REL = 0.01  # a tile whose sharpest measure is under 1 % of the frame's best is textureless
SIGMAS_PX = np.concatenate([np.arange(0.0, 3.0, 0.25), np.arange(3.0, 8.0, 0.5), np.arange(8.0, 16.01, 1.0)])


@dataclass
class TileGrid:
    """tile_px square tiles over an (H, W) frame: floor(side / tile_px) tiles per side, centred, the remainder an
    unmeasured border (what `aat-calibrate fit` uses); or, with to_edges, spread from edge to edge:
    ceil(side / tile_px) = n tiles per side, the outermost flush with the frame's borders and the rest evenly between
    (integer starts), neighbours overlapping by (n * tile_px - side) / (n - 1) px on average where tile_px does not
    divide the side (0.35 px on the phone's 640 x 480 in 27 px tiles, each overlap 0 or 1 px; (tile_px - 1) / k px
    on a side of k tiles and one pixel), so that the tiles reach the frame's corners (on a 640 x 480 frame in 27 px
    tiles the farthest tile centre lies at field radius 0.953 instead of 0.920; benchmarks/probes/corner_tiles.py
    and BENCHMARKS.md, "The tiles and the frame's corners", for why it is not the fit's default). Where tile_px
    divides both sides the two are the same grid. ValueError for a tile_px outside 1 to the frame's shorter side."""

    height: int
    width: int
    tile_px: int
    to_edges: bool = False

    def __post_init__(self):
        if not 1 <= self.tile_px <= min(self.height, self.width):
            raise ValueError(f"tiles of {self.tile_px} px on a {self.width} x {self.height} px frame")

    def _starts(self, side: int) -> np.ndarray:
        t = self.tile_px
        if not self.to_edges:
            n = side // t
            return (side - n * t) // 2 + np.arange(n, dtype=np.int64) * t
        n = -(-side // t)
        return np.round(np.linspace(0, side - t, n)).astype(np.int64) if n > 1 else np.zeros(1, np.int64)

    @property
    def starts(self) -> tuple[np.ndarray, np.ndarray]:
        """Row starts (ny,) and column starts (nx,) of the tiles (px)."""
        return self._starts(self.height), self._starts(self.width)

    @property
    def shape(self) -> tuple[int, int]:
        rows, cols = self.starts
        return len(rows), len(cols)

    @property
    def contiguous(self) -> bool:
        """The tiles abut (no overlap): the centred grid, or tile_px dividing both sides."""
        return not self.to_edges or (self.height % self.tile_px == 0 and self.width % self.tile_px == 0)

    def mean(self, img: np.ndarray) -> np.ndarray:
        """(..., H, W) -> (..., ny, nx) tile means."""
        t = self.tile_px
        ny, nx = self.shape
        rows, cols = self.starts
        if self.contiguous:
            r0, c0 = int(rows[0]), int(cols[0])
            x = img[..., r0:r0 + ny * t, c0:c0 + nx * t]
            return x.reshape(*x.shape[:-2], ny, t, nx, t).mean((-3, -1))
        x = np.stack([img[..., c:c + t].mean(-1) for c in cols], -1)  # (..., H, nx)
        return np.stack([x[..., r:r + t, :].mean(-2) for r in rows], -2)

    def owner(self) -> tuple[np.ndarray, np.ndarray]:
        """(H,) tile row and (W,) tile column each pixel belongs to (the tile whose centre is nearest)."""
        u, v = self.centres_px()
        return (np.argmin(np.abs(np.arange(self.height)[:, None] - v[:, 0][None]), 1),
                np.argmin(np.abs(np.arange(self.width)[:, None] - u[0][None]), 1))

    def centres_px(self) -> tuple[np.ndarray, np.ndarray]:
        """(ny, nx) pixel coordinates u (column), v (row) of the tile centres (OpenCV convention)."""
        rows, cols = self.starts
        t = self.tile_px
        return np.meshgrid(cols + t / 2 - 0.5, rows + t / 2 - 0.5)

    def field(self) -> tuple[np.ndarray, np.ndarray]:
        """(ny, nx) normalised field x (right), y (up) of the tile centres."""
        u, v = self.centres_px()
        return 2 * (u + 0.5) / self.width - 1, 1 - 2 * (v + 0.5) / self.height


@dataclass
class SweepPeaks:
    """One sweep's tiles: reported_d (S,) ascending; curves (S, ny, nx) tile focus measure; peak_d (ny, nx)
    reported diopters of the peak (NaN where the tile does not count); why (ny, nx) str codes: "" counted,
    "off_chart", "flat" (no texture), "unbracketed" (peak at the first or last frame); contrast (ny, nx) the
    curve's (max - min) / (max + tau), tau = TAU_REL x the 99th percentile of the tiles' max; sharpest (ny, nx) frame index."""

    grid: TileGrid
    reported_d: np.ndarray
    curves: np.ndarray
    peak_d: np.ndarray
    why: np.ndarray
    contrast: np.ndarray
    sharpest: np.ndarray

    @property
    def counted(self) -> np.ndarray:
        return self.why == ""


def tile_peaks(frames: np.ndarray, reported_d: np.ndarray, grid: TileGrid, on_chart: np.ndarray,
               measure: str = "mlap2", window_px: float = 15.0, prefilter_px: float = 1.0,
               estimator: str = "gauss", min_contrast: float = 0.5) -> SweepPeaks:
    """frames (S, 3, H, W) linear, sorted by reported_d (S,) ascending (distinct); on_chart (ny, nx) bool: the
    tile lies wholly on the chart. min_contrast: least (max - min) / max of a counted tile's curve."""
    vol = focus_volume(frames, measure, window_px, prefilter_px=prefilter_px)
    curves = grid.mean(vol).astype(np.float64)  # (S, ny, nx)
    s = curves.shape[0]
    est = "gauss" if estimator == "gauss" else estimator
    peak = estimate_peak(curves.astype(np.float32), np.asarray(reported_d, np.float32), None, est)
    k = peak.index
    mx, mn = curves.max(0), curves.min(0)
    tau = TAU_REL * float(np.percentile(mx, 99))  # as the focus method's confidence: relative to the frame's best
    contrast = (mx - mn) / np.maximum(mx + tau, 1e-30)
    why = np.full(k.shape, "", dtype=object)
    why[~on_chart] = "off_chart"
    why[(why == "") & (contrast < min_contrast)] = "flat"
    why[(why == "") & ((k == 0) | (k == s - 1))] = "unbracketed"
    pd = np.where(why == "", peak.diopters.astype(np.float64), np.nan)
    return SweepPeaks(grid, np.asarray(reported_d, np.float64), curves, pd, why.astype(str), contrast, k)


def relative_blur_px(frames: np.ndarray, sharpest: np.ndarray, grid: TileGrid,
                     sigmas: np.ndarray = SIGMAS_PX) -> np.ndarray:
    """(S, ny, nx) Gaussian sigma (px) that takes each tile's sharpest frame to frame s (NaN beyond the grid's
    largest sigma). frames (S, 3, H, W) linear; sharpest (ny, nx) frame index per tile."""
    g = grey(frames)  # (S, H, W)
    s = g.shape[0]
    ny, nx = grid.shape
    # the composite of each tile's sharpest frame (every pixel of a tile from its own sharpest frame)
    # (pixels of no tile, the centred grid's border, from the first frame)
    row, col = grid.owner()
    (rows, cols), t = grid.starts, grid.tile_px
    inside = ((np.arange(g.shape[1]) >= rows[0]) & (np.arange(g.shape[1]) < rows[-1] + t))[:, None] & \
        ((np.arange(g.shape[2]) >= cols[0]) & (np.arange(g.shape[2]) < cols[-1] + t))[None, :]
    idx = np.where(inside, sharpest[row[:, None], col[None, :]], 0)
    ref = np.take_along_axis(g, idx[None], 0)[0]
    sse = np.empty((len(sigmas), s, ny, nx))
    for i, sg in enumerate(sigmas):
        b = ref if sg == 0 else cv2.GaussianBlur(ref, (0, 0), float(sg), borderType=cv2.BORDER_REFLECT)
        sse[i] = grid.mean((g - b[None]) ** 2)
    best = np.argmin(sse, 0)  # (S, ny, nx)
    # parabola through the best sigma and its neighbours (uneven spacing)
    i0, i2 = np.clip(best - 1, 0, len(sigmas) - 1), np.clip(best + 1, 0, len(sigmas) - 1)
    take = lambda i: np.take_along_axis(sse, i[None], 0)[0]
    y0, y1, y2 = take(i0), take(best), take(i2)
    x0, x1, x2 = sigmas[i0], sigmas[best], sigmas[i2]
    a, b_ = x1 - x0, x1 - x2
    fa, fb = y1 - y2, y1 - y0
    den = a * fa - b_ * fb
    with np.errstate(divide="ignore", invalid="ignore"):
        v = x1 - 0.5 * (a * a * fa - b_ * b_ * fb) / den
    inner = (best > 0) & (best < len(sigmas) - 1) & (np.abs(den) > 1e-30)
    out = np.where(inner, np.clip(v, x0, x2), x1)
    return np.where(best == len(sigmas) - 1, np.nan, out)


def blur_slope(sigma_rel: np.ndarray, defocus_d: np.ndarray, sharpest: np.ndarray, lo_px: float = 1.0,
               hi_px: float = 12.0) -> np.ndarray:
    """(ny, nx) Gaussian-equivalent sigma per diopter k from sigma_rel (S, ny, nx) and the frames' defocus (S, ny,
    nx) diopters (frame in-focus minus object): least squares of sigma_rel^2 = k^2 (defocus^2 - defocus_0^2)
    over the frames with lo_px <= sigma_rel <= hi_px (defocus_0: the sharpest frame's). NaN with fewer than 2."""
    d0 = np.take_along_axis(defocus_d, sharpest[None], 0)[0]
    a = defocus_d ** 2 - d0[None] ** 2
    y = sigma_rel ** 2
    ok = np.isfinite(y) & (sigma_rel >= lo_px) & (sigma_rel <= hi_px) & (a > 0)
    num = np.where(ok, a * y, 0).sum(0)
    den = np.where(ok, a * a, 0).sum(0)
    k2 = np.where(ok.sum(0) >= 2, num / np.maximum(den, 1e-30), np.nan)
    return np.sqrt(np.maximum(k2, 0))
