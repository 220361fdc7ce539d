"""The focus sweep made robust to what a twin does not reproduce, before the focus fits read it (docs/diagnosis.md,
"Focus errors"; issue 32). A capture's focus-measure curves carry three things its twin's may lack:

- **a noise floor.** Sensor noise adds its own Laplacian energy to every frame; a developed RAW correlates it
  (demosaicking), so binned captures keep more of it than binned twins with the same noise; a twin of an early
  round has no noise at all. Far from focus a region's log focus measure then stays on the floor instead of
  falling with the twin's, and a frame that shows little in focus is read as focused nearer the middle of the
  stack (the shipped sample: every frame pulled towards the middle, the end frames up to the +-0.4 D bound).
  Each region gets a floor, in the twin's units, fitted on a grid: the twin's curve becomes
  log(exp(t) + exp(beta_r)) (`fit_floors`, `floored`); beta_r = -inf is the twin as rendered.
- **exposure.** A frame g times brighter has g^2 its focus measure: a level shared by every region of the frame,
  which the per-region levels do not remove, and which a focus fit would read as focus. Each frame's gain is
  measured from its regions' brightness against the twin's (`frame_gains_log`, the exposure fitter's measure:
  blur moves light around but keeps a region's mean), and the capture's curves are corrected by it. Brightness
  that changes with focus (a working f-number, a RAW development scaling each frame) is corrected alike, so
  exposure never absorbs focus nor focus exposure.
- **regions the twin misses** (an all-in-focus image without a region's texture, an occlusion edge): each region
  is weighted by the inverse of its residual variance at the per-frame fit (`region_weights`; floored at a
  quarter of the median variance, so no region dominates), i.e. by how well its curve is determined.

The floors and weights are fitted at the per-frame focus estimates (every frame free, `focusfit.frame_focus`),
alternating (`ITERATIONS`), starting from the focus the twin assumes; the families are then fitted on the
prepared sweep with both held fixed. Pure numpy.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from aat_deploy.diagnose import focusfit as ff

FLOOR_STEPS_LOG = np.arange(0.5, 8.01, 0.5)  # candidate floors: log units below the region's highest twin value
ITERATIONS = 12  # at most, floors <-> per-frame focus (from a wrong reported focus the first floors are too high,
# which holds the estimates back: each round moves them part of the way)
CONVERGED_D = 0.002  # ... until no frame's estimate moves more than this (diopters)
MIN_VARIANCE_SHARE = 0.25  # a region's residual variance counts at least this share of the median region's


@dataclass
class RobustConfig:
    """Which corrections `prepare` makes (all on by default; the evidence script switches them one by one)."""

    floors: bool = True
    gains: bool = True
    weights: bool = True
    iterations: int = ITERATIONS


def twin_at(data: ff.SweepData, d: np.ndarray) -> np.ndarray:
    """(n, R, S) the twin's curves with frame focus d (n, S) diopters (every region of a frame alike)."""
    n, r, s = data.capture.shape
    return ff.curves_at(data, np.broadcast_to(d[:, None, :], (n, r, s)).copy())


def region_ss(capture: np.ndarray, twin: np.ndarray) -> np.ndarray:
    """(n, R) squared residuals over the frames with each region's level profiled out; capture, twin (n, R, S),
    NaN frames count nothing."""
    res = capture - twin
    ok = np.isfinite(res)
    res = np.where(ok, res, 0.0)
    res = np.where(ok, res - res.sum(-1, keepdims=True) / np.maximum(ok.sum(-1, keepdims=True), 1), 0.0)
    return (res * res).sum(-1)


def fit_floors(data: ff.SweepData, d: np.ndarray, steps=FLOOR_STEPS_LOG) -> np.ndarray:
    """(n, R) per-region floors beta (the twin's log units; -inf = none) that fit the capture best at frame focus
    d (n, S): the grid of `steps` below the region's highest twin value, and none."""
    tw = twin_at(data, d)
    top = data.twin.max(-1)  # (n, R)
    best, best_ss = np.full(top.shape, -np.inf), region_ss(data.capture, tw)
    for k in steps:
        beta = top - k
        ss = region_ss(data.capture, np.logaddexp(tw, beta[..., None]))
        better = ss < best_ss - 1e-12
        best, best_ss = np.where(better, beta, best), np.where(better, ss, best_ss)
    return best


def floored(data: ff.SweepData, beta: np.ndarray) -> ff.SweepData:
    """The sweep with every region's twin curve lifted by its floor beta (n, R)."""
    return dataclasses.replace(data, twin=np.logaddexp(data.twin, beta[..., None]))


def frame_gains_log(data: ff.SweepData) -> np.ndarray:
    """(n, S) log gain of every frame against the twin (median over regions of the log luminance ratio, less its
    median over the frames); zeros without luminance in the sweep."""
    n, _, s = data.capture.shape
    if data.capture_lum is None or data.twin_lum is None:
        return np.zeros((n, s))
    per = np.nanmedian(data.capture_lum - data.twin_lum[..., None], axis=1)  # (n, S)
    per = np.where(np.isfinite(per), per, np.nan)
    return np.nan_to_num(per - np.nanmedian(per, axis=1, keepdims=True))


def region_weights(data: ff.SweepData, d: np.ndarray) -> np.ndarray:
    """(n, R) the sweep's weights over each region's residual variance at frame focus d (n, S) (two levels of
    freedom: its level and its floor), that variance at least MIN_VARIANCE_SHARE of the median region's."""
    ss = region_ss(data.capture, twin_at(data, d))
    dof = np.maximum(np.isfinite(data.capture).sum(-1) - 2, 1)
    var = ss / dof
    used = data.weight > 0
    if not used.any():
        return data.weight
    floor = MIN_VARIANCE_SHARE * float(np.median(var[used]))
    return data.weight / np.maximum(var, max(floor, 1e-12)) * float(np.median(np.maximum(var[used], floor)))


def prepare(data: ff.SweepData, cfg: RobustConfig = RobustConfig()) -> tuple[ff.SweepData, dict]:
    """The sweep with the capture's curves corrected for each frame's exposure, each region's floor in the twin
    and each region weighted by how well its curve is determined; and a report (gains, floors, weights, the
    per-frame focus at each iteration)."""
    rep: dict = {}
    out = data
    if cfg.gains:
        g = frame_gains_log(data)
        out = dataclasses.replace(out, capture=data.capture - 2.0 * g[:, None, :])
        rep["frame_gains"] = np.exp(g).round(4).tolist()
    base = out
    d = np.asarray(data.base_d, np.float64)
    rep["frame_focus_d"] = []
    for _ in range(cfg.iterations if cfg.floors else 0):
        out = floored(base, fit_floors(base, d))
        d, prev = ff.frame_focus(out, start=d), d
        rep["frame_focus_d"].append(np.round(d, 4).tolist())
        if np.max(np.abs(d - prev)) < CONVERGED_D:
            break
    if cfg.floors:
        beta = fit_floors(base, d)
        out = floored(base, beta)
        used = data.weight > 0
        rep["floored_regions"] = float(np.mean(np.isfinite(beta)[used])) if used.any() else 0.0
    if cfg.weights:
        # weighed once the floors have settled: residuals at a wrong focus would down-weight the very regions
        # that show the error
        out = dataclasses.replace(out, weight=region_weights(out, d))
        d = ff.frame_focus(out, start=d)
        rep["frame_focus_d"].append(np.round(d, 4).tolist())
        w = out.weight[data.weight > 0]
        rep["weight_spread"] = [round(float(np.quantile(w, q)), 3) for q in (0.1, 0.5, 0.9)] if w.size else []
    return out, rep


def fit_robust(sweep: ff.SweepData, n_boot: int = 50, seed: int = 0, cfg: RobustConfig = RobustConfig()
               ) -> tuple[ff.MetadataFit, dict]:
    """The focus-metadata fit (`focusfit.fit_metadata`) on the sweep made robust (`prepare`), without the frames
    whose expected focus measure is mostly noise: where the sweep carries the noise by its expectation, every
    frame's noise share at its per-frame estimate (`focusfit.noise_share`, from the twin alone); frames at or over
    `focusfit.NOISE_DOMINATED_SHARE` are left out (`focusfit.without_frames`), the sweep prepared again without
    them, and they get no estimate of their own, only the family's value with its error (issue 32: scene 2038's
    nearest frames, 95-110 % noise, read a 4 % misfit of the noise level as their +-0.4 D bound). Returns the fit
    and `prepare`'s report."""
    data, robust = prepare(sweep, cfg)
    est = np.asarray(robust["frame_focus_d"][-1]) if robust.get("frame_focus_d") else np.asarray(sweep.base_d)
    share = ff.noise_share(data, est)
    dom = (share >= ff.NOISE_DOMINATED_SHARE) & (sweep.frames > 0)
    if dom.any():  # their curves are the floor's: they would drive the family too
        data, robust = prepare(ff.without_frames(sweep, dom), cfg)
        # null where a frame was kept (not NaN: diagnosis.json is strict JSON)
        robust["noise_dominated_at_d"] = [[round(float(x), 4) if d else None for x, d in zip(e, m)]
                                          for e, m in zip(np.asarray(est, np.float64), dom)]
    return ff.fit_metadata(data, n_boot=n_boot, seed=seed, excluded=dom, share=share), robust
