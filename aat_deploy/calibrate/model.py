"""The smooth model fitted to tile observations: "a frame reporting focus r diopters has the object at D diopters in
focus at field (x, y)" -> the reported-focus error (`FocusError`, a family) and the field term (`FieldPoly`), with
the model order chosen by cross-validation, the family by BIC, and bootstrap intervals (numpy, its BLAS at one
thread: `machine.one_blas_thread`).

    D_i = g(r_i) + sum_k sum_j c[k, j] phi_k(x_i, y_i) P_j(tau(g(r_i)))

g is the family: none (g = r), offset (g = r - b), scale (g = s r), monotone (a parabola in r, stored as 9 knots of
`map_d`, the diagnosis's form; only with three or more sweeps: `families_for`). phi_k are the monomials of degree
1..n in (x, y) (no constant: the frame centre is g's) and, beyond them, even powers rho^2m of the field radius up
to `radial` (rho = 1 at the frame's corner: `FieldBasis`): a lens's field curvature is round about its axis and
may be steep at the edge (a phone lens's best focus moves 2.6 D between field radius 0.5 and 0.7 and 7 D to the
corner), which low-degree monomials cannot follow; what they cannot follow, the family's constant takes, and the
whole frame's focus error is then wrong. The radial powers are stored expanded into monomials (`FieldPoly`).
P_j Legendre polynomials of the on-axis focus over the measured range. For a given g the model is linear in
(family parameters, c); g enters tau, so the fit alternates (tau from the last g) until it settles.

Family choice: BIC with the observations grouped into cells of one sweep and one frame interval (tiles that peak
between the same two frames share that frame's focus error, so counting them as independent would let every
extra parameter look significant; the diagnosis counts frames the same way). Model order: spatial-block
cross-validation over the tiles. Intervals: a Poisson bootstrap of tiles (and of sweeps when there are three or
more) that refits and reselects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..machine import one_blas_thread
from .format import FieldPoly, FocusError, poly_terms

FAMILY_PARAMS = {"none": 0, "offset": 1, "scale": 1, "monotone": 3}
DEGREES = (2, 3, 4, 5, 6)
RADIAL = (0, 8, 12)  # the radial powers' highest degree (0: none); 12 is the format's MAX_DEGREE
MONOTONE_KNOTS = 9
MAX_FOCUS_DEGREE = 2  # the field term's highest Legendre degree in focus (as the sweeps allow: `fit_model`)
LOW_FOCUS_DEGREES: tuple = (None,)  # the non-edge functions' degrees in focus the CV tries (None: focus_degree's)
EDGE_POWER = 8  # radial powers from rho^8 on are the edge's (`FieldBasis.edge_powers`)
EDGE_FOCUS_DEGREE = 3  # the edge powers' degree in focus where cross-validation over frames wants it (`choose_edge_focus`)
# The chosen orders are blended, not picked (`order_weights`, `edge_weight`, `fit_blend`): a hard choice at a CV
# margin flipped with small changes of the tiles (the benchmark's phone copies rendered on another machine: their
# maps moved by 0.01-0.03 D), and where two orders are about as good the blend is no worse than either.
ORDER_BAND = 0.02  # an order's weight falls linearly from 1 at the best spatial CV RMS to 0 at ORDER_BAND worse
EDGE_BAND = 0.02  # the edge cubic's weight rises linearly from 0 (cell CV no better) to 1 (2 x EDGE_BAND better)


@dataclass(frozen=True)
class FieldBasis:
    """The field term's functions: the monomials x^a y^b of total degree 1..degree, then the even powers
    rho^2m of the field radius for degree < 2m <= radial (none when radial <= degree), rho^2 = (x^2 w^2 +
    y^2 h^2) / (w^2 + h^2) with aspect = w / h of the frames (square pixels: rho = 1 at the corners, the
    best-focus maps' radius)."""

    degree: int
    radial: int = 0
    aspect: float = 1.0

    def powers(self) -> list[int]:
        """The radial powers 2m used."""
        return [p for p in range(2, self.radial + 1, 2) if p > self.degree]

    def expansion(self) -> tuple[np.ndarray, np.ndarray]:
        """(terms (M, 2), E (K, M)): function k = sum_m E[k, m] x^terms[m][0] y^terms[m][1]."""
        mono = [tuple(t) for t in poly_terms(self.degree, constant=False)]
        a2 = self.aspect ** 2 / (1.0 + self.aspect ** 2)  # rho^2 = a2 x^2 + (1 - a2) y^2
        rows = [{t: 1.0} for t in mono]
        for p in self.powers():
            m = p // 2
            rows.append({(2 * i, 2 * (m - i)): math.comb(m, i) * a2 ** i * (1 - a2) ** (m - i)
                         for i in range(m, -1, -1)})
        terms = list(dict.fromkeys(mono + [t for r in rows[len(mono):] for t in r]))
        e = np.zeros((len(rows), len(terms)))
        for k, r in enumerate(rows):
            for t, v in r.items():
                e[k, terms.index(t)] = v
        return np.array(terms, np.int64).reshape(-1, 2), e

    def columns(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(N, K) the functions at field points x, y (N,)."""
        terms, e = self.expansion()
        return np.stack([x ** a * y ** b for a, b in terms], 1) @ e.T

    def field_poly(self, c: np.ndarray, focus_range_d: tuple[float, float]) -> FieldPoly:
        """The stored form of coefficients c (K, J) of these functions: monomial coefficients E^T c."""
        terms, e = self.expansion()
        return FieldPoly(terms, e.T @ c, focus_range_d)

    @property
    def size(self) -> int:
        return len(poly_terms(self.degree, constant=False)) + len(self.powers())

    @property
    def n_mono(self) -> int:
        """How many of the functions are monomials (the first ones; the radial powers follow)."""
        return len(poly_terms(self.degree, constant=False))

    def edge_powers(self) -> list[int]:
        """The radial powers rho^2m with 2m >= EDGE_POWER: those that live at the field's edge (rho^8 is 0.03 at
        radius 0.65), where a phone lens's best focus moves with focus in more than a parabola (`focus_mask`)."""
        return [p for p in self.powers() if p >= EDGE_POWER]

    def focus_mask(self, focus_degree: int, low_focus_degree: int | None = None) -> np.ndarray:
        """(K, J) which (function, Legendre degree in focus) pairs are fitted: every function to focus_degree, or,
        with low_focus_degree, only the edge powers (`edge_powers`) to focus_degree and the others (monomials:
        tilt, decentre; the low radial powers: the field's curvature) to low_focus_degree."""
        j = np.arange(focus_degree + 1)[None, :]
        low = focus_degree if low_focus_degree is None else min(low_focus_degree, focus_degree)
        degs = [low] * self.n_mono + [focus_degree if p >= EDGE_POWER else low for p in self.powers()]
        return j <= np.array(degs)[:, None]

    def params(self, focus_degree: int, low_focus_degree: int | None = None) -> int:
        return int(self.focus_mask(focus_degree, low_focus_degree).sum())


@dataclass
class Observations:
    """N tile observations: x, y normalised field; reported_d the reported focus (diopters) at the tile's focus
    peak; object_d the tile's object (diopters from the sensor plane); sweep (N,) int; weight (N,) >= 0;
    cell (N,) int: the sweep-and-frame-interval group (for BIC); aspect: the frames' width / height (the field
    radius's shape, `FieldBasis`)."""

    x: np.ndarray
    y: np.ndarray
    reported_d: np.ndarray
    object_d: np.ndarray
    sweep: np.ndarray
    cell: np.ndarray
    weight: np.ndarray | None = None
    aspect: float = 1.0
    dz: np.ndarray | None = None  # (N,) D of object per mm of the sweep's chart distance, where it is fitted; else 0

    def __post_init__(self):
        if self.weight is None:
            self.weight = np.ones_like(self.x)

    def __len__(self) -> int:
        return len(self.x)

    def subset(self, keep: np.ndarray) -> Observations:
        return Observations(*(getattr(self, k)[keep] for k in ("x", "y", "reported_d", "object_d", "sweep", "cell",
                                                                  "weight")), aspect=self.aspect,
                            dz=None if self.dz is None else self.dz[keep])

    def free_sweeps(self) -> np.ndarray:
        """The sweeps whose chart distance is fitted (an unknown of the model: `distance_columns`)."""
        if self.dz is None:
            return np.zeros(0, np.int64)
        return np.unique(self.sweep[self.dz != 0])


def distance_columns(obs: Observations) -> np.ndarray:
    """(N, F) one column per sweep whose chart distance is fitted (`Observations.dz`): a shift of that chart's
    distance by delta mm moves its tiles' objects by dz * delta diopters (linearised). Model: object_d + dz delta =
    g(r) + field: the joint least squares' shift, which `fit.fit_calibration` uses only where the measured charts'
    residuals have no minimum (`profile_shifts`, its criterion since 2026-11-28)."""
    free = obs.free_sweeps()
    if not len(free):
        return np.zeros((len(obs), 0))
    return np.stack([-np.where(obs.sweep == s, obs.dz, 0.0) for s in free], 1)


@dataclass(frozen=True)
class Component:
    """One order of a blended model (`fit_blend`): the field basis's degree and radial powers, the degree in focus
    (and the non-edge functions', `FieldBasis.focus_mask`), and its weight."""

    degree: int
    radial: int
    focus_degree: int
    low_focus_degree: int | None
    weight: float


@dataclass
class ModelFit:
    """focus: the chosen family's error; field: the field term; residual_d (N,) object minus model; fits: every
    family's (FocusError, FieldPoly, BIC); degree, radial, focus_degree: the model order (`FieldBasis`, Legendre
    degree in focus); cv: the order's CV table."""

    focus: FocusError
    field: FieldPoly
    residual_d: np.ndarray
    fits: dict = field(default_factory=dict)
    degree: int = 0
    focus_degree: int = 0
    cv: list = field(default_factory=list)
    radial: int = 0
    shifts_mm: dict = field(default_factory=dict)  # {sweep: its chart distance's fitted shift (mm)}
    low_focus_degree: int | None = None  # the non-edge functions' degree in focus (`FieldBasis.focus_mask`)
    edge_cv: dict | None = None  # `choose_edge_focus`'s table, where it was asked
    # the orders blended (`fit_blend`; the order fields above are the rule's order, where the family is chosen, not
    # necessarily the heaviest component's), () where the order was given
    blend: tuple = ()

    def predict(self, x, y, reported_d) -> np.ndarray:
        """In-focus object diopters at field (x, y) for reported focus diopters (all broadcast together)."""
        x, y, r = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (x, y, reported_d)))
        t = self.focus.true_diopters(r.ravel())
        out = t + (self.field.focus_weights(t) * self.field.basis(x.ravel(), y.ravel()).T).sum(1)
        return out.reshape(x.shape)


def _family_columns(name: str, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(columns (N, p), target offset o (N,)): D - o = columns . params + field."""
    if name == "none":
        return np.zeros((len(r), 0)), r
    if name == "offset":
        return -np.ones((len(r), 1)), r
    if name == "scale":
        return r[:, None], np.zeros_like(r)
    return np.column_stack([np.ones_like(r), r, r * r]), np.zeros_like(r)


def _focus_error(name: str, p: np.ndarray, r_range: tuple[float, float]) -> FocusError | None:
    """The family's FocusError from its least-squares parameters (None: a monotone fit that turns back)."""
    if name == "none":
        return FocusError("none")
    if name == "offset":
        return FocusError("offset", bias_d=float(p[0]))
    if name == "scale":
        return FocusError("scale", scale=float(p[0])) if p[0] > 0 else None
    xs = np.linspace(r_range[0], r_range[1], MONOTONE_KNOTS)
    ys = p[0] + p[1] * xs + p[2] * xs * xs
    if np.any(np.diff(xs) <= 0) or np.any(np.diff(ys) <= 0):
        return None
    return FocusError("monotone", map_d=tuple(float(v) for pair in zip(xs, ys) for v in pair))


@one_blas_thread()  # many small solves: threads that meet after each step wait for any other process (machine.py)
def fit_family(obs: Observations, name: str, degree: int, focus_degree: int, iterations: int = 6,
               weight: np.ndarray | None = None, radial: int = 0, columns: np.ndarray | None = None,
               shifts: dict | None = None, low_focus_degree: int | None = None
               ) -> tuple[FocusError, FieldPoly, np.ndarray] | None:
    """One family at one model order: (FocusError, FieldPoly, residuals (N,)) or None if it cannot be fitted.
    columns: `FieldBasis(degree, radial, obs.aspect).columns(obs.x, obs.y)` when the caller has them (the same for
    every family, fold and replicate). Sweeps whose chart distance is fitted (`Observations.dz`) get one unknown
    each (`distance_columns`); shifts, when given, receives {sweep: fitted shift of its distance, mm}; the residuals
    are against the shifted objects. low_focus_degree: the degree in focus of every function but the edge powers
    (`FieldBasis.focus_mask`; None: focus_degree for all)."""
    w = obs.weight if weight is None else weight
    r, d = obs.reported_d, obs.object_d
    fb = FieldBasis(degree, radial, obs.aspect)
    basis = fb.columns(obs.x, obs.y) if columns is None else columns  # (N, K)
    nk = basis.shape[1]
    mask = fb.focus_mask(focus_degree, low_focus_degree).ravel()  # (K * J,) the fitted (function, focus) pairs
    fam, off = _family_columns(name, r)
    dist = distance_columns(obs)
    fam = np.column_stack([fam, dist])
    n_fam = fam.shape[1] - dist.shape[1]
    r_range = (float(r.min()), float(r.max()))
    t = r.copy()
    sw = np.sqrt(np.maximum(w, 0))
    fe = fp = None
    for _ in range(iterations):
        lo, hi = float(t.min()), float(t.max())
        tau = FieldPoly(np.array([[1, 0]]), np.zeros((1, 1)), (lo, hi)).tau(t)  # the stored form's tau
        leg = np.polynomial.legendre.legvander(tau, focus_degree)  # (N, J)
        field_cols = (basis[:, :, None] * leg[:, None, :]).reshape(len(r), -1)[:, mask]
        a = np.column_stack([fam, field_cols])
        sol, *_ = np.linalg.lstsq(a * sw[:, None], (d - off) * sw, rcond=None)
        if not np.all(np.isfinite(sol)):
            return None
        c = np.zeros(nk * (focus_degree + 1))
        c[mask] = sol[fam.shape[1]:]
        p, c = sol[:n_fam], c.reshape(nk, focus_degree + 1)
        delta = sol[n_fam:fam.shape[1]]
        fe = _focus_error(name, p, r_range)
        if fe is None:
            return None
        t_new = fe.true_diopters(r)
        try:
            fp = fb.field_poly(c, (lo, hi))
        except ValueError:  # coefficients beyond what the file stores (near-collinear high powers): no fit
            return None
        fit_c = c
        if np.max(np.abs(t_new - t)) < 1e-7:
            t = t_new
            break
        t = t_new
    tt = fe.true_diopters(r)
    pred = tt + (np.polynomial.legendre.legvander(fp.tau(tt), focus_degree) @ fit_c.T * basis).sum(1)
    if shifts is not None:
        shifts.clear()
        shifts.update({int(k): float(v) for k, v in zip(obs.free_sweeps(), delta)})
    return fe, fp, d - dist @ delta - pred


def bic(obs: Observations, residual: np.ndarray, k: int, weight: np.ndarray | None = None) -> float:
    """BIC of tiles grouped in cells, each cell with its own error (its frame's focus error) besides each tile's:
    n_c log(RSS_between / n_c) + n_w log(RSS_within / n_w) + k log n_c, RSS_between over the cells' weighted mean
    residuals (n_c cells), RSS_within over the tiles' residuals about their cell's mean (n_w = tiles - cells).

    The between part alone (the criterion before) treats a cell's tiles as one observation, which a frame's own
    focus error makes them; but it also discards what the tiles of one cell show across the field, and that is
    where a small reported-focus offset differs from the field term (a phone lens's 0.18 D: the field term's
    radial powers take a near-constant over most of the field and leave a pattern across it, which averages away
    within a cell; BENCHMARKS.md). A family that changes only how the cells' means follow the reported focus
    (scale, curve) changes the between part; a frame's own error cannot enter the within part."""
    w = obs.weight if weight is None else weight
    cells, inv = np.unique(obs.cell, return_inverse=True)
    sw = np.bincount(inv, weights=w, minlength=len(cells))
    ok = sw > 0
    mean_all = np.bincount(inv, weights=w * residual, minlength=len(cells)) / np.maximum(sw, 1e-300)
    mean = mean_all[ok]
    n = max(int(ok.sum()), 2)
    within = float(np.sum(w * (residual - mean_all[inv]) ** 2))
    n_w = max(float(np.sum(w)) - n, 1.0)
    return (n * math.log(max(float(np.sum(mean ** 2)), 1e-300) / n)
            + n_w * math.log(max(within, 1e-300) / n_w) + k * math.log(n))


def spatial_folds(obs: Observations, k: int = 5, blocks: int = 4) -> np.ndarray:
    """(N,) fold index: the field cut into blocks x blocks squares, assigned to folds at random (seeded)."""
    bx = np.clip(((obs.x + 1) / 2 * blocks).astype(int), 0, blocks - 1)
    by = np.clip(((obs.y + 1) / 2 * blocks).astype(int), 0, blocks - 1)
    perm = np.random.default_rng(0).permutation(blocks * blocks) % k
    return perm[by * blocks + bx]


@one_blas_thread()
def choose_order(obs: Observations, family: str, focus_degrees: tuple[int, ...], degrees=DEGREES, radials=RADIAL,
                 low_focus_degrees: tuple[int | None, ...] = (None,)) -> tuple[int, int, int, list]:
    """(degree, radial, focus_degree, table) minimising the spatial-block CV RMS residual (each held-out fold
    predicted by the fit on the others); ties within 2 % go to the smaller model (fewer parameters, then lower
    degrees). low_focus_degrees: the non-edge functions' degrees in focus tried (None: focus_degree); the table's
    rows say which (`low_focus_degree`), and the pick's is `table_pick(table)["low_focus_degree"]`."""
    folds = spatial_folds(obs)
    table = []
    for fd in focus_degrees:
        for mfd in low_focus_degrees:
            if mfd is not None and mfd >= fd:
                continue  # the same model as None
            for deg in degrees:
                for rad in radials:
                    if rad and not FieldBasis(deg, rad).powers():
                        continue  # no radial power beyond the monomials: the same model as rad = 0
                    if mfd is not None and not FieldBasis(deg, rad).edge_powers():
                        continue  # no edge power: the same model as focus degree mfd
                    cols = FieldBasis(deg, rad, obs.aspect).columns(obs.x, obs.y)
                    err, n = 0.0, 0
                    for f in np.unique(folds):
                        test = folds == f
                        w = np.where(test, 0.0, obs.weight)
                        res = fit_family(obs, family, deg, fd, weight=w, radial=rad, columns=cols,
                                         low_focus_degree=mfd)
                        if res is None:
                            err = math.inf
                            break
                        err += float(np.sum(obs.weight[test] * res[2][test] ** 2))
                        n += float(obs.weight[test].sum())
                    row = {"degree": deg, "radial": rad, "focus_degree": fd,
                           "params": FieldBasis(deg, rad).params(fd, mfd),
                           "cv_rms_d": math.sqrt(err / max(n, 1e-12)) if math.isfinite(err) else math.inf}
                    if mfd is not None:
                        row["low_focus_degree"] = mfd
                    table.append(row)
    pick = table_pick(table)
    return pick["degree"], pick["radial"], pick["focus_degree"], table


def table_pick(table: list) -> dict:
    """The CV table's chosen row: the smallest model within 2 % of the best CV RMS."""
    best = min(t["cv_rms_d"] for t in table)
    ok = [t for t in table if t["cv_rms_d"] <= best * 1.02]
    return min(ok, key=lambda t: (t["params"], t["degree"], t["radial"]))


def order_weights(table: list) -> list[tuple[dict, float]]:
    """The spatial-block CV table's rows with a weight in the blend: 1 at the best CV RMS, falling linearly to 0 at
    ORDER_BAND worse (rows at 0 left out). Continuous in the CVs: where the rule before (the smallest model within
    2 % of the best) flipped between two orders, the blend moves a little."""
    finite = [t for t in table if math.isfinite(t["cv_rms_d"])]
    if not finite:
        raise ValueError("no field order could be fitted in every cross-validation fold")
    best = min(t["cv_rms_d"] for t in finite)
    rows = [(t, 1.0 - (t["cv_rms_d"] / best - 1.0) / ORDER_BAND) for t in finite]
    return [(t, float(w)) for t, w in rows if w > 0]


def edge_weight(table: dict) -> float:
    """The edge cubic's weight from `choose_edge_focus`'s table: 0 where it predicts held-out cells no better than
    the quadratic, 1 where 2 x EDGE_BAND better, linear between (0.5 at EDGE_BAND better: the rule before took the
    cubic from there on)."""
    cv = table["cv_rms_d"]
    base, edge = cv[next(k for k in cv if not k.startswith("edge"))], cv[f"edge {EDGE_FOCUS_DEGREE}"]
    if not math.isfinite(edge) or edge <= 0:  # the cubic failed in a fold (as the rule before: not taken)
        return 0.0
    if not math.isfinite(base):  # only the quadratic failed
        return 1.0
    return float(np.clip((base / edge - 1.0) / (2 * EDGE_BAND), 0.0, 1.0))


def cell_folds(obs: Observations, k: int = 5) -> np.ndarray:
    """(N,) fold index: the cells (one sweep's tiles peaking between the same two frames) assigned to folds at
    random (seeded): a held-out fold is a set of focus intervals, which tests how the model follows focus."""
    cells = np.unique(obs.cell)
    perm = np.random.default_rng(0).permutation(len(cells)) % k
    return perm[np.searchsorted(cells, obs.cell)]


@one_blas_thread()
def cv_rms(obs: Observations, family: str, degree: int, radial: int, focus_degree: int, folds: np.ndarray,
           low_focus_degree: int | None = None) -> float:
    """RMS residual of each fold's tiles predicted by the fit on the others."""
    cols = FieldBasis(degree, radial, obs.aspect).columns(obs.x, obs.y)
    err, n = 0.0, 0.0
    for f in np.unique(folds):
        test = folds == f
        res = fit_family(obs, family, degree, focus_degree, weight=np.where(test, 0.0, obs.weight), radial=radial,
                         columns=cols, low_focus_degree=low_focus_degree)
        if res is None:
            return math.inf
        err += float(np.sum(obs.weight[test] * res[2][test] ** 2))
        n += float(obs.weight[test].sum())
    return math.sqrt(err / max(n, 1e-12))


def choose_edge_focus(obs: Observations, family: str, degree: int, radial: int, focus_degree: int
                      ) -> tuple[int, int | None, dict | None]:
    """(focus_degree, low_focus_degree, table): whether the edge powers (`FieldBasis.edge_powers`) follow focus
    one degree further (EDGE_FOCUS_DEGREE) than the rest of the field term, by cross-validation over frame cells
    (`cell_folds`: the question is how the model follows focus, which spatial blocks do not test), the larger
    model only where it is more than 2 % better. Needs a sweep per Legendre degree (as `fit_model`'s cap) and
    a quadratic chosen for the rest; else the order as it is (table None).

    Why: a phone lens's best focus at the field's edge does not move with focus as a parabola. Under its
    astigmatism the focus measure follows the sagittal focus near and the middle between the foci farther
    (BENCHMARKS.md, "The phone's outer field"), so at field radius 0.8 the in-focus object's offset from the
    axis's rises, falls and rises again over 5-20 D. With tiles made exactly from the truth the quadratic misses
    that by 0.17 D RMS at radius 0.75-0.84 (the edge cubic: 0.05 D). The monomials (tilt, decentre) and the low
    radial powers (the field's curvature) stay quadratic: given the cubic too, they follow the measured tiles'
    noise in the middle of the field (benchmarks/probes/phone_map_model.py)."""
    n_sweeps = len(np.unique(obs.sweep))
    fb = FieldBasis(degree, radial, obs.aspect)
    if focus_degree != 2 or n_sweeps - 1 < EDGE_FOCUS_DEGREE or not fb.edge_powers():
        return focus_degree, None, None
    folds = cell_folds(obs)
    base = cv_rms(obs, family, degree, radial, focus_degree, folds)
    edge = cv_rms(obs, family, degree, radial, EDGE_FOCUS_DEGREE, folds, focus_degree)
    table = {"cells": int(len(np.unique(obs.cell))), "cv_rms_d": {str(focus_degree): base,
                                                                  f"edge {EDGE_FOCUS_DEGREE}": edge}}
    if edge < base / 1.02:
        return EDGE_FOCUS_DEGREE, focus_degree, table
    return focus_degree, None, table


def families_for(obs: Observations) -> tuple[str, ...]:
    """The families the sweeps can tell apart: a monotone curve (3 parameters) needs three chart distances; with
    two, each sweep's own small offset (a tape-measure error) would bend the curve through the gap between them."""
    n = len(np.unique(obs.sweep))
    return tuple(f for f in FAMILY_PARAMS if f != "monotone" or n >= 3)


@one_blas_thread()
def fit_all(obs: Observations, degree: int, focus_degree: int, families=None,
            weight: np.ndarray | None = None, radial: int = 0, columns: np.ndarray | None = None,
            low_focus_degree: int | None = None) -> dict:
    """{family: (FocusError, FieldPoly, residuals, BIC)} for every family (default: `families_for`) that can be
    fitted (columns: as `fit_family`'s)."""
    out = {}
    if columns is None:
        columns = FieldBasis(degree, radial, obs.aspect).columns(obs.x, obs.y)
    for name in families or families_for(obs):
        res = fit_family(obs, name, degree, focus_degree, weight=weight, radial=radial, columns=columns,
                         low_focus_degree=low_focus_degree)
        if res is not None:
            out[name] = (*res, bic(obs, res[2], FAMILY_PARAMS[name], weight))
    return out


def select(fits: dict) -> str:
    """The family with the lowest BIC (ties: fewer parameters)."""
    return min(fits, key=lambda n: (round(fits[n][3], 9), FAMILY_PARAMS[n]))


def edge_split(obs: Observations, family: str, row: dict, weight: float) -> tuple[list[Component], dict | None]:
    """A spatial order (a CV table row) with its weight, split between the edge powers quadratic and cubic in focus
    by `edge_weight` where `choose_edge_focus` asks (else the order as it is); and that table."""
    low = row.get("low_focus_degree")
    if low is not None:
        return [Component(row["degree"], row["radial"], row["focus_degree"], low, weight)], None
    _, _, table = choose_edge_focus(obs, family, row["degree"], row["radial"], row["focus_degree"])
    if table is None:
        return [Component(row["degree"], row["radial"], row["focus_degree"], None, weight)], None
    w = edge_weight(table)
    comps = [Component(row["degree"], row["radial"], row["focus_degree"], None, weight * (1 - w)),
             Component(row["degree"], row["radial"], EDGE_FOCUS_DEGREE, row["focus_degree"], weight * w)]
    return [c for c in comps if c.weight > 0], table


def _blend_focus(errors: list[FocusError], w: np.ndarray) -> FocusError:
    """The weighted mean of one family's FocusErrors (their parameters; a monotone curve's knots lie at the same
    reported diopters, the observations' range, so its true diopters are averaged)."""
    fam = errors[0].family
    if fam == "offset":
        return FocusError("offset", bias_d=float(sum(wi * e.bias_d for wi, e in zip(w, errors))))
    if fam == "scale":
        return FocusError("scale", scale=float(sum(wi * e.scale for wi, e in zip(w, errors))))
    if fam == "monotone":
        k = sum(wi * np.asarray(e.map_d) for wi, e in zip(w, errors))
        return FocusError("monotone", map_d=tuple(float(v) for v in k))
    return FocusError("none")


def _blend_fields(fields: list[FieldPoly], w: np.ndarray) -> FieldPoly:
    """The weighted sum of field terms over one focus range: on the union of their monomials."""
    terms = list(dict.fromkeys(tuple(t) for f in fields for t in f.terms.tolist()))
    j = max(f.coefficients.shape[1] for f in fields)
    c = np.zeros((len(terms), j))
    for wi, f in zip(w, fields):
        for t, row in zip(f.terms.tolist(), f.coefficients):
            c[terms.index(tuple(t)), :len(row)] += wi * row
    return FieldPoly(np.array(terms, np.int64), c, fields[0].focus_range_d)


@one_blas_thread()
def fit_blend(obs: Observations, components, rule: Component | None = None, family: str | None = None) -> ModelFit:
    """The model as the weighted mean of its components' fits (`Component`). The family is chosen by BIC at the
    order `rule` (default the heaviest component's; `fit_model` gives the one its rule picks, whose order the fit
    reports); each component is fitted with it, the focus error is the weighted mean of theirs, and, with that
    focus error fixed, each component's field term is fitted again (so that they share one on-axis focus and one
    focus range) and summed with the weights, as are fitted chart distances. One component at the rule's order:
    the fit at that order, as `fit_model` with the order given. The residuals are against the blend. family: that
    family instead of the one BIC chooses (`profile_shifts`)."""
    comps = sorted((c for c in components if c.weight > 0), key=lambda c: -c.weight)
    if not comps:
        raise ValueError("no order with a weight to fit")
    head = rule or comps[0]
    order = lambda c: dict(radial=c.radial, low_focus_degree=c.low_focus_degree)
    fits = fit_all(obs, head.degree, head.focus_degree, families=(family,) if family else None, **order(head))
    if not fits:
        raise ValueError("no focus-error family could be fitted to the tiles")
    best = select(fits)
    total = sum(c.weight for c in comps)
    blend = tuple(replace(c, weight=c.weight / total) for c in comps)
    base = dict(degree=head.degree, focus_degree=head.focus_degree, radial=head.radial,
                low_focus_degree=head.low_focus_degree, blend=blend)
    same = lambda a, b: (a.degree, a.radial, a.focus_degree, a.low_focus_degree) == \
        (b.degree, b.radial, b.focus_degree, b.low_focus_degree)
    if len(comps) == 1 and same(comps[0], head):
        fe, fp, res, _ = fits[best]
        shifts: dict = {}
        if len(obs.free_sweeps()):
            fit_family(obs, best, head.degree, head.focus_degree, shifts=shifts, **order(head))
        return ModelFit(fe, fp, res, fits, shifts_mm=shifts, **base)
    parts = [(c, r[0]) for c in comps if (r := fit_family(obs, best, c.degree, c.focus_degree, **order(c)))]
    w = np.array([c.weight for c, _ in parts])
    w = w / w.sum()
    fe = _blend_focus([e for _, e in parts], w)
    on_axis = replace(obs, reported_d=fe.true_diopters(obs.reported_d))  # the focus error fixed: family "none"
    fields, shifts_k = [], []
    for c, _ in parts:
        sh: dict = {}
        fields.append(fit_family(on_axis, "none", c.degree, c.focus_degree, shifts=sh, **order(c))[1])
        shifts_k.append(sh)
    fp = _blend_fields(fields, w)
    shifts = {k: float(sum(wi * sh[k] for wi, sh in zip(w, shifts_k))) for k in shifts_k[0]}
    fit = ModelFit(fe, fp, np.zeros(len(obs)), fits, shifts_mm=shifts, **base)
    delta = np.array([shifts[int(k)] for k in obs.free_sweeps()])
    fit.residual_d = obs.object_d - distance_columns(obs) @ delta - fit.predict(obs.x, obs.y, obs.reported_d)
    return fit


def _family_for_order(obs: Observations) -> str:
    """The family the orders' cross-validations fit with: the most general the sweeps allow."""
    return "monotone" if "monotone" in families_for(obs) else "scale"


@one_blas_thread()
def fit_model(obs: Observations, degree: int | None = None, focus_degree: int | None = None,
              radial: int | None = None, low_focus_degree: int | None = None,
              max_focus_degree: int = MAX_FOCUS_DEGREE, low_focus_degrees: tuple = LOW_FOCUS_DEGREES,
              edge_focus: bool = True) -> ModelFit:
    """The model on all observations: order by CV (what is not given), family by BIC. With one sweep the field
    term cannot depend on focus (focus_degree 0); with two at most linearly; never beyond max_focus_degree.
    low_focus_degree: the non-edge functions' degree in focus when the order is given (`FieldBasis.focus_mask`);
    when it is chosen, the CV tries low_focus_degrees (None: focus_degree for every function), and the orders
    within ORDER_BAND of the best are blended (`order_weights`), each with, where edge_focus, its edge powers
    quadratic or cubic in focus blended by the frame cells' CV (`edge_split`; `fit_blend`)."""
    n_sweeps = len(np.unique(obs.sweep))
    max_fd = min(max_focus_degree, n_sweeps - 1)
    if degree is not None and focus_degree is not None and radial is not None:
        fit = fit_blend(obs, [Component(degree, radial, focus_degree, low_focus_degree, 1.0)])
        return replace(fit, blend=())
    fds = (focus_degree,) if focus_degree is not None else tuple(range(max_fd + 1))
    degs = (degree,) if degree is not None else DEGREES
    rads = (radial,) if radial is not None else RADIAL
    fam = _family_for_order(obs)
    _, _, _, table = choose_order(obs, fam, fds, degs, rads, low_focus_degrees)
    comps, rule, edge_cv = _split_edges(obs, fam, order_weights(table), table_pick(table), edge_focus)
    return replace(fit_blend(obs, comps, rule), cv=table, edge_cv=edge_cv)


def _split_edges(obs: Observations, family: str, rows: list, pick: dict, edge_focus: bool = True
                 ) -> tuple[list[Component], Component, dict | None]:
    """`edge_split` over weighted spatial orders (rows: (CV table row, weight)); the order the rule picks (pick:
    the spatial CV's smallest within 2 % of the best, `table_pick`; its edge powers cubic where the frame cells'
    CV is more than EDGE_BAND better, `choose_edge_focus`), where the family is chosen and which the fit reports;
    and pick's edge table."""
    key = lambda r: (r["degree"], r["radial"], r["focus_degree"], r.get("low_focus_degree"))
    if key(pick) not in {key(r) for r, _ in rows}:
        rows = [*rows, (pick, 0.0)]  # (its edge table is asked; it adds no component)
    comps, rule, edge_cv = [], None, None
    for row, w in rows:
        if edge_focus:
            cs, table = edge_split(obs, family, row, w)
        else:
            cs, table = [Component(*key(row), w)], None
        comps += [c for c in cs if c.weight > 0]
        if key(row) == key(pick):
            edge_cv = table
            cubic = table is not None and edge_weight(table) >= 0.5
            rule = Component(row["degree"], row["radial"], EDGE_FOCUS_DEGREE, row["focus_degree"], 1.0) if cubic \
                else Component(*key(row), 1.0)
    return comps, rule, edge_cv


def _rule_of(fit: ModelFit) -> Component:
    return Component(fit.degree, fit.radial, fit.focus_degree, fit.low_focus_degree, 1.0)


def refit(obs: Observations, fit: ModelFit, family: str | None = None) -> ModelFit:
    """`fit`'s order (or blend of orders, with their weights) on obs, its CV tables kept; family: that family
    instead of BIC's choice."""
    if fit.blend:
        new = fit_blend(obs, fit.blend, _rule_of(fit), family=family)
    else:
        new = replace(fit_blend(obs, [replace(_rule_of(fit), weight=1.0)], family=family), blend=())
    return replace(new, cv=fit.cv, edge_cv=fit.edge_cv)


PROFILE_STEP_D = 0.1  # `profile_shifts`' step: the chart's tiles moved by about this many diopters of object
PROFILE_MAX_SHIFT = 0.05  # a profile minimum farther than this share of the chart's distance is not taken


def _vertex(rss: tuple[float, float, float], h: float) -> float | None:
    """The minimum of the parabola through (-h, rss[0]), (0, rss[1]), (h, rss[2]); None when it has none."""
    a = (rss[0] + rss[2] - 2.0 * rss[1]) / (2.0 * h * h)
    if not (np.isfinite(a) and a > 0):
        return None
    return float(-(rss[2] - rss[0]) / (2.0 * h) / (2.0 * a))


def measured_rss(obs: Observations, residual: np.ndarray, weight: np.ndarray | None = None) -> float:
    """The weighted squared residuals of the tiles of sweeps whose chart distance is measured (not fitted)."""
    w = obs.weight if weight is None else weight
    m = ~np.isin(obs.sweep, obs.free_sweeps())
    return float(np.sum(w[m] * residual[m] ** 2))


def profile_step_mm(obs: Observations, sweep: int) -> float:
    """The profile's step for `sweep`'s chart distance (mm): its tiles' objects move by about PROFILE_STEP_D."""
    dz = np.abs(obs.dz[obs.sweep == sweep])
    return PROFILE_STEP_D / max(float(np.mean(dz)), 1e-12)


def profile_shifts(obs: Observations, fit: ModelFit, family: str | None = None) -> dict:
    """{sweep: shift (mm)} of each fitted chart distance (`Observations.dz`) where the tiles of the charts whose
    distance is measured fit best: the model refitted at `fit`'s order (or blend) and family (default fit's) with the
    chart's tiles moved by dz * s, the measured charts' weighted squared residuals (`measured_rss`) at s = -h, 0, h,
    and the parabola's minimum (linearised: `fit.fit_calibration` moves the chart and asks again). Each fitted
    chart in turn, the others where obs has them; a chart whose profile has no minimum, or one farther than
    PROFILE_MAX_SHIFT of its distance, is left out (the caller keeps the joint fit's shift).

    Why not the joint least squares (`distance_columns`): a shift of the near chart moves all its tiles alike, and
    the field term, zero only at the frame centre and free in focus where only that chart's tiles are, takes most of
    such a shift; the shift is then the intercept of a high-order polynomial through that chart's tiles, and a few
    hundredths of a diopter of ring-shaped error in them move it by most of a millimetre (on the benchmark's phone:
    55.75-55.91 mm for a chart at 55.0, its own tiles at radius 0.5-0.75 pulling +0.6 mm;
    benchmarks/probes/near_distance.py). The measured charts' tiles see the shift only through the smooth surface
    they share with the near chart, and their residuals are least at the true distance (54.97-55.13 mm there)."""
    fam = family or fit.focus.family
    out: dict = {}
    for k in obs.free_sweeps():
        v = _profile_vertex(obs, int(k), lambda moved: measured_rss(obs, refit(moved, fit, family=fam).residual_d))
        if v is not None:
            out[int(k)] = v
    return out


def _profile_vertex(obs: Observations, sweep: int, rss_of) -> float | None:
    """The parabola's minimum (mm) of rss_of(obs with `sweep`'s tiles moved by dz * s, distances fixed) at s = -h, 0,
    h (h: `profile_step_mm`); None when rss_of gives None or the parabola has no minimum."""
    h = profile_step_mm(obs, sweep)
    move = np.where(obs.sweep == sweep, obs.dz, 0.0)
    fixed = replace(obs, dz=None)
    rss = [rss_of(replace(fixed, object_d=obs.object_d + move * s)) for s in (-h, 0.0, h)]
    return None if any(r is None for r in rss) else _vertex(tuple(rss), h)


def profile_shift_at_order(obs: Observations, sweep: int, family: str, degree: int, focus_degree: int,
                           radial: int, low_focus_degree: int | None, weight: np.ndarray, columns: np.ndarray
                           ) -> float | None:
    """`profile_shifts` for one chart at one order (no blend) under bootstrap weights (`bootstrap`)."""
    def rss_of(moved):
        res = fit_family(moved, family, degree, focus_degree, weight=weight, radial=radial, columns=columns,
                         low_focus_degree=low_focus_degree)
        return None if res is None else measured_rss(obs, res[2], weight)

    return _profile_vertex(obs, sweep, rss_of)


def refit_edge(obs: Observations, fit: ModelFit) -> ModelFit:
    """`fit`'s spatial order(s) on obs with the edge powers' degree in focus chosen (blended) again
    (`choose_edge_focus`, `edge_split`): after the fit's outlier pass, whose tiles (a few, 5 robust SDs off)
    otherwise weigh most in the squared errors the cross-validation compares (on the benchmark's nominal phone:
    0.2185 against 0.2191 D with them, 0.2196 against 0.1845 D without), and after chart distances are fitted."""
    fam = _family_for_order(obs)
    if not fit.blend:
        fd = fit.low_focus_degree if fit.low_focus_degree is not None else fit.focus_degree
        fd, low, table = choose_edge_focus(obs, fam, fit.degree, fit.radial, fd)
        return replace(fit_model(obs, fit.degree, fd, fit.radial, low), cv=fit.cv, edge_cv=table)
    base = lambda c: c.low_focus_degree if c.focus_degree == EDGE_FOCUS_DEGREE and c.low_focus_degree is not None \
        else c.focus_degree
    spatial: dict = {}  # the spatial orders and their weights, the edge split undone
    for c in fit.blend:
        spatial[(c.degree, c.radial, base(c))] = spatial.get((c.degree, c.radial, base(c)), 0.0) + c.weight
    row = lambda d, r, f: {"degree": d, "radial": r, "focus_degree": f}
    rows = [(row(*k), w) for k, w in spatial.items()]
    comps, rule, table = _split_edges(obs, fam, rows, row(fit.degree, fit.radial, base(fit)))
    return replace(fit_blend(obs, comps, rule), cv=fit.cv, edge_cv=table)


@dataclass
class Bootstrap:
    """support {family: share}; intervals {"bias_d" | "scale": [lo, hi]} of the chosen family; map_sd (ny, nx) the
    spread of the in-focus diopters at the middle of the focus range on grid x (nx,), y (ny,); replicates."""

    support: dict
    intervals: dict
    grid_x: np.ndarray
    grid_y: np.ndarray
    map_sd: np.ndarray
    replicates: int
    shifts_mm: dict = field(default_factory=dict)  # {sweep: [lo, hi]} of a fitted chart distance's shift (mm)


@one_blas_thread()
def bootstrap(obs: Observations, fit: ModelFit, n_boot: int = 100, seed: int = 0, level: float = 0.95,
              grid: tuple[int, int] = (9, 13), max_shift_mm: dict | None = None) -> Bootstrap:
    """Poisson weights per tile, times per sweep when there are >= 3 sweeps; each replicate refits every family at
    the chosen order and reselects, with the charts at their fitted distances; a fitted distance's spread is each
    replicate's own `profile_shifts` minimum (at the order, linearised: `profile_shift_at_order`), or, as the fit
    does, the joint least squares' shift where it has none or one beyond max_shift_mm {sweep: mm}."""
    rng = np.random.default_rng(seed)
    sweeps = np.unique(obs.sweep)
    wins = {k: 0 for k in FAMILY_PARAMS}
    params: dict[str, list] = {"bias_d": [], "scale": []}
    ny, nx = grid
    gx, gy = np.linspace(-1, 1, nx), np.linspace(-1, 1, ny)
    xx, yy = np.meshgrid(gx, gy)
    lo, hi = fit.field.focus_range_d
    mid_t = 0.5 * (lo + hi)
    maps = []
    shift_draws: dict[int, list] = {}
    cols = FieldBasis(fit.degree, fit.radial, obs.aspect).columns(obs.x, obs.y)
    fixed = replace(obs, dz=None)  # the charts at their fitted distances; each replicate's own by `profile_shifts`
    for _ in range(n_boot):
        w = obs.weight * rng.poisson(1.0, len(obs))
        if len(sweeps) >= 3:
            ws = rng.poisson(1.0, len(sweeps))
            w = w * ws[np.searchsorted(sweeps, obs.sweep)]
        if w.sum() <= 0 or (len(obs.free_sweeps()) and w[~np.isin(obs.sweep, obs.free_sweeps())].sum() <= 0):
            continue  # (a replicate without any sweep of a measured distance cannot measure the focus error)
        fits = fit_all(fixed, fit.degree, fit.focus_degree, weight=w, radial=fit.radial, columns=cols,
                       low_focus_degree=fit.low_focus_degree)
        if not fits:
            continue
        wins[select(fits)] += 1
        if fit.focus.family in fits:
            fe, fp = fits[fit.focus.family][:2]
            params["bias_d"].append(fe.bias_d)
            params["scale"].append(fe.scale)
            maps.append(fp(xx, yy, [mid_t])[0])
            for k in obs.free_sweeps():
                if w[obs.sweep == k].sum() > 0:
                    v = profile_shift_at_order(obs, int(k), fit.focus.family, fit.degree, fit.focus_degree,
                                               fit.radial, fit.low_focus_degree, w, cols)
                    if v is None or abs(v) > (max_shift_mm or {}).get(int(k), math.inf):
                        sh: dict = {}
                        fit_family(obs, fit.focus.family, fit.degree, fit.focus_degree, weight=w, radial=fit.radial,
                                   columns=cols, shifts=sh, low_focus_degree=fit.low_focus_degree)
                        v = sh.get(int(k))
                    if v is not None:
                        shift_draws.setdefault(int(k), []).append(v)
    a = (1 - level) / 2
    total = max(sum(wins.values()), 1)
    keys = {"offset": ["bias_d"], "scale": ["scale"]}.get(fit.focus.family, [])
    intervals = {k: [float(np.quantile(params[k], a)), float(np.quantile(params[k], 1 - a))]
                 for k in keys if params[k]}
    sd = np.std(np.array(maps), 0) if len(maps) > 1 else np.full((ny, nx), np.nan)
    shifts = {k: [float(np.quantile(v, a)), float(np.quantile(v, 1 - a))] for k, v in shift_draws.items() if v}
    return Bootstrap({k: v / total for k, v in wins.items()}, intervals, gx, gy, sd, len(maps), shifts)


def with_intervals(fe: FocusError, boot: Bootstrap) -> FocusError:
    return replace(fe, intervals=boot.intervals, support=boot.support)
