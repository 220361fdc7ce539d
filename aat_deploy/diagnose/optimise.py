"""Small derivative-free minimisers for the diagnosis's fits (numpy only)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

GOLDEN = (math.sqrt(5) - 1) / 2


def golden(f: Callable[[float], float], lo: float, hi: float, tol: float = 1e-3, max_iter: int = 60) -> tuple[float, float]:
    """Minimum of a unimodal f on [lo, hi] by golden-section search: (x, f(x)), x within tol of the minimiser."""
    a, b = float(lo), float(hi)
    c, d = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(max_iter):
        if b - a <= tol:
            break
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - GOLDEN * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + GOLDEN * (b - a)
            fd = f(d)
    return (c, fc) if fc <= fd else (d, fd)


def grid_then_golden(f: Callable[[float], float], lo: float, hi: float, n: int = 9, tol: float = 1e-3) -> tuple[float, float]:
    """Global minimum of a possibly multimodal 1-D f on [lo, hi]: the best of n grid points, then golden-section
    search between its neighbours."""
    xs = np.linspace(lo, hi, n)
    vs = np.array([f(float(x)) for x in xs])
    i = int(np.argmin(vs))
    a, b = xs[max(i - 1, 0)], xs[min(i + 1, n - 1)]
    x, v = golden(f, a, b, tol)
    return (x, v) if v <= vs[i] else (float(xs[i]), float(vs[i]))


def nelder_mead(f: Callable[[np.ndarray], float], x0, step, tol: float = 1e-4, max_iter: int = 400,
                lower=None, upper=None) -> tuple[np.ndarray, float]:
    """Minimum of f near x0 by the Nelder-Mead simplex (initial edges `step`), parameters clipped to
    [lower, upper]. Stops when the simplex's values and size both fall under tol. Returns (x, f(x))."""
    x0 = np.asarray(x0, np.float64)
    n = len(x0)
    lo = np.full(n, -np.inf) if lower is None else np.asarray(lower, np.float64)
    hi = np.full(n, np.inf) if upper is None else np.asarray(upper, np.float64)

    def g(x):
        return f(np.clip(x, lo, hi))

    pts = [x0] + [x0 + np.eye(n)[i] * np.asarray(step, np.float64).reshape(-1)[i % np.size(step)] for i in range(n)]
    vals = [g(p) for p in pts]
    for _ in range(max_iter):
        order = np.argsort(vals)
        pts, vals = [pts[i] for i in order], [vals[i] for i in order]
        size = max(np.max(np.abs(p - pts[0])) for p in pts[1:])
        if abs(vals[-1] - vals[0]) <= tol * (abs(vals[0]) + tol) and size <= tol:
            break
        centre = np.mean(pts[:-1], 0)
        xr = centre + (centre - pts[-1])
        fr = g(xr)
        if fr < vals[0]:
            xe = centre + 2 * (centre - pts[-1])
            fe = g(xe)
            pts[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < vals[-2]:
            pts[-1], vals[-1] = xr, fr
        else:
            xc = centre + 0.5 * (pts[-1] - centre)
            fc = g(xc)
            if fc < vals[-1]:
                pts[-1], vals[-1] = xc, fc
            else:  # shrink towards the best point
                pts = [pts[0]] + [pts[0] + 0.5 * (p - pts[0]) for p in pts[1:]]
                vals = [vals[0]] + [g(p) for p in pts[1:]]
    i = int(np.argmin(vals))
    return np.clip(pts[i], lo, hi), float(vals[i])


def isotonic(y: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Weighted least-squares non-decreasing fit to y (pool adjacent violators)."""
    y = np.asarray(y, np.float64)
    w = np.ones_like(y) if w is None else np.asarray(w, np.float64)
    vals, wts, sizes = [], [], []
    for v, ww in zip(y, w):
        vals.append(v)
        wts.append(ww)
        sizes.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            v2, w2, s2 = vals.pop(), wts.pop(), sizes.pop()
            wt = wts[-1] + w2
            vals[-1] = (vals[-1] * wts[-1] + v2 * w2) / wt
            wts[-1], sizes[-1] = wt, sizes[-1] + s2
    return np.repeat(vals, sizes)
