"""Frames whose reported focus distances are equal, placed from the images themselves.

Real metadata can be coarse: a Canon macro stack converted through Lightroom reports XMP focus distances 0.37 /
0.35 / 0.35 / 0.34 m, two frames alike, though the lens moved between them. Refusing the stack loses the capture;
here each such frame gets the focus position its images imply.

Method: from the frames with distinct reported focus (the "known" frames) each pixel's in-focus position D_p is
estimated (`estimate.estimate_peak`, two-point ratio); a tied frame t is sharpest, relative to the best known frame,
at the pixels whose D_p equals its own focus position. So x_t is where the score "log m_t - log max_known m",
averaged over textured pixels with D_p near x (a Gaussian kernel in diopters), peaks, searched between the
neighbouring known levels (widened by a quarter of the interval) and refined by a parabola. It needs no model of
the focus curve's shape, only that it is symmetric. With fewer than 3 known frames, or too few textured pixels near
the interval, the tied frames are spread evenly over it and the result says so.
"""

from __future__ import annotations

import numpy as np

MAX_PIXELS = 40000  # pixels sampled for the fit (a regular subsample: enough, and fast)
N_CANDIDATES = 81  # positions searched over the interval


def tied_groups(focus_m: np.ndarray, rel_tol: float = 1e-6) -> list[list[int]]:
    """Indices of frames that share a reported focus distance (groups of >= 2), in input order."""
    f = np.asarray(focus_m, np.float64)
    groups: dict[float, list[int]] = {}
    for i, v in enumerate(f):
        key = next((k for k in groups if abs(k - v) <= rel_tol * max(abs(k), 1e-12)), v)
        groups.setdefault(key, []).append(i)
    return [g for g in groups.values() if len(g) > 1]


def place_equal_focus(volume: np.ndarray, focus_m: np.ndarray) -> tuple[np.ndarray, list[dict]]:
    """volume (S, H, W) focus measure, focus_m (S,) reported (metres, any order) -> (placed focus_m (S,), notes).

    Frames with a distinct reported focus keep it. Each note: {"frame", "reported_m", "placed_m", "method",
    "pixels"} for a tied frame."""
    f = np.asarray(focus_m, np.float64).copy()
    groups = tied_groups(f)
    if not groups:
        return f, []
    s = volume.shape[0]
    x = 1.0 / f  # diopters
    tied = np.zeros(s, bool)
    for g in groups:
        tied[g] = True
    known = np.flatnonzero(~tied)
    levels = np.unique(np.round(x, 9))
    flat = volume.reshape(s, -1)
    step = max(1, int(np.ceil(np.sqrt(flat.shape[1] / MAX_PIXELS))))
    h, w = volume.shape[1:]
    idx = (np.arange(0, h, step)[:, None] * w + np.arange(0, w, step)[None, :]).ravel()
    sub = flat[:, idx].astype(np.float64)
    notes: list[dict] = []
    est = None
    if len(known) >= 3:
        from .estimate import estimate_peak

        kv = sub[known][:, None, :].astype(np.float32)
        pk = estimate_peak(kv, x[known].astype(np.float32), estimator="ratio", gamma=1.0)
        est = (pk.diopters[0].astype(np.float64), pk.confidence[0], np.log(kv[:, 0].max(0) + 1e-30))
    for g in groups:
        x0 = x[g[0]]
        lower = levels[levels < x0 - 1e-9]
        upper = levels[levels > x0 + 1e-9]
        lo = lower.max() if lower.size else x0 - (upper.min() - x0 if upper.size else 0.1)
        hi = upper.min() if upper.size else x0 + (x0 - lo)
        span = hi - lo
        evenly = np.linspace(lo, hi, len(g) + 2)[1:-1][::-1]  # near (high diopters) first, as frames sort
        lo, hi = lo - 0.25 * span, hi + 0.25 * span
        cand = np.linspace(lo, hi, N_CANDIDATES)
        bw = max(span / 8, 1e-3)
        for j, t in enumerate(g):
            placed, how, used = None, "images", 0
            if est is not None:
                dp, cp, lref = est
                near = (cp > 0.3) & (dp > lo - 2 * bw) & (dp < hi + 2 * bw)
                used = int(near.sum())
                if used >= 50:
                    score = np.log(sub[t, near] + 1e-30) - lref[near]
                    wk = np.exp(-0.5 * ((cand[:, None] - dp[near][None]) / bw) ** 2)
                    mass = wk.sum(1)
                    curve = np.where(mass > 1.0, (wk * score[None]).sum(1) / np.maximum(mass, 1e-12), -np.inf)
                    i = int(np.argmax(curve))
                    if np.isfinite(curve[i]):
                        placed = float(cand[i])
                        if 0 < i < N_CANDIDATES - 1 and np.isfinite(curve[i - 1]) and np.isfinite(curve[i + 1]):
                            y0, y1, y2 = curve[i - 1:i + 2]
                            den = y0 - 2 * y1 + y2
                            if den < 0:
                                placed += 0.5 * (y0 - y2) / den * (cand[1] - cand[0])
            if placed is None or placed <= 0:
                placed, how = float(evenly[j]), "spread evenly (too few textured pixels or known frames)"
            notes.append({"frame": int(t), "reported_m": float(f[t]), "placed_m": float(1.0 / placed),
                          "method": how, "pixels": used})
    for n in notes:
        f[n["frame"]] = n["placed_m"]
    return f, notes
