"""Confidence that means something: the chance that a pixel's depth is within a stated tolerance of the truth.

A depth method's own score (the focus method's contrast of the focus curve, the fill's support, a DfF model's
predicted std) is not a probability. A `Calibration` maps it to one: measured on held-out rendered validation
stacks (noise and phone processing included; `benchmarks/calibrate_confidence.py`), confidence c at a pixel is
the share of validation pixels with that score whose depth was within `tolerance_rel` of the truth
(|depth - truth| <= tolerance_rel x truth). The map is monotone (isotonic regression, pool-adjacent-violators),
piecewise linear between its knots, constant beyond them.

Below `min_confidence` a depth is "unknown" (`mark_unknown`): NaN in depth_m (grey in the previews, left out of
the point cloud). The focus method fills unconfident pixels from their surroundings; a filled pixel carries the
fill's own calibrated confidence and is unknown only if that too is below the threshold.

Files (format FORMAT, docs/contracts.md "Confidence calibration"): the focus method's ships in
`aat_deploy/focus/data/confidence.json` (curves `estimate` and `fill`); a model's sits next to it as
`<model stem>.confidence.json` (curve `relative_std`: the predicted std over the depth).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from .errors import CaptureError
from .io.atomic import write_text_atomic
from .io.files import load_json

FORMAT = "aat-confidence-calibration-v1"
TOLERANCE_REL = 0.10  # "within 10 % of the true depth"
MIN_CONFIDENCE = 0.5  # default threshold: below it depth is more likely off than within the tolerance
SCORES = {
    "estimate": "the focus method's own estimate: its agreement with its neighbours (`agreement`) or its focus-curve "
                "contrast (m_max - m_min) / (m_max + tau), as notes.estimate_score says, in [0, 1]",
    "fill": "the fill's support: the confidence-weighted share of its edge-aware neighbourhood, in [0, 1]",
    "relative_std": "a DfF model's predicted std_m divided by its depth_m",
}
SECOND = "tolerance_steps: the tolerance in diopters over the local frame spacing in diopters"


class ConfidenceCalibrationError(CaptureError):
    """A confidence-calibration file is missing or malformed (message: one line naming the file)."""


@dataclass(frozen=True)
class Curve:
    """x (K,) ascending score knots; p (K,) the probability at each (monotone in x), or, with a second score,
    y (L,) its ascending knots and p (K, L) (monotone in each); n: validation pixels used."""

    x: np.ndarray
    p: np.ndarray
    n: int = 0
    y: np.ndarray | None = None

    def __post_init__(self):
        x, p = np.asarray(self.x, np.float64), np.asarray(self.p, np.float64)
        y = None if self.y is None else np.asarray(self.y, np.float64)
        shape = (x.size,) if y is None else (x.size, y.size)
        knots = [x] if y is None else [x, y]
        if any(k.ndim != 1 or k.size < 1 or not np.isfinite(k).all() for k in knots) or p.shape != shape \
                or not np.isfinite(p).all():
            raise ConfidenceCalibrationError(f"calibration curve: knots {[k.shape for k in knots]} and probabilities {p.shape} "
                                   "must be finite and match")
        if any(np.any(np.diff(k) < 0) for k in knots) or np.any((p < 0) | (p > 1)):
            raise ConfidenceCalibrationError("calibration curve: knots must ascend and probabilities lie in [0, 1]")
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "p", p)

    def __call__(self, score: np.ndarray, second: np.ndarray | None = None) -> np.ndarray:
        """Probability (score's shape, float32) at each score (and second score, for a 2-D curve): linear
        (bilinear) between the knots, held beyond them."""
        s = np.asarray(score, np.float64)
        if self.y is None:
            return np.interp(s, self.x, self.p).astype(np.float32)
        if second is None:
            raise ValueError("this calibration curve needs a second score")
        (i, ti), (j, tj) = _cell(s, self.x), _cell(np.broadcast_to(np.asarray(second, np.float64), s.shape), self.y)
        p = self.p
        i1, j1 = np.minimum(i + 1, p.shape[0] - 1), np.minimum(j + 1, p.shape[1] - 1)
        out = ((1 - ti) * ((1 - tj) * p[i, j] + tj * p[i, j1]) + ti * ((1 - tj) * p[i1, j] + tj * p[i1, j1]))
        return out.astype(np.float32)


def _cell(v: np.ndarray, knots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the knot interval holding each value and the fraction across it (clamped to the ends)."""
    if knots.size == 1:
        return np.zeros(v.shape, np.int64), np.zeros(v.shape)
    i = np.clip(np.searchsorted(knots, v, side="right") - 1, 0, knots.size - 2)
    width = np.maximum(knots[i + 1] - knots[i], 1e-300)
    return i, np.clip((v - knots[i]) / width, 0.0, 1.0)


def agreement(diopters: np.ndarray, focus_m, window_px: float) -> np.ndarray:
    """How well a pixel's estimate agrees with its neighbours': 1 / (1 + s), s the standard deviation of the
    estimates (diopters) over a box of about window_px (the focus measure's window) in units of the median frame
    spacing in diopters. Noise scatters the estimates of textureless and low-contrast areas; occlusion bands and
    depth edges spread them too. (H, W) float32 in (0, 1]."""
    import cv2

    x = np.sort(1.0 / np.asarray(focus_m, np.float64).ravel())
    gap = float(np.median(np.diff(x))) if x.size > 1 else 1.0
    k = max(3, int(round(window_px)) | 1)
    d = np.asarray(diopters, np.float32)
    m1 = cv2.blur(d, (k, k), borderType=cv2.BORDER_REFLECT)
    m2 = cv2.blur(d * d, (k, k), borderType=cv2.BORDER_REFLECT)
    s = np.sqrt(np.maximum(m2 - m1 * m1, 0.0)) / max(gap, 1e-9)
    return (1.0 / (1.0 + s)).astype(np.float32)


def tolerance_steps(diopters: np.ndarray, focus_m, tolerance_rel: float = TOLERANCE_REL) -> np.ndarray:
    """The tolerance as a share of the frames' focus spacing at each pixel: tolerance_rel x (the estimate in
    diopters) / (the gap in diopters between the two frames whose focus positions surround it). The same error
    in diopters is a small relative error near and a large one far; a coarse schedule errs more: this second
    score lets one calibration serve any schedule. (H, W) float32."""
    x = np.sort(1.0 / np.asarray(focus_m, np.float64).ravel())
    d = np.maximum(np.asarray(diopters, np.float64), 1e-3)
    if x.size < 2:
        return np.full(d.shape, np.inf, np.float32)
    gaps = np.diff(x)
    k = np.clip(np.searchsorted(x, d) - 1, 0, gaps.size - 1)
    return (tolerance_rel * d / np.maximum(gaps[k], 1e-9)).astype(np.float32)


@dataclass(frozen=True)
class Calibration:
    """Curves by score name (SCORES), the tolerance they predict, and how they were made (notes)."""

    curves: dict
    tolerance_rel: float = TOLERANCE_REL
    notes: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> Curve:
        return self.curves[name]

    def probability(self, name: str, score: np.ndarray, diopters: np.ndarray, focus_m) -> np.ndarray:
        """Curve `name` at the score and, for a 2-D curve, at `tolerance_steps` of the depth estimate (diopters)
        among the frames' focus distances (focus_m). (H, W) float32."""
        c = self.curves[name]
        return c(score) if c.y is None else c(score, tolerance_steps(diopters, focus_m, self.tolerance_rel))

    def to_dict(self) -> dict:
        return {"format": FORMAT, "tolerance_rel": self.tolerance_rel,
                "meaning": f"confidence = chance that |depth - truth| <= {self.tolerance_rel:g} x truth, measured "
                           "on held-out rendered validation stacks",
                "curves": {k: {"score": SCORES.get(k, k), "x": np.round(c.x, 6).tolist(),
                               **({} if c.y is None else {"second": SECOND, "y": np.round(c.y, 6).tolist()}),
                               "p": np.round(c.p, 5).tolist(), "pixels": int(c.n)} for k, c in self.curves.items()},
                "notes": self.notes}

    @classmethod
    def from_dict(cls, d: dict, source: str = "confidence calibration") -> Calibration:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ConfidenceCalibrationError(f"{source}: not a confidence calibration (format {FORMAT!r} expected)")
        try:
            curves = {k: Curve(v["x"], v["p"], int(v.get("pixels", 0)), v.get("y")) for k, v in d["curves"].items()}
            tol = float(d["tolerance_rel"])
        except ConfidenceCalibrationError as e:
            raise ConfidenceCalibrationError(f"{source}: {e}") from None
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise ConfidenceCalibrationError(f"{source}: malformed confidence calibration ({type(e).__name__}: {e})") from None
        if not 0 < tol < 10:
            raise ConfidenceCalibrationError(f"{source}: tolerance_rel {tol} out of range")
        return cls(curves, tol, dict(d.get("notes") or {}))

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps(self.to_dict(), indent=1))
        return path


def load(path: str | Path) -> Calibration:
    """A calibration file; ConfidenceCalibrationError (one line naming it) for anything unreadable or malformed."""
    return Calibration.from_dict(load_json(Path(path), ConfidenceCalibrationError), str(path))


FOCUS_CALIBRATION = Path(__file__).resolve().parent / "focus" / "data" / "confidence.json"


@lru_cache(maxsize=1)
def focus_calibration() -> Calibration | None:
    """The focus method's shipped calibration (read once), or None if the file is absent (confidences stay raw)."""
    return load(FOCUS_CALIBRATION) if FOCUS_CALIBRATION.is_file() else None


def model_calibration_path(model_path: str | Path) -> Path:
    p = Path(model_path)
    return p.with_name(f"{p.stem}.confidence.json")


def model_calibration(model_path: str | Path) -> Calibration | None:
    """`<model stem>.confidence.json` next to the model, or None."""
    p = model_calibration_path(model_path)
    return load(p) if p.is_file() else None


def std_confidence(cal: Calibration, depth_m: np.ndarray, std_m: np.ndarray) -> np.ndarray:
    """(H, W) float32 confidence of a model's depth from its std (curve `relative_std`)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(np.asarray(depth_m) > 0, np.asarray(std_m, np.float64) / np.asarray(depth_m, np.float64),
                       np.inf)
    c = cal["relative_std"](rel)
    return np.where(np.isfinite(rel), c, 0.0).astype(np.float32)


# --- fitting (the calibration script; the rule tested on hand-made cases) ---------------------------------------
def pool_adjacent_violators(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least-squares non-decreasing fit of y (K,) with weights w (K,) > 0: (K,) fitted values."""
    vals, wts, sizes = [], [], []
    for yi, wi in zip(np.asarray(y, np.float64), np.asarray(w, np.float64)):
        vals.append(yi)
        wts.append(wi)
        sizes.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            wsum = wts[-2] + wts[-1]
            v = (vals[-2] * wts[-2] + vals[-1] * wts[-1]) / wsum
            vals[-2:], wts[-2:], sizes[-2:] = [v], [wsum], [sizes[-2] + sizes[-1]]
    return np.repeat(vals, sizes)


def fit_curve(score: np.ndarray, correct: np.ndarray, increasing: bool = True, n_bins: int = 64,
              min_pixels: int = 200, second: np.ndarray | None = None, n_bins2: int = 10) -> Curve:
    """Isotonic fit of P(correct | score): scores binned at quantiles (n_bins, each >= min_pixels pixels), each
    bin's share of correct pixels, made monotone (non-decreasing in the score if `increasing`, else
    non-increasing) by pool-adjacent-violators weighted by the bins' pixel counts; knots at the bins' mean scores.
    With `second` (a second score, non-decreasing too): P(correct | score, second) on a grid of quantile bins of
    each (`fit_grid`)."""
    s = np.asarray(score, np.float64).ravel()
    c = np.asarray(correct, np.float64).ravel()
    ok = np.isfinite(s) if second is None else np.isfinite(s) & np.isfinite(np.asarray(second, np.float64).ravel())
    if second is not None:
        return fit_grid(s[ok], np.asarray(second, np.float64).ravel()[ok], c[ok], n_bins, n_bins2, min_pixels)
    s, c = s[ok], c[ok]
    if s.size == 0:
        raise ValueError("no pixels to fit a calibration on")
    n_bins = int(max(1, min(n_bins, s.size // max(min_pixels, 1))))
    order = np.argsort(s, kind="stable")
    s, c = s[order], c[order]
    edges = np.linspace(0, s.size, n_bins + 1).astype(int)
    xs = np.array([s[a:b].mean() for a, b in zip(edges[:-1], edges[1:])])
    ps = np.array([c[a:b].mean() for a, b in zip(edges[:-1], edges[1:])])
    ws = np.diff(edges).astype(np.float64)
    fitted = pool_adjacent_violators(ps if increasing else -ps, ws)
    fitted = fitted if increasing else -fitted
    return Curve(xs, np.clip(fitted, 0, 1), int(s.size))


def fit_grid(s: np.ndarray, t: np.ndarray, c: np.ndarray, n_s: int, n_t: int, min_pixels: int,
             sweeps: int = 4) -> Curve:
    """P(c | s, t) non-decreasing in both, on quantile bins of s (n_s) and t (n_t): each cell's share, then
    pool-adjacent-violators along s in every t row and along t in every s column, alternately (`sweeps` times;
    empty cells take the interpolation of their row). Knots at the marginal bins' mean values."""
    if s.size == 0:
        raise ValueError("no pixels to fit a calibration on")
    n_s = int(max(1, min(n_s, s.size // max(min_pixels * n_t, 1))))
    es = np.unique(np.quantile(s, np.linspace(0, 1, n_s + 1)))
    et = np.unique(np.quantile(t, np.linspace(0, 1, n_t + 1)))
    i = np.clip(np.searchsorted(es, s, side="right") - 1, 0, max(es.size - 2, 0))
    j = np.clip(np.searchsorted(et, t, side="right") - 1, 0, max(et.size - 2, 0))
    ks, kt = max(es.size - 1, 1), max(et.size - 1, 1)
    cnt = np.zeros((ks, kt))
    hit = np.zeros((ks, kt))
    np.add.at(cnt, (i, j), 1.0)
    np.add.at(hit, (i, j), c)
    xs = np.array([s[i == a].mean() if np.any(i == a) else es[a] for a in range(ks)])
    ys = np.array([t[j == b].mean() if np.any(j == b) else et[b] for b in range(kt)])
    p = np.where(cnt > 0, hit / np.maximum(cnt, 1), np.nan)
    w = np.maximum(cnt, 1e-6)
    for b in range(kt):  # empty cells: interpolated along s from their row's filled ones (or the whole mean)
        m = cnt[:, b] > 0
        p[:, b] = np.interp(xs, xs[m], p[m, b]) if m.any() else c.mean()
    for _ in range(sweeps):
        for b in range(kt):
            p[:, b] = pool_adjacent_violators(p[:, b], w[:, b])
        for a in range(ks):
            p[a] = pool_adjacent_violators(p[a], w[a])
    return Curve(xs, np.clip(p, 0, 1), int(s.size), ys)


def reliability(conf: np.ndarray, correct: np.ndarray, n_bins: int = 10) -> dict:
    """Reliability table: per confidence bin (even in [0, 1]) the mean confidence, the observed share correct and
    the pixel count; ECE = count-weighted mean |observed - confidence|."""
    cf = np.asarray(conf, np.float64).ravel()
    ok = np.isfinite(cf)
    cf, cr = cf[ok], np.asarray(correct, np.float64).ravel()[ok]
    idx = np.minimum((cf * n_bins).astype(int), n_bins - 1)
    rows = []
    for b in range(n_bins):
        m = idx == b
        if m.any():
            rows.append({"bin": [b / n_bins, (b + 1) / n_bins], "confidence": float(cf[m].mean()),
                         "observed": float(cr[m].mean()), "pixels": int(m.sum())})
    n = sum(r["pixels"] for r in rows)
    ece = sum(r["pixels"] * abs(r["observed"] - r["confidence"]) for r in rows) / max(n, 1)
    return {"bins": rows, "ece": float(ece), "pixels": int(n)}


# --- unknown depth ------------------------------------------------------------------------------------------------
def mark_unknown(depth_m: np.ndarray, confidence: np.ndarray | None, min_confidence: float) -> tuple[np.ndarray, dict]:
    """depth_m with NaN where confidence < min_confidence; and the shares for summary.json. Without a confidence
    nothing is marked (the share says so: null)."""
    depth = np.asarray(depth_m, np.float32)
    known0 = np.isfinite(depth) & (depth > 0)
    if confidence is None:
        return depth, {"min_confidence": None, "unknown_share": float(1 - known0.mean()) if depth.size else 0.0,
                       "note": "no confidence: only pixels the method left without depth are unknown"}
    conf = np.asarray(confidence, np.float32)
    low = ~(conf >= min_confidence)  # NaN confidence counts as unknown
    out = np.where(low, np.float32(np.nan), depth).astype(np.float32)
    known = np.isfinite(out) & (out > 0)
    return out, {"min_confidence": float(min_confidence), "unknown_share": float(1 - known.mean()),
                 "below_threshold_share": float((low & known0).mean())}
