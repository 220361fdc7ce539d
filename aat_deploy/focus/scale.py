"""The working resolution of `--method focus`, chosen from the stack's blur scale (numpy + OpenCV).

Depth from focus tells frames apart by how much sharper one is than its neighbour. What matters is the **blur
step**: the defocus blur between two adjacent frames at a pixel in focus in one of them, in pixels. It is a product
of the camera (blur-disk diameter per diopter, about f^2 / (N p)) and the focus schedule (diopters between frames),
and neither needs to be known: it is measured from the frames themselves. Working at 1/k of the size divides the
step by k; as long as the step stays several pixels the method loses nothing, and everything after decoding runs
k^2 times faster.

**Measuring the step** (`blur_step_px`): on a grid of tiles of the frames at four pyramid levels (native, 1/2,
1/4, 1/8; `TileSampler`, a few MB per frame, cut while the frames are decoded), each tile's frames are compared by
a high-pass energy (the focus measure's: squared modified Laplacian after the 1 px pre-filter, averaged over the
tile's centre, each frame divided by its mean level first, so that exposure differences are not read as blur). In a
tile whose sharpest frame a stands out (textured, and at least `PEAK_CONTRAST` x the energy of its blurriest
frame), the Gaussian blur sigma that brings a's energy down to each neighbour's is found on a ladder of blurs of a
itself; the tile's step is the larger of its two neighbours' sigmas (at least sqrt(3)/2 of the true step for a
depth anywhere between a and a neighbour, under a blur linear in diopters). A level's step is the median over its
tiles, as a blur-disk diameter in native px (4 sigma, the disk's second moment, times 2^level); the stack's is the
largest over the levels with `MIN_TILES` usable tiles (noise and a phone's processing make fine levels read too
small a step, too coarse a level reads it too small as well). No such level: unknown.

**The rule** (`working_factor`): reduce by k = min(step / STEP_MIN_PX, longer side / SIDE_MIN_PX), not below 1
(and not at all when k < K_MIN): the step stays at least STEP_MIN_PX at the working size and the longer side at
least SIDE_MIN_PX. Chosen on validation stacks (`benchmarks/select_focus_resolution.py`, BENCHMARKS.md,
"Working resolution"): depth error against ground truth at the native grid, for every candidate pair, the pair that
reduces most without raising the error anywhere. The size floor is measured: from 1920 x 1280 stacks, working at
960 px is level on clean frames and better with noise; 960 x 640 stacks of 8 or 16 frames lose accuracy when reduced.
The step threshold is not decided by those sets (where the floor allowed a reduction, the step stayed >= 13 px):
8 px is the most cautious candidate.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .measures import LUMA, prefilter, second_diffs

STEP_MIN_PX = 8.0     # blur step (disk diameter, px) kept at the working size (the cautious end: module doc)
SIDE_MIN_PX = 960     # longer side kept at the working size (measured: module doc)
K_MIN = 1.25          # smaller reductions are not worth a resampling
TILE_PX = 64          # centre of a tile, where energies are compared
MARGIN_PX = 48        # context around it, so the ladder's blurs see real neighbours (sigma <= MARGIN_PX / 3)
GRID = (8, 6)         # tiles across x down on the longer x shorter side
PREFILTER_PX = 1.0    # as the focus measure's default (FocusConfig.prefilter_px)
PEAK_CONTRAST = 4.0   # a tile's sharpest frame has at least this x the energy of its blurriest
TEXTURE_REL = 0.02    # ... and at least this x the 90th percentile of the tiles' peak energies
MIN_TILES = 4
LEVELS = 4            # pyramid levels searched (native, 1/2, 1/4, 1/8)
LADDER = 0.3 * 1.25 ** np.arange(17)  # Gaussian sigmas tried, px: 0.3 ... 10.7 (MARGIN_PX / 3 = 16)


@dataclass(frozen=True)
class TileSampler:
    """Where the tiles sit in a frame of (H, W) px, at each pyramid level (the frame reduced by 2^level): top-left
    corners of (TILE_PX + 2 MARGIN_PX)^2 regions on a regular grid (fewer where the level is small).
    `sample(frame)` cuts them from one native frame: a list over the levels of (N_level, R, R) grey regions."""

    levels: tuple[tuple[tuple[int, int], ...], ...]

    @classmethod
    def for_size(cls, hw: tuple[int, int]) -> TileSampler:
        r = TILE_PX + 2 * MARGIN_PX
        levels = []
        for lev in range(LEVELS):
            h, w = (int(v) // 2 ** lev for v in hw)
            if min(h, w) < r:
                break
            nx, ny = GRID if w >= h else GRID[::-1]
            nx, ny = min(nx, w // r), min(ny, h // r)
            ys = np.linspace(0, h - r, ny).round().astype(int)
            xs = np.linspace(0, w - r, nx).round().astype(int)
            levels.append(tuple((int(y), int(x)) for y in ys for x in xs))
        return cls(tuple(levels))

    def sample(self, frame: np.ndarray) -> list[np.ndarray]:
        """frame (H, W, 3) linear RGB -> per level (N, R, R) float32 grey regions."""
        r = TILE_PX + 2 * MARGIN_PX
        g = cv2.transform(np.asarray(frame, np.float32), LUMA[None]) if frame.ndim == 3 else frame
        out = []
        for lev, corners in enumerate(self.levels):
            if lev:
                g = cv2.resize(g, (g.shape[1] // 2, g.shape[0] // 2), interpolation=cv2.INTER_AREA)
            out.append(np.stack([g[y:y + r, x:x + r] for y, x in corners]).astype(np.float32))
        return out


def _energy(regions: np.ndarray) -> np.ndarray:
    """(..., R, R) grey -> (...) mean high-pass energy over the centre TILE_PX^2: the focus measure's squared
    modified Laplacian after the pre-filter, averaged without its window."""
    flat = regions.reshape(-1, *regions.shape[-2:])
    c = slice(MARGIN_PX, MARGIN_PX + TILE_PX)
    e = np.empty(len(flat))
    for i, x in enumerate(prefilter(np.ascontiguousarray(flat, np.float32), PREFILTER_PX)):
        dxx, dyy = second_diffs(x, 1)
        ml = np.abs(dxx[c, c]) + np.abs(dyy[c, c])
        e[i] = float(np.mean(ml * ml))
    return e.reshape(regions.shape[:-2])


def _ladder_energy(region: np.ndarray) -> np.ndarray:
    """log energy of `region` (R, R) blurred by each sigma of LADDER."""
    blurred = np.stack([cv2.GaussianBlur(region, (0, 0), float(s), borderType=cv2.BORDER_REFLECT) for s in LADDER])
    return np.log(np.maximum(_energy(blurred), 1e-30))


def _matching_sigma(ladder_log_e: np.ndarray, target: float) -> float:
    """The ladder sigma (px, log-interpolated) at which the blurred region's energy falls to `target`: 0 if the
    unblurred region is already at or below it, the ladder's top if even that is above."""
    e = ladder_log_e
    t = np.log(max(target, 1e-30))
    if t >= e[0]:
        return 0.0
    if t <= e[-1]:
        return float(LADDER[-1])
    j = int(np.argmax(e < t))  # first ladder step below the target (energies fall with sigma)
    a = (e[j - 1] - t) / max(e[j - 1] - e[j], 1e-12)
    return float(np.exp(np.log(LADDER[j - 1]) + a * (np.log(LADDER[j]) - np.log(LADDER[j - 1]))))


def _level_sigmas(regions: np.ndarray) -> list[float]:
    """regions (S, N, R, R) of one level -> the relative blur sigma (px of that level) of every usable tile."""
    s, n = regions.shape[:2]
    c = slice(MARGIN_PX, MARGIN_PX + TILE_PX)
    gain = np.maximum(regions[:, :, c, c].mean((1, 2, 3)), 1e-12)  # per frame: exposure may differ
    scaled = regions / gain[:, None, None, None]
    energy = _energy(scaled)  # (S, N)
    peak = energy.max(0)
    texture = TEXTURE_REL * float(np.percentile(peak, 90))
    out = []
    for i in range(n):
        e = energy[:, i]
        a = int(np.argmax(e))
        if e[a] <= texture or e[a] < PEAK_CONTRAST * max(float(e.min()), 1e-30):
            continue
        ladder = _ladder_energy(scaled[a, i])
        out.append(max(_matching_sigma(ladder, float(e[b])) for b in (a - 1, a + 1) if 0 <= b < s))
    return out


def blur_step_px(levels: list[np.ndarray]) -> tuple[float | None, dict]:
    """levels: per pyramid level (S, N, R, R), the same tiles of S frames sorted by focus (`TileSampler`) -> (the
    stack's blur step as a blur-disk diameter in native px, or None when no level has MIN_TILES tiles with a focus
    peak; details per level).

    Each level's step is 4 x the median tile sigma x 2^level. Noise and a phone's processing put a floor under the
    high-pass energy of blurred frames, which makes the fine levels read too small a step, and a level too coarse
    for the step reads it too small as well: the stack's step is the largest level estimate."""
    per, best = [], None
    for lev, regions in enumerate(levels):
        if regions.shape[0] < 2 or regions.shape[1] == 0:
            continue
        sig = _level_sigmas(regions)
        row = {"level": lev, "tiles": int(regions.shape[1]), "used": len(sig)}
        if len(sig) >= MIN_TILES:
            row["step_px"] = round(4.0 * float(np.median(sig)) * 2 ** lev, 3)
            best = max(best or 0.0, row["step_px"])
        per.append(row)
    return best, {"levels": per}


def working_factor(step_px: float | None, hw: tuple[int, int]) -> float:
    """The reduction k >= 1 of the rule (module doc) for a stack of (H, W) frames with this blur step (native
    px; None = unknown: no reduction)."""
    if step_px is None or not np.isfinite(step_px):
        return 1.0
    k = min(step_px / STEP_MIN_PX, max(hw) / SIDE_MIN_PX)
    return float(k) if k >= K_MIN else 1.0


def rule_text() -> str:
    return (f"reduce by k = min(blur step / {STEP_MIN_PX:g} px, longer side / {SIDE_MIN_PX} px) when k >= "
            f"{K_MIN:g}: the blur step between adjacent frames stays >= {STEP_MIN_PX:g} px and the longer side "
            f">= {SIDE_MIN_PX} px")
