"""The phone's map error at field radius 0.66-0.92, inside the tile grid: tile-peak noise, the tiles' other errors,
where the tiles lie, the smooth model's basis and the truth's own reading (issue 33; docs/calibration.md, "The error
at field radius 0.66-0.92, split").

    OMP_NUM_THREADS=1 python -m benchmarks.probes.outer_fit --truth results/render_truth_map_cellphone_19p.json \
        [--variants nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2] [--noise-draws 6] \
        --out results/outer_fit.json

bench_calibrate's `cellphone_near` development sweeps only (the nominal lens, the hand-chosen copy and the declared
random copies 0-2 of seed 2026; no scene, held-out or not). Per variant the fit as part a makes it
(`phone_map_budget.development_fit`), and at its rule's order and family (`model.fit_family`; the charts' distances as
fitted, the same kept tiles and weights) maps from the same tiles with their (peak, object) replaced. Every map holds
the field term beyond the farthest kept tile (as the fit does) and is scored against the truth over part a's 10
"inside" settings (7-18 cm), by field radius of the pixel (0-0.66, 0.66-0.75, 0.75-0.84, 0.84 to the farthest tile).

Each chart is rendered again with the variant's effects but the sensor noise (`noise`), the same frames and seeds
(`bench_calibrate.sweep(noise=False)`, cached with the benchmark's sweeps under `_noise0` names), and its tiles'
peaks found on those frames (*clean*) and on the clean frames with --noise-draws new draws of the benchmark's noise
(Poisson-Gaussian, the `noise` effect's parameters). The map error of the measured tiles splits exactly (a
telescoping sum of maps; each difference's share of the squared error is its inner product with the total over the
total's square, so the shares add to 1):

- **noise**: measured tiles (the cached noisy peaks, their objects as fitted) minus the same tiles at the clean
  peaks: what the sensor noise does to the peaks, through the fit;
- **distance**: the clean peaks with the objects as fitted minus the same with the objects as rendered (the mean of
  1/depth over the tile: the tapes, the near chart's fitted distance);
- **measurement (clean)**: the rendered objects minus the truth's in-focus object at the tile for its clean peak
  (texture, the renderer, the estimator: what a noise-free tile's peak does);
- **where the tiles lie**: exact tiles (the truth's object at each tile for its clean peak) minus the same model
  fitted to the truth itself on a dense grid (every 16 px within the farthest tile's radius, 16 reported focus
  settings over part a's range): what the fit between and beyond the tiles costs with tiles that are right;
- **basis**: that dense fit minus the truth: what the model's form (the rule's order) cannot follow at all.

The clean measurement is split the same way into its systematic part (the tiles' mean per chart and field-radius
bin) and the scatter about it (each tile's own texture: noise-free, but random from tile to tile). The outer ring
(0.66 to the farthest tile) is also split by pixel into inside the kept tile centres' rectangle and the band outside
it, and by pixel-frame into where `measured_mask` says the in-focus object was measured and where it flags it.
Per tile by radius: the noise, the clean measurement and the distance (object D), and the in-focus object averaged
over the tile's pixels minus at its centre (a tile's peak averages a curved field; the model reads the centre).

The noise draws give the noise part's bias (their mean map minus the clean map) and its spread (the maps' RMS about
that mean); the benchmark's own draw is one more. **The truth's own reading**: the truth read linearly between its
annuli (the benchmark's) against a cubic through the four nearest (`middle_field.CubicRadial`), RMS by bin, part a's
error against each, and the map file's standard errors and interpolation check.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks import ROOT

BINS = ((0.0, 0.66), (0.66, 0.75), (0.75, 0.84), (0.84, None))  # None: the farthest kept tile's radius
PARTS = ("noise", "distance", "measurement (clean)", "where the tiles lie", "basis")
DENSE_PX, DENSE_F = 16, 16
SUB = 9  # points per tile side for its average
TILE_EDGES = (0.0, 0.33, 0.5, 0.66, 0.75, 0.84, 0.9, 1.0)  # the systematic part's radius bins


def bin_masks(prad: np.ndarray, r_max: float) -> dict:
    """{name: (H, W) bool} of BINS within r_max (the last bin ends at r_max)."""
    out = {}
    for lo, hi in BINS:
        top = r_max if hi is None else hi
        out[f"{lo:g}-{top:.3g}" if hi is None else f"{lo:g}-{hi:g}"] = (prad >= lo) & (
            (prad <= top) if hi is None else (prad < hi)) & (prad <= r_max)
    out["within"] = prad <= r_max
    return out


def split(total: np.ndarray, parts: dict, masks: dict) -> dict:
    """total (S, H, W) and parts {name: (S, H, W)} that add up to it: per mask ((H, W) pixels or (S, H, W)
    pixel-frames; empty ones left out), its share of the pixel-frames, each part's RMS, mean and share of the
    total's squared error (sum(part * total) / sum(total^2): the shares add to 1), and the total's RMS and mean.
    ValueError when the parts do not add up to the total."""
    acc = sum(parts.values())
    if not np.allclose(acc, total, atol=1e-6, rtol=0):
        raise ValueError(f"the parts do not add up to the total (max {float(np.max(np.abs(acc - total))):.3g} D)")
    out = {}
    for k, m in masks.items():
        t = total[..., m]  # (H, W) pixels of every frame, or (S, H, W) pixel-frames
        if t.size == 0:
            continue
        tt = float(np.sum(t ** 2))
        row = {"total": {"rms_d": float(np.sqrt(np.mean(t ** 2))), "mean_d": float(np.mean(t))},
               "pixel_share": float(t.size / total.size)}
        for name, p in parts.items():
            v = p[..., m]
            row[name] = {"rms_d": float(np.sqrt(np.mean(v ** 2))), "mean_d": float(np.mean(v)),
                         "share": float(np.sum(v * t) / tt) if tt > 0 else 0.0}
        out[k] = row
    return out


def clean_sweep(rig, variant: str, i: int, log) -> dict:
    """Chart i as bench_calibrate.sweep renders it (same scene, frames, seed) with the variant's effects but `noise`:
    `sweep(noise=False)`, cached as its sweeps are and checked against the lens and PSF files as they are."""
    from benchmarks import bench_calibrate as B

    return B.sweep(rig, variant, i, log, noise=False)


def peaks_on(rig, variant: str, sw: dict, frames: np.ndarray, grid) -> np.ndarray:
    """(ny, nx) the tiles' peaks (reported D; NaN where a tile does not count) on `frames` in place of sw's, found as
    `measure_sweep` finds them (every tile taken as on the chart: the kept tiles are on it)."""
    from aat_deploy.calibrate.peaks import tile_peaks
    from benchmarks import bench_calibrate as B

    sweep = B.as_sweep(rig, {**sw, "frames": frames}, variant)
    pk = tile_peaks(sweep.frames, sweep.reported_d, grid, np.ones(grid.shape, bool), rig.measure, 15.0,
                    rig.prefilter_px, "gauss")
    return pk.peak_d


def noisy(frames: np.ndarray, params: dict, seed: int) -> np.ndarray:
    """The clean frames with a new draw of the benchmark's sensor noise, stored as its sweeps are (float16)."""
    from aat_deploy.render.effects.noise import poisson_gaussian

    rng = np.random.default_rng(seed)
    out = np.stack([poisson_gaussian(f, float(params["full_well_e"]), float(params["read_noise_e"]), rng)
                    for f in frames])
    return out.astype(np.float16).astype(np.float32)


def run_variant(variant: str, truth_path: str, draws: int, log, sampling: bool = False) -> dict:
    from aat_deploy.calibrate import in_focus_diopters
    from aat_deploy.calibrate.fit import tile_rectangle
    from aat_deploy.calibrate.format import field_grid, field_radius_of, measured_mask
    from aat_deploy.calibrate.model import Observations, fit_family
    from aat_deploy.eval.stats import field_radius
    from aat_deploy.render import effects as fx
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT
    from benchmarks.probes import phone_map_budget as P
    from benchmarks.probes import tile_bias as TB
    from benchmarks.probes.corners import outside_rectangle
    from benchmarks.probes.middle_field import CubicRadial, _with

    t0 = time.time()
    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", variant)
    s = rig.setup
    eff, scale, sweeps, ms, res = P.development_fit(rig, v, log)
    truth = TB.Truth(rig, eff, scale)
    aspect = rig.w / rig.h
    obs = res.observations  # the kept tiles
    noise_fx = [e for e in fx.parse(B.effects_for(s, v)) if e.name == "noise"]
    if len(noise_fx) != 1:
        raise SystemExit(f"outer_fit: {variant}: the sweeps' effects have no single noise effect")
    params = noise_fx[0].params
    # per chart: the kept tiles' grid cells, their objects as fitted / as rendered, and their peaks: measured (the
    # cached noisy sweep, as the fit found them), clean and in each noise draw
    index = {}
    for i, m in enumerate(res.measures):
        x, y = m.peaks.grid.field()
        for r in range(x.shape[0]):
            for c in range(x.shape[1]):
                index[P.tile_key(i, x[r, c], y[r, c])] = (r, c)
    keys = [P.tile_key(*k) for k in zip(obs.sweep, obs.x, obs.y)]
    rc = np.array([index[k] for k in keys])
    n = len(obs)
    p_meas, p_clean = np.full(n, np.nan), np.full(n, np.nan)
    p_draw = np.full((draws, n), np.nan)
    o_true = np.full(n, np.nan)
    check = []
    for i, m in enumerate(res.measures):
        sel = obs.sweep == i
        rr, cc = rc[sel, 0], rc[sel, 1]
        p_meas[sel] = m.peaks.peak_d[rr, cc]
        again = peaks_on(rig, v, sweeps[i], sweeps[i]["frames"], m.peaks.grid)[rr, cc]
        check.append(float(np.nanmax(np.abs(again - p_meas[sel]))))
        cl = clean_sweep(rig, v, i, log)
        if not np.allclose(cl["reported_m"], sweeps[i]["reported_m"]):
            raise SystemExit(f"outer_fit: {variant}: chart {i}'s clean render reports other focus distances")
        p_clean[sel] = peaks_on(rig, v, cl, cl["frames"], m.peaks.grid)[rr, cc]
        for k in range(draws):
            p_draw[k, sel] = peaks_on(rig, v, cl, noisy(cl["frames"], params, 50_000 + 97 * k + i),
                                      m.peaks.grid)[rr, cc]
        _, depth, _ = TB.rendered_scene(rig, i)
        o_true[sel] = m.peaks.grid.mean(1.0 / depth.astype(np.float64))[rr, cc]
        log(f"{variant} chart {s.distances_m[i]:g} m: {int(sel.sum())} kept tiles; peaks again on the cached sweep "
            f"within {check[-1]:.2g} D; clean minus noisy peaks RMS "
            f"{float(np.sqrt(np.nanmean((p_clean[sel] - p_meas[sel]) ** 2))):.3f} D of frame")
    ok = np.isfinite(p_clean) & np.all(np.isfinite(p_draw), 0)
    od = obs.object_d
    rad = field_radius_of(obs.x, obs.y, aspect)
    r_max = float(np.max(rad))
    fam, order = res.model.focus.family, (res.model.degree, res.model.focus_degree, res.model.radial,
                                          res.model.low_focus_degree)
    inside = s.inside()
    rep_m = inside * scale
    dense = rig.truth(eff, inside).astype(np.float64)
    prad = field_radius(rig.h, rig.w)
    masks = bin_masks(prad, r_max)
    # the outer ring (0.66 to r_max) split: inside the kept tile centres' rectangle or in the band outside it (where
    # the polynomial is extrapolated in x or y), and where the calibration says it measured the in-focus object or not
    gxf, gyf = field_grid(rig.h, rig.w)
    band = outside_rectangle(gxf, gyf, tile_rectangle(obs))
    ring = (prad >= 0.66) & (prad <= r_max)
    masks["0.66-r_max, inside the tile centres' rectangle"] = ring & ~band
    masks["0.66-r_max, the band outside it"] = ring & band
    flagged = ~measured_mask(res.calibration, rep_m, rig.h, rig.w)
    masks["0.66-r_max, in-focus object measured (measured_mask)"] = ring[None] & ~flagged
    masks["0.66-r_max, in-focus object outside the charts' (flagged)"] = ring[None] & flagged
    sub = obs.subset(ok)

    def fit_map(peak, obj, o=sub, keep=None):
        ob = Observations(o.x, o.y, peak, obj, o.sweep, o.cell, o.weight, aspect=o.aspect)
        fe, fp, _ = fit_family(ob, fam, order[0], order[1], radial=order[2], low_focus_degree=order[3])
        if keep is not None:
            keep.extend([fe, fp])
        cal = dataclasses.replace(res.calibration, focus_error=fe, best_focus=fp)
        return in_focus_diopters(P.held(cal, r_max), rep_m, rig.h, rig.w).astype(np.float64)

    tr_clean = truth.at(obs.x[ok], obs.y[ok], p_clean[ok])
    m_meas = fit_map(p_meas[ok], od[ok])
    m_clean = fit_map(p_clean[ok], od[ok])
    m_clean_true = fit_map(p_clean[ok], o_true[ok])
    m_exact = fit_map(p_clean[ok], tr_clean)
    # the truth itself on a dense grid within r_max, fitted by the same order and family
    gx, gy = np.meshgrid(np.arange(DENSE_PX / 2, rig.w, DENSE_PX), np.arange(DENSE_PX / 2, rig.h, DENSE_PX))
    xs, ys = 2 * (gx.ravel() + 0.5) / rig.w - 1, 1 - 2 * (gy.ravel() + 0.5) / rig.h
    inn = field_radius_of(xs, ys, aspect) <= r_max
    xs, ys = xs[inn], ys[inn]
    rep_d = np.linspace((1 / rep_m).min(), (1 / rep_m).max(), DENSE_F)
    obj = rig.truth_at(eff, xs, ys, 1.0 / (rep_d * scale))  # (F, N)
    nf, npts = obj.shape
    sw_d = np.repeat(np.arange(nf) % 4, npts)
    o_dense = Observations(np.tile(xs, nf), np.tile(ys, nf), np.repeat(rep_d, npts), obj.ravel(), sw_d,
                           sw_d * 10_000 + np.repeat(np.arange(nf), npts), aspect=aspect)
    kept_fit: list = []
    m_dense = fit_map(o_dense.reported_d, o_dense.object_d, o_dense, kept_fit)
    dense_fe, dense_fp = kept_fit
    if sampling:
        # the basis: the dense fit at the rule's order against the same at the format's richest order (monomials to
        # degree 6, radial powers to rho^12, cubic in focus for the edge powers, quadratic for the rest)
        ob = Observations(o_dense.x, o_dense.y, o_dense.reported_d, o_dense.object_d, o_dense.sweep, o_dense.cell,
                          aspect=aspect)
        fe6, fp6, _ = fit_family(ob, fam, 6, 3, radial=12, low_focus_degree=2)
        m6 = in_focus_diopters(P.held(dataclasses.replace(res.calibration, focus_error=fe6, best_focus=fp6), r_max),
                               rep_m, rig.h, rig.w).astype(np.float64)
        basis = {name: {k: {"rms_d": float(np.sqrt(np.mean(e[..., mk] ** 2))), "mean_d": float(np.mean(e[..., mk]))}
                        for k, mk in masks.items() if mk.any()}
                 for name, e in (("the rule's order", m_dense - dense), ("6/12/3/2, the format's richest", m6 - dense))}
        return {"variant": variant, "tile_radius_max": r_max, "order": {"degree": order[0], "radial": order[2],
                                                                         "focus_degree": order[1],
                                                                         "low_focus_degree": order[3]},
                "sampling": sampling_runs(rig, eff, scale, res, sub, p_clean[ok], tr_clean, fit_map, m_dense, masks),
                "basis": basis, "seconds": time.time() - t0}
    parts = {"noise": m_meas - m_clean, "distance": m_clean - m_clean_true,
             "measurement (clean)": m_clean_true - m_exact, "where the tiles lie": m_exact - m_dense,
             "basis": m_dense - dense}
    # the clean measurement split: its systematic part (the mean per chart and radius bin of the tiles) and the
    # scatter about it (each tile's own texture under the lens's astigmatism: deterministic, but random across tiles)
    e_clean = o_true[ok] - tr_clean
    rk = rad[ok]
    sys_part = np.zeros(int(ok.sum()))
    for sw_ in np.unique(sub.sweep):
        for lo, hi in zip(TILE_EDGES[:-1], TILE_EDGES[1:]):
            g = (sub.sweep == sw_) & (rk >= lo) & (rk < hi)
            if g.any():
                sys_part[g] = e_clean[g].mean()
    m_sys = fit_map(p_clean[ok], tr_clean + sys_part)
    clean_split = {"systematic (chart x radius-bin means)": m_sys - m_exact,
                   "scatter about them": m_clean_true - m_sys}
    out = {"variant": variant, "tiles": n, "tiles_used": int(ok.sum()), "tile_radius_max": r_max,
           "order": {"degree": order[0], "focus_degree": order[1], "radial": order[2],
                     "low_focus_degree": order[3], "family": fam},
           "peaks_again_max_d": max(check), "noise_params": {k: float(val) for k, val in params.items()},
           "split": split(m_meas - dense, parts, masks),
           "measurement_clean_split": split(parts["measurement (clean)"], clean_split,
                                            {k: mk for k, mk in masks.items() if mk.any()})}
    cal_a = P.held(res.calibration, r_max)
    m_a = in_focus_diopters(cal_a, rep_m, rig.h, rig.w).astype(np.float64)
    masks = {k: mk for k, mk in masks.items() if mk.any()}
    out["part_a_fit"] = {k: {"rms_d": float(np.sqrt(np.mean((m_a - dense)[..., mk] ** 2)))} for k, mk in masks.items()}
    # the noise draws: bias (their mean map minus the clean map) and spread (about their mean); and the tiles' noise
    maps = np.stack([fit_map(p_draw[k, ok], od[ok]) - m_clean for k in range(draws)]) if draws else None
    if maps is not None:
        mean = maps.mean(0)
        spread = maps - mean
        out["noise_draws"] = {k: {"bias_rms_d": float(np.sqrt(np.mean(mean[..., mk] ** 2))),
                                  "bias_mean_d": float(np.mean(mean[..., mk])),
                                  "spread_rms_d": float(np.sqrt(np.mean(spread[..., mk] ** 2))),
                                  "benchmark_draw_rms_d": float(np.sqrt(np.mean(parts["noise"][..., mk] ** 2)))}
                              for k, mk in masks.items()}
    # per tile, by field radius: the noise (object D: truth at the clean peak minus at the noisy one, what a tile's
    # error gains), the clean measurement and the distance
    t_meas = truth.at(obs.x[ok], obs.y[ok], p_meas[ok])
    per_tile = {"noise (benchmark draw)": tr_clean - t_meas,
                "noise (draws)": np.concatenate([tr_clean - truth.at(obs.x[ok], obs.y[ok], p_draw[k, ok])
                                                 for k in range(draws)]) if draws else np.zeros(0),
                "measurement (clean)": o_true[ok] - tr_clean, "distance": od[ok] - o_true[ok]}
    # a tile's peak is where the measure averaged over its pixels peaks, the model reads its centre: the in-focus
    # object averaged over the tile's pixels (SUB x SUB points) minus at its centre, for its clean peak, on the dense
    # fit (the rule's order fitted to the truth: smooth, twice differentiable) and on the truth read linearly
    tpx = res.measures[0].peaks.grid.tile_px
    off = (np.arange(SUB) + 0.5) / SUB - 0.5  # fractions of the tile across
    dx, dy = np.meshgrid(off * 2 * tpx / rig.w, off * 2 * tpx / rig.h)
    xo, yo = obs.x[ok], obs.y[ok]
    t_on = dense_fe.true_diopters(p_clean[ok])
    at = lambda a, b: dense_fp(xo + a, yo + b, t_on)
    per_tile["tile average minus centre (the dense fit)"] = np.mean(
        [at(a, b) for a, b in zip(dx.ravel(), dy.ravel())], 0) - at(0.0, 0.0)
    d3x, d3y = np.meshgrid((np.arange(3) - 1) / 3 * 2 * tpx / rig.w, (np.arange(3) - 1) / 3 * 2 * tpx / rig.h)
    per_tile["tile average minus centre (the truth read linearly, 3 x 3)"] = np.mean(
        [truth.at(xo + a, yo + b, p_clean[ok]) for a, b in zip(d3x.ravel(), d3y.ravel())], 0) - tr_clean
    rt = rad[ok]
    out["tiles_by_radius"] = {}
    for lo, hi in BINS:
        top = r_max if hi is None else hi
        sel = (rt >= lo) & ((rt <= top) if hi is None else (rt < hi))
        row = {"n": int(sel.sum())}
        for name, e in per_tile.items():
            s_ = np.tile(sel, draws) if name == "noise (draws)" else sel
            if s_.any():
                row[name] = {"mean_d": float(e[s_].mean()), "sd_d": float(e[s_].std())}
        out["tiles_by_radius"][f"{lo:g}-{top:.3g}"] = row
    # the truth's own reading: linear between annuli (the benchmark's) against a cubic through four
    cub = _with(rig, CubicRadial(rig.truth_map)).truth(eff, inside).astype(np.float64)
    out["truth_reading"] = {k: {"linear_minus_cubic_rms_d": float(np.sqrt(np.mean((dense - cub)[..., mk] ** 2))),
                                "part_a_fit_vs_cubic_rms_d": float(np.sqrt(np.mean((m_a - cub)[..., mk] ** 2)))}
                            for k, mk in masks.items()}
    tm = json.loads((ROOT / truth_path).read_text()) if not Path(truth_path).is_absolute() else \
        json.loads(Path(truth_path).read_text())
    out["truth_map_se_by_radius"] = tm.get("se_by_radius")
    out["truth_map_interpolation_check"] = tm.get("interpolation_check")
    out["seconds"] = time.time() - t0
    w = out["split"]
    log(f"{variant}: " + "; ".join(f"{k} {w[k]['total']['rms_d']:.3f} D = " + ", ".join(
        f"{p} {100 * w[k][p]['share']:.0f} %" for p in PARTS) for k in w if k != "0-0.66") +
        f" ({out['seconds']:.0f} s)")
    return out


def plane_objects(x: np.ndarray, y: np.ndarray, obj: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """A chart's objects (D) at field points xs, ys from its tiles' (x, y, obj): a plane's inverse depth is affine in
    the image coordinates (`pose`), so an affine least-squares fit through the tiles."""
    a = np.column_stack([np.ones_like(x), x, y])
    c, *_ = np.linalg.lstsq(a, obj, rcond=None)
    return c[0] + c[1] * xs + c[2] * ys


def sampling_runs(rig, eff, scale, res, sub, peak, exact, fit_map, m_dense, masks) -> dict:
    """Where the tiles lie, with exact tiles only (no render): the same model (the rule's order and family) fitted to
    exact tiles sampled otherwise, each map minus the dense fit by bin (RMS, mean): as fitted (the kept tiles);
    with virtual charts between the real ones in object diopters (the tiles' positions of the 10 cm chart, objects
    of the same plane moved to the new distance, the peak where the truth has that object in focus: more bands of
    focus at every field point); and on a finer grid (the four charts' planes sampled at 20 and 13.5 px tile
    centres, the peaks from the truth: more field points, reaching farther)."""
    from aat_deploy.calibrate.model import Observations
    from benchmarks.probes import phone_map_budget as P

    aspect = sub.aspect
    rows = {"as fitted (the kept tiles, 27 px)": (sub, peak, exact)}
    s = rig.setup
    ref = s.distances_m.index(0.1)
    sel = sub.sweep == ref

    def exact_tiles(xs, ys, objs, sweeps):
        t = rig.truth_at(eff, xs, ys, 1.0 / P.F_GRID_D)
        pk = P.ideal_reported_d(t, objs, scale)
        ok = np.isfinite(pk)
        o = Observations(xs[ok], ys[ok], pk[ok], objs[ok], sweeps[ok], sweeps[ok] * 10_000, aspect=aspect)
        return o, pk[ok], objs[ok]

    for name, extra_m in (("plus virtual charts at 12.8, 8.3 and 6.2 cm (between the four)", (0.128, 0.083, 0.062)),
                          ("plus virtual charts at 12.8 and 8.3 cm", (0.128, 0.083))):
        xs, ys, objs, sws = [sub.x], [sub.y], [exact], [sub.sweep]
        for k, d in enumerate(extra_m):
            xs.append(sub.x[sel])
            ys.append(sub.y[sel])
            objs.append(sub.object_d[sel] * 0.1 / d)  # the 10 cm chart's plane (tilt) moved to d
            sws.append(np.full(int(sel.sum()), 100 + k))
        xv, yv, ov, sv = (np.concatenate(v) for v in (xs, ys, objs, sws))
        o, pk, ob = exact_tiles(xv[len(sub.x):], yv[len(sub.x):], ov[len(sub.x):], sv[len(sub.x):])
        allo = Observations(np.concatenate([sub.x, o.x]), np.concatenate([sub.y, o.y]),
                            np.concatenate([peak, pk]), np.concatenate([exact, ob]),
                            np.concatenate([sub.sweep, o.sweep]), np.concatenate([sub.cell, o.cell]), aspect=aspect)
        rows[name] = (allo, allo.reported_d, allo.object_d)
    for tile in (20, 13.5):
        gx, gy = np.meshgrid(np.arange(tile / 2, rig.w - tile / 2 + 1e-9, tile),
                             np.arange(tile / 2, rig.h - tile / 2 + 1e-9, tile))
        fx_, fy_ = 2 * (gx.ravel() + 0.5) / rig.w - 1, 1 - 2 * (gy.ravel() + 0.5) / rig.h
        xs, ys, objs, sws = [], [], [], []
        for sw in np.unique(sub.sweep):
            m = sub.sweep == sw
            xs.append(fx_)
            ys.append(fy_)
            objs.append(plane_objects(sub.x[m], sub.y[m], sub.object_d[m], fx_, fy_))
            sws.append(np.full(fx_.size, int(sw)))
        o, pk, ob = exact_tiles(*(np.concatenate(v) for v in (xs, ys, objs, sws)))
        rows[f"the four charts on a {tile:g} px grid (centres {tile / 2:g} px from the edges)"] = (o, pk, ob)
    out = {}
    for name, (o, pk, ob) in rows.items():
        e = fit_map(pk, ob, o) - m_dense
        out[name] = {"tiles": int(len(o)),
                     **{k: {"rms_d": float(np.sqrt(np.mean(e[..., mk] ** 2))), "mean_d": float(np.mean(e[..., mk]))}
                        for k, mk in masks.items() if mk.any()}}
    return out


def table(res: dict) -> str:
    if res["variants"] and "sampling" in res["variants"][0]:
        keys = [k for k in res["variants"][0]["sampling"]["as fitted (the kept tiles, 27 px)"] if k != "tiles"]
        return "\n".join(["| variant | exact tiles sampled | tiles | " + " | ".join(keys) + " |",
                          "|---|---|---|" + "---|" * len(keys)] + [
            f"| {v['variant']} | {n} | {r['tiles']} | " + " | ".join(f"{r[k]['rms_d']:.3f}" for k in keys) + " |"
            for v in res["variants"] for n, r in v["sampling"].items()] + [
            "", "| variant | the dense fit to the truth itself, at | " + " | ".join(keys) + " |",
            "|---|---|" + "---|" * len(keys)] + [
            f"| {v['variant']} | {n} | " + " | ".join(f"{r[k]['rms_d']:.3f}" for k in keys) + " |"
            for v in res["variants"] if "basis" in v for n, r in v["basis"].items()])
    out = ["| variant | radius | map error RMS (mean), rule's order | " + " | ".join(
        f"{p}: RMS, share" for p in PARTS) + " | part a's fit RMS |", "|---|---|---|" + "---|" * (len(PARTS) + 1)]
    for v in res["variants"]:
        for k, row in v["split"].items():
            out.append(f"| {v['variant']} | {k} | {row['total']['rms_d']:.3f} ({row['total']['mean_d']:+.3f}) | "
                       + " | ".join(f"{row[p]['rms_d']:.3f}, {100 * row[p]['share']:.0f} %" for p in PARTS)
                       + f" | {v['part_a_fit'][k]['rms_d']:.3f} |")
    out += ["", "| variant | radius | measurement (clean) RMS | its systematic part (chart x radius means): RMS, share "
            "| the scatter about them: RMS, share |", "|---|---|---|---|---|"]
    for v in res["variants"]:
        for k, row in v["measurement_clean_split"].items():
            a, b = row["systematic (chart x radius-bin means)"], row["scatter about them"]
            out.append(f"| {v['variant']} | {k} | {row['total']['rms_d']:.3f} | {a['rms_d']:.3f}, "
                       f"{100 * a['share']:.0f} % | {b['rms_d']:.3f}, {100 * b['share']:.0f} % |")
    nd = [v for v in res["variants"] if "noise_draws" in v]
    if nd:
        out += ["", "| variant | radius | noise draws: bias RMS (mean) | spread RMS | the benchmark's draw RMS | "
                "truth linear minus cubic RMS | part a's fit against the cubic reading |", "|---|---|---|---|---|---|---|"]
        for v in nd:
            for k, row in v["noise_draws"].items():
                t = v["truth_reading"][k]
                out.append(f"| {v['variant']} | {k} | {row['bias_rms_d']:.3f} ({row['bias_mean_d']:+.3f}) | "
                           f"{row['spread_rms_d']:.3f} | {row['benchmark_draw_rms_d']:.3f} | "
                           f"{t['linear_minus_cubic_rms_d']:.3f} | {t['part_a_fit_vs_cubic_rms_d']:.3f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    from benchmarks.probes.tile_bias import chosen_variants
    from benchmarks.render_truth_map import load_or_exit

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--truth", required=True, help="a render-truth map (aat-render-truth-map-v1; a repo path)")
    ap.add_argument("--variants", default="nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2")
    ap.add_argument("--noise-draws", type=int, default=6, help="new draws of the sensor noise per chart")
    ap.add_argument("--sampling", action="store_true", help="only where the tiles lie, with exact tiles sampled "
                    "otherwise (virtual charts between the real ones; finer grids): `sampling_runs`; and the basis "
                    "at the rule's order against the format's richest (the dense fit to the truth itself)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    if a.noise_draws < 0:
        ap.error(f"--noise-draws {a.noise_draws}: 0 or more")
    if Path(a.out).exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    variants = chosen_variants(ap, a.variants)
    if not variants:
        ap.error("nothing to run: --variants is empty")
    load_or_exit(a.truth, "outer_fit")
    log = lambda m: print(m, file=sys.stderr, flush=True)
    res = {"what": __doc__.split("\n")[0], "truth": a.truth,
           "command": "python -m benchmarks.probes.outer_fit " + " ".join(argv if argv is not None else sys.argv[1:]),
           "variants": [run_variant(v, a.truth, a.noise_draws, log, a.sampling) for v in variants]}
    write_text_atomic(a.out, json.dumps(res, indent=1, default=float))
    print(table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
