"""Frames whose reported focus distances are equal, placed from the images themselves.

Real metadata can be coarse: a Canon macro stack converted through Lightroom reports XMP focus distances 0.37 /
0.35 / 0.35 / 0.34 m, two frames alike, though the lens moved between them. Refusing the stack loses the capture;
here each such frame gets the focus position its images imply.

Model: near its peak a pixel's focus curve is a Gaussian in diopters, log m_s = log A - (x_s - D)^2 / (2 w^2).
From the frames with distinct reported focus (the "known" frames) each confident pixel's peak D, width w and height
A are fitted (a parabola through log m at the sharpest known frame and its two neighbours). A tied frame t at the
unknown position x then predicts log m_t = log A - (x - D)^2 / (2 w^2) at every such pixel; x is the position in
the interval between the neighbouring known levels (widened by half a step) that best explains all of them (least
squares over a grid of candidates, then refined). Pixels whose peaks lie at different depths break the
sign ambiguity of a single pixel. With fewer than 3 known levels, or too few usable pixels, the tied frames are
spread evenly over their interval and the result says so.
"""

from __future__ import annotations

import numpy as np

MAX_PIXELS = 40000  # pixels sampled for the fit (a regular subsample: enough, and fast)
N_CANDIDATES = 81


def tied_groups(focus_m: np.ndarray, rel_tol: float = 1e-6) -> list[list[int]]:
    """Indices of frames that share a reported focus distance (groups of >= 2), in input order."""
    f = np.asarray(focus_m, np.float64)
    groups: dict[float, list[int]] = {}
    for i, v in enumerate(f):
        key = next((k for k in groups if abs(k - v) <= rel_tol * max(abs(k), 1e-12)), v)
        groups.setdefault(key, []).append(i)
    return [g for g in groups.values() if len(g) > 1]


def _known_fit(volume: np.ndarray, x: np.ndarray, known: np.ndarray):
    """Per sampled pixel: Gaussian peak D, log height L and 1/(2 w^2) from the known frames; and a usable mask."""
    v = np.log(volume[known] + 1e-30)  # (K, N)
    xk = x[known]
    order = np.argsort(xk)
    v, xk = v[order], xk[order]
    k = np.argmax(v, 0)
    inner = (k > 0) & (k < len(xk) - 1)
    kk = np.clip(k, 1, len(xk) - 2)
    n = np.arange(v.shape[1])
    x0, x1, x2 = xk[kk - 1], xk[kk], xk[kk + 1]
    y0, y1, y2 = v[kk - 1, n], v[kk, n], v[kk + 1, n]
    # parabola y = c0 + c1 x + c2 x^2 through three points (any spacing)
    d01, d12, d02 = (y1 - y0) / (x1 - x0), (y2 - y1) / (x2 - x1), x2 - x0
    c2 = (d12 - d01) / d02
    c1 = d01 - c2 * (x0 + x1)
    c0 = y0 - c1 * x0 - c2 * x0 * x0
    ok = inner & (c2 < 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        peak = -c1 / (2 * c2)
        top = c0 + c1 * peak + c2 * peak * peak
    ok &= np.isfinite(peak) & np.isfinite(top)
    return peak, top, -c2, ok


def place_equal_focus(volume: np.ndarray, focus_m: np.ndarray, confidence: np.ndarray | None = None
                      ) -> tuple[np.ndarray, list[dict]]:
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
    conf = None if confidence is None else confidence.reshape(-1)[idx]
    notes: list[dict] = []
    fit = _known_fit(sub, x, known) if len(known) >= 3 else None
    for g in groups:
        x0 = x[g[0]]
        lower = levels[levels < x0 - 1e-9]
        upper = levels[levels > x0 + 1e-9]
        lo = lower.max() if lower.size else x0 - (upper.min() - x0 if upper.size else 0.1)
        hi = upper.min() if upper.size else x0 + (x0 - lo)
        span = hi - lo
        lo, hi = lo - 0.25 * span, hi + 0.25 * span
        evenly = np.linspace(x0 - 0.25 * span, x0 + 0.25 * span, len(g) + 2)[1:-1]
        for j, t in enumerate(g):
            placed, how, used = None, "images", 0
            if fit is not None:
                peak, top, curv, ok = fit
                near = ok & (peak > lo - span) & (peak < hi + span)
                if conf is not None:
                    near &= conf > 0.2
                used = int(near.sum())
                if used >= 50:
                    y = np.log(sub[t, near] + 1e-30)
                    cand = np.linspace(lo, hi, N_CANDIDATES)
                    pred = top[near][None] - curv[near][None] * (cand[:, None] - peak[near][None]) ** 2
                    cost = np.median(np.abs(pred - y[None]), 1)  # robust to pixels the Gaussian model misses
                    i = int(np.argmin(cost))
                    fine = np.linspace(cand[max(i - 1, 0)], cand[min(i + 1, N_CANDIDATES - 1)], 41)
                    pred = top[near][None] - curv[near][None] * (fine[:, None] - peak[near][None]) ** 2
                    placed = float(fine[int(np.argmin(np.median(np.abs(pred - y[None]), 1)))])
            if placed is None or placed <= 0:
                placed, how = float(evenly[j]), "spread evenly (too few textured pixels or known frames)"
            notes.append({"frame": int(t), "reported_m": float(f[t]), "placed_m": float(1.0 / placed),
                          "method": how, "pixels": used})
    for n in notes:
        f[n["frame"]] = n["placed_m"]
    return f, notes
