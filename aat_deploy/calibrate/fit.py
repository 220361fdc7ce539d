"""From measured chart sweeps to a `CameraCalibration` (what `aat-calibrate fit` runs): the tiles' observations
pooled over the sweeps, the smooth model (`model.py`) with its bootstrap, the blur growth, the residuals.

Frames from different cameras across the sweeps are refused (one line); everything is computed before anything
is written (the CLI writes atomically).
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass, field, replace

import numpy as np

from .. import __version__
from .format import CameraCalibration, CameraIdentity, FieldPoly, field_radius_of, poly_terms
from .model import (
    PROFILE_MAX_SHIFT,
    Observations,
    bootstrap,
    fit_model,
    profile_shifts,
    refit,
    refit_edge,
    with_intervals,
)
from .peaks import blur_slope, relative_blur_px
from .sweep import SweepError, SweepMeasurement, identity_differences

BLUR_DEGREE = 2
MIN_TILES = 30
# the field term beyond the farthest tile's radius (`FieldPoly.beyond`): "held" along the radius; "linear"
# (continued to first order along the radius) was declared, scored on the benchmark's phone and not adopted: it
# carries the held edge's own error outward (docs/calibration.md, "The corners beyond the farthest tile");
# "rectangle" (held at the nearest point of the tile centres' rectangle, inside which the fit has data) was declared
# and scored the same way and not adopted: it also holds the band within the radius where the polynomial's short
# extrapolation follows the lens's rise (docs/calibration.md, "The corners held at the tile centres' rectangle")
BEYOND_TILES = "held"


@dataclass
class FitResult:
    """The calibration, the pooled observations and the model fit, per-sweep tables and warnings."""

    calibration: CameraCalibration
    observations: Observations
    model: object
    blur_obs: dict
    sweeps: list
    warnings: list[str] = field(default_factory=list)
    measures: list = field(default_factory=list)  # the sweeps as fitted (a fitted chart distance's objects moved)


def observations(measures: list[SweepMeasurement]) -> Observations:
    """Every counted tile of every sweep; cells = (sweep, interval between the two frames the peak lies between);
    the frames' aspect (the field radius's shape)."""
    cols = {k: [] for k in ("x", "y", "reported_d", "object_d", "sweep", "cell")}
    dz = []
    for i, m in enumerate(measures):
        ok = m.peaks.counted
        x, y = m.peaks.grid.field()
        rd = m.peaks.reported_d
        interval = np.clip(np.searchsorted(rd, m.peaks.peak_d[ok]), 0, len(rd))
        cols["x"].append(x[ok])
        cols["y"].append(y[ok])
        cols["reported_d"].append(m.peaks.peak_d[ok])
        cols["object_d"].append(m.object_d[ok])
        cols["sweep"].append(np.full(int(ok.sum()), i))
        cols["cell"].append(i * 10_000 + interval)
        dz.append(m.object_dz()[ok] if m.fit_distance else np.zeros(int(ok.sum())))
    w, h = measures[0].sweep.size_px
    free = any(m.fit_distance for m in measures)
    return Observations(*(np.concatenate(cols[k]).astype(np.float64 if k not in ("sweep", "cell") else np.int64)
                          for k in cols), aspect=w / h, dz=np.concatenate(dz).astype(np.float64) if free else None)


def camera_identity(measures: list[SweepMeasurement]) -> CameraIdentity:
    """The sweeps' common camera; SweepError naming the sweep whose frames come from another camera."""
    first = measures[0].sweep
    for m in measures[1:]:
        diff = identity_differences(first.identity, m.sweep.identity)
        if diff:
            raise SweepError(f"{m.sweep.path}: from another camera than {first.path} ({'; '.join(diff)}): calibrate "
                             "one camera, lens, aperture and zoom at a time")
        if m.sweep.size_px != first.size_px:
            raise SweepError(f"{m.sweep.path}: frames of {m.sweep.size_px[0]}x{m.sweep.size_px[1]} px, "
                             f"{first.path}'s {first.size_px[0]}x{first.size_px[1]} px")
    return camera_identity_of(first)


def camera_identity_of(sweep) -> CameraIdentity:
    """A sweep's (or capture's) camera from its frames' EXIF."""
    i = sweep.identity
    num = lambda v: float(v) if v not in (None, "") else None
    return CameraIdentity(str(i.get("make") or ""), str(i.get("model") or ""), str(i.get("lens") or ""),
                          num(i.get("focal_length_mm")), num(i.get("f_number")))


def fit_blur(measures: list[SweepMeasurement], model) -> tuple[FieldPoly | None, dict]:
    """Blur growth: per tile the Gaussian-equivalent sigma per diopter (`peaks.blur_slope`), times 4 (a disk's
    diameter), in px of the frames as shot; a smooth field (degree BLUR_DEGREE with a constant), linear in the
    on-axis focus when there are two or more sweeps. Returns (FieldPoly or None, observations)."""
    xs, ys, ts, ks = [], [], [], []
    for m in measures:
        pk = m.peaks
        ok = pk.counted
        if not ok.any():
            continue
        x, y = pk.grid.field()
        sig = relative_blur_px(m.sweep.frames, pk.sharpest, pk.grid)
        frame_d = np.stack([model.predict(x, y, np.full(x.shape, r)) for r in pk.reported_d])  # (S, ny, nx)
        k = blur_slope(sig, frame_d - m.object_d[None], pk.sharpest)
        good = ok & np.isfinite(k) & (k > 0)
        xs.append(x[good])
        ys.append(y[good])
        ts.append(model.focus.true_diopters(pk.peak_d[good]))
        ks.append(4.0 * k[good] / m.sweep.scale)  # diameter, px of the frames as shot
    obs = {"x": np.concatenate(xs) if xs else np.zeros(0), "y": np.concatenate(ys) if ys else np.zeros(0),
           "t_d": np.concatenate(ts) if ts else np.zeros(0), "px_per_d": np.concatenate(ks) if ks else np.zeros(0)}
    n = len(obs["x"])
    terms = poly_terms(BLUR_DEGREE, constant=True)
    if n < 2 * len(terms):
        return None, obs
    fd = 1 if len({round(float(m.chart_distance_m), 3) for m in measures}) >= 2 else 0
    lo, hi = float(obs["t_d"].min()), float(obs["t_d"].max())
    fp0 = FieldPoly(terms, np.zeros((len(terms), fd + 1)), (lo, hi))
    leg = np.polynomial.legendre.legvander(fp0.tau(obs["t_d"]), fd)
    basis = np.stack([obs["x"] ** a * obs["y"] ** b for a, b in terms], 1)
    a = (basis[:, :, None] * leg[:, None, :]).reshape(n, -1)
    keep = np.ones(n, bool)
    for _ in range(2):  # one pass of outlier rejection (tiles whose best sigma hit the grid's end)
        sol, *_ = np.linalg.lstsq(a[keep], obs["px_per_d"][keep], rcond=None)
        res = obs["px_per_d"] - a @ sol
        mad = float(np.median(np.abs(res[keep] - np.median(res[keep])))) * 1.4826
        keep = np.abs(res) <= max(4 * mad, 1e-9)
    obs["residual"] = res
    obs["kept"] = keep
    return FieldPoly(terms, sol.reshape(len(terms), fd + 1), (lo, hi)), obs


FIT_DISTANCE_ITERATIONS = 6
FITTED = "fitted (where the measured charts' tiles fit best)"


def _same_tiles(new: Observations, old: Observations) -> Observations:
    """new's tiles that old kept (old: after the outlier pass), matched by sweep and position."""
    key = lambda o: [(int(s), round(float(x), 9), round(float(y), 9)) for s, x, y in zip(o.sweep, o.x, o.y)]
    kept = set(key(old))
    return new.subset(np.array([k in kept for k in key(new)], bool))


def held_beyond_tiles(field_poly: FieldPoly, obs: Observations) -> FieldPoly:
    """The field term not extrapolated as a polynomial beyond the farthest tile (`FieldPoly.radius_max`: held,
    continued to first order along the radius, or held at the tile centres' rectangle, as BEYOND_TILES says): there
    no tile measured it, and its radial powers (to rho^12) extrapolated into the corners went 0.9 D wrong on the
    benchmark's phone lens (0.6 D held; BENCHMARKS.md, "What the phone's error is made of")."""
    r = float(np.max(field_radius_of(obs.x, obs.y, obs.aspect)))
    rect = tile_rectangle(obs) if BEYOND_TILES == "rectangle" else None
    return replace(field_poly, radius_max=r, aspect=obs.aspect, beyond=BEYOND_TILES, rectangle=rect)


def tile_rectangle(obs: Observations) -> tuple[float, float, float, float]:
    """(x_lo, x_hi, y_lo, y_hi): the bounding box of the kept tiles' centres (normalised field), the rectangle
    inside which the field term has data on both sides (`FieldPoly.rectangle`)."""
    return float(np.min(obs.x)), float(np.max(obs.x)), float(np.min(obs.y)), float(np.max(obs.y))


def robust_fit(obs: Observations, degree: int | None = None, focus_degree: int | None = None,
               radial: int | None = None) -> tuple:
    """The model with one outlier pass: tiles whose peak disagrees wildly with the first fit (chart border, a glare,
    a two-peaked focus curve) are dropped once and the model fitted again on the tiles kept, with what was to be
    chosen (the field's order by the spatial-block CV, then the edge powers' degree in focus) chosen again there:
    a few tiles 5 robust SDs off weigh most in the squared errors the CVs compare. Until 2026-11-27 only the edge
    powers' degree was chosen again; on the benchmark's phone with tiles reaching the frame's corners (some of them
    1-2.5 D off) the first fit's spatial CV then kept rho^8 instead of rho^12, and the map was 0.12 D instead of
    0.10 (BENCHMARKS.md, "The tiles reach the corners"). Returns (fit, the tiles kept, a warning line or "")."""
    fit = fit_model(obs, degree, focus_degree, radial)
    mad = float(np.median(np.abs(fit.residual_d - np.median(fit.residual_d)))) * 1.4826
    limit = max(5 * mad, 0.005)
    bad = np.abs(fit.residual_d) > limit
    if not bad.any():
        return fit, obs, ""
    obs = obs.subset(~bad)
    if degree is None or radial is None or focus_degree is None:
        fit = fit_model(obs, degree, focus_degree, radial)
    else:
        fit = refit(obs, fit)
    return fit, obs, (f"{int(bad.sum())} of {len(bad)} tiles left out as outliers (peak more than {limit:.3f} D off "
                      "the first fit)")


def fit_calibration(measures: list[SweepMeasurement], n_boot: int = 100, degree: int | None = None,
                    focus_degree: int | None = None, sensor_mm: tuple[float, float] | None = None,
                    settings: dict | None = None, progress=None, radial: int | None = None) -> FitResult:
    """The calibration from measured sweeps (`sweep.measure_sweep`). degree, radial, focus_degree: the field
    term's order (`model.FieldBasis`; None: chosen by cross-validation)."""
    if not measures:
        raise SweepError("no sweeps to fit")
    identity = camera_identity(measures)
    if all(m.fit_distance for m in measures):
        raise SweepError(f"{measures[0].sweep.path}: every chart distance is to be fitted: at least one sweep needs "
                         "a measured distance (the reported focus's error is measured against it)")
    start = {i: m.chart_distance_m for i, m in enumerate(measures) if m.fit_distance}
    from_pose = {i for i in start if measures[i].geometry.how == "pose"}  # `--distance-m ...,~`: the markers' start
    obs = observations(measures)
    if len(obs) < MIN_TILES:
        raise SweepError(f"{measures[0].sweep.path}: only {len(obs)} tiles with a bracketed focus peak over all "
                         f"sweeps (need {MIN_TILES}): fill the frame with the chart and sweep past it on both sides")
    fit, obs, outliers = robust_fit(obs, degree, focus_degree, radial)
    warnings: list[str] = [outliers] if outliers else []
    if start:
        # fitted chart distances: where the measured charts' tiles fit best (`model.profile_shifts`; the joint
        # least squares' shift where that profile has no minimum), the tiles' objects recomputed at the new
        # distance, until the shift is below a micrometre; the model then refitted with the distances fixed
        def fit_distances(measures, obs, fit):
            for _ in range(FIT_DISTANCE_ITERATIONS):
                prof = profile_shifts(obs, fit)
                far = {i for i, v in prof.items() if abs(v) > PROFILE_MAX_SHIFT * 1000.0 * measures[i].chart_distance_m}
                no_minimum.clear()
                no_minimum.update(i for i in start if i not in prof or i in far)
                joint = refit(obs, fit).shifts_mm if no_minimum else {}  # (obs has the fitted distances free)
                shifts = {i: joint.get(i, 0.0) if i in no_minimum else prof[i] for i in start}
                if max(abs(v) for v in shifts.values()) < 1e-3:
                    break
                measures = [m.at_distance(m.chart_distance_m + shifts[i] / 1000.0, FITTED)
                            if i in start else m for i, m in enumerate(measures)]
                obs = _same_tiles(observations(measures), obs)
                fit = refit(replace(obs, dz=None), fit)
            return measures, obs, refit(replace(obs, dz=None), fit)

        no_minimum: set = set()
        measures, obs, fit = fit_distances(measures, obs, fit)
        if focus_degree is None and fit.edge_cv:
            # the edge powers' degree chosen again with the charts at their fitted distances (the choice above saw
            # the tiles of a chart to be fitted at its starting distance); a changed choice refits the distances
            again = refit_edge(replace(obs, dz=None), fit)
            if (again.focus_degree, again.low_focus_degree, again.blend) != \
                    (fit.focus_degree, fit.low_focus_degree, fit.blend):
                measures, obs, fit = fit_distances(measures, obs, again)
            else:
                fit = replace(fit, edge_cv=again.edge_cv)
        for i in sorted(no_minimum):
            warnings.append(f"{measures[i].sweep.path}: the measured charts' tiles do not fix this chart's distance "
                            "(their residuals have no minimum within "
                            f"{100 * PROFILE_MAX_SHIFT:g} % of it): fitted from all tiles together instead")
    if progress:
        progress("bootstrap")
    boot = bootstrap(obs, fit, n_boot=n_boot,
                     max_shift_mm={i: PROFILE_MAX_SHIFT * 1000.0 * measures[i].chart_distance_m for i in start})
    fe = with_intervals(fit.focus, boot)
    if boot.support.get(fe.family, 0) < 0.5:
        warnings.append(f"the focus-error family {fe.family!r} is chosen by only {100 * boot.support.get(fe.family, 0):.0f}"
                        f" % of bootstrap replicates ({', '.join(f'{k} {100 * v:.0f} %' for k, v in boot.support.items() if v)})")
    fit = replace(fit, field=held_beyond_tiles(fit.field, obs))
    if progress:
        progress("blur")
    blur, blur_obs = fit_blur(measures, fit)
    res = fit.residual_d
    per_sweep = []
    for i, m in enumerate(measures):
        r = res[obs.sweep == i]
        extra = {}
        if i in start:  # the distance as started, and the fitted one's bootstrap interval (mm of shift from it)
            ci = boot.shifts_mm.get(i)
            extra = {"distance_given_m": round(start[i], 5),
                     "distance_ci_m": None if ci is None else [round(m.chart_distance_m + v / 1000.0, 5) for v in ci]}
            if i in from_pose:  # the start was the chart's marker pose, not a number given
                extra["distance_start_from"] = "marker pose"
        per_sweep.append({"sweep": str(m.sweep.path), "tiles": int(len(r)),
                          "chart_distance_m": round(m.chart_distance_m, 5 if i in start else 4),
                          "distance_from": m.geometry.how, **extra,
                          "reported_focus_m": [round(float(v), 4) for v in m.sweep.reported_m],
                          "mean_d": float(np.mean(r)) if len(r) else None,
                          "rms_d": float(np.sqrt(np.mean(r ** 2))) if len(r) else None,
                          "markers": int(m.view.markers), "marker_rms_px": round(float(m.view.rms_px), 3),
                          "notes": m.geometry.notes})
        for n in m.geometry.notes:
            if n not in warnings:
                warnings.append(n)
    residuals = {"tiles": int(len(res)), "rms_d": float(np.sqrt(np.mean(res ** 2))),
                 "p95_d": float(np.quantile(np.abs(res), 0.95)), "max_d": float(np.max(np.abs(res))),
                 "per_sweep": per_sweep,
                 "families": {k: {"bic": float(v[3]), "rms_d": float(np.sqrt(np.mean(v[2] ** 2)))}
                              for k, v in fit.fits.items()}}
    if blur is not None:
        keep = blur_obs["kept"]
        residuals["blur_rms_px_per_d"] = float(np.sqrt(np.mean(blur_obs["residual"][keep] ** 2)))
        residuals["blur_tiles"] = int(keep.sum())
    uncertainty = {"x": boot.grid_x.tolist(), "y": boot.grid_y.tolist(),
                   "sd_d": np.round(boot.map_sd, 6).tolist(), "replicates": boot.replicates,
                   "what": "bootstrap standard deviation of the field term at the middle of the focus range"}
    first = measures[0].sweep
    fitinfo = {"method": "chart", "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
               "version": __version__, "degree": fit.degree, "radial_degree": fit.radial,
               "field_radius_max": fit.field.radius_max,
               "object_range_d": [round(float(np.min(obs.object_d)), 6), round(float(np.max(obs.object_d)), 6)],
               "focus_degree": fit.focus_degree, "low_focus_degree": fit.low_focus_degree, "edge_focus_cv": fit.edge_cv,
               "order_blend": [{"degree": c.degree, "radial_degree": c.radial, "focus_degree": c.focus_degree,
                                "low_focus_degree": c.low_focus_degree, "weight": round(c.weight, 6)}
                               for c in fit.blend],
               "order_cv": fit.cv, "working_scale": first.scale, **(settings or {})}
    cal = CameraCalibration(identity, first.size_px, fe, fit.field, blur, sensor_mm, residuals, uncertainty, fitinfo)
    return FitResult(cal, obs, fit, blur_obs, per_sweep, warnings, measures)

