"""The phone's middle field (field radius 0.33-0.5): model misfit or tile measurement, and what the measurement's
-0.025 D is (issue 33; docs/calibration.md, "The middle field's bias, and radial powers beyond rho^12").

    OMP_NUM_THREADS=1 python -m benchmarks.probes.middle_field --truth results/render_truth_map_cellphone_19p.json \
        [--variants nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2] \
        [--alt "name=results/map.json;..."] [--square-planes 5,6,...,18 --square-draws 6] [--renders 0.07,0.1] \
        --out results/middle_field.json

bench_calibrate's `cellphone_near` development sweeps only (the nominal lens, the hand-chosen copy and the declared
random copies of seed 2026; no scene, held-out or not). Every diopter is of object (1/m, distances from the sensor
plane) unless it says frame.

1. **The map split** (per variant). The fit as part a makes it (`fit_calibration`: outlier pass, the near chart's
   fitted distance, the blend), and at its rule's order and family (`model.fit_family`, the distances fixed as
   fitted) the same kept tiles with their objects replaced: each tile keeps its position and measured peak
   (reported focus), and its object is
   - *exact*: the truth's in-focus object at the tile for the frame of its peak (`--truth`);
   - *exact + distance*: plus the tile's object as fitted minus its object as rendered (the mean of 1/depth over the
     tile's pixels in the rendered scene: the tape, the near chart's fitted distance);
   - *exact + measurement*: plus the rendered object minus the truth (what the tile's peak does);
   - *exact + measurement at 0.33-0.5 only*; and the measured tiles with the 0.33-0.5 measurement's mean (per chart)
     taken out of the tiles there.
   The objects add up (measured = exact + distance + measurement), and at one order and family the fit is nearly
   linear in them, so the maps' errors split. Each map (the field term held beyond the farthest kept tile) is scored
   against the truth over part a's 10 "inside" settings (7-18 cm), within the farthest tile's radius, by field
   radius: RMS and mean (map minus truth).
2. **The measurement against other rulers** (per variant, the same tiles): the rendered object minus each `--alt`
   truth map (`benchmarks/render_truth_map.py`) at the tile for its peak, and minus the `--truth` map read with a
   cubic through the four nearest annuli instead of linearly between two (the ruler's radial reading).
3. **Square planes** (`--square-planes`, the nominal lens): flat planes of the chart's softened dead leaves, square to
   the camera, rendered noise-free as `render_truth` renders its planes (same frames, same seeds as its `leaves`
   draws, 64 px PSF cells), with the measure averaged both over the fit's 27 px tiles and over the truth's annuli.
   Per tile: its peak against the same renders' annulus peak at its radius (linear between annulus mids; frame D:
   tiles against annuli, the same texture, frames and render), and the plane minus the `--truth` map at the tile
   for its peak (object D: the tile measurement of part 2 without the chart's tilt, noise and marker layout).
   Cached under cache/middle_field/.
4. **The chart's renders** (`--renders`, the nominal lens's charts, m): each chart as swept (noisy, bench_calibrate's
   cache) and as `tile_bias --renders` rendered it again (noise-free; depth layers 4 x finer; frames twice as dense;
   the chart square to the camera; its cache, rendered when missing), the counted tiles' measurement against
   `--truth` and each `--alt`, read linearly and by the cubic: which of the chart sweeps' differences from the
   square noise-free planes carries what is left once the texture and the ruler's reading are taken out.
5. With `--alt`: each alt map's annuli against `--truth` at the same frames (`annuli_against`), and every map's
   radial reading checked on its own points (`radial_check`).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks import ROOT
from benchmarks.probes.tile_bias import EDGES, _bins  # tile_bias's radius bins, to the farthest tile (0.92)

CACHE = ROOT / "cache" / "middle_field"
MIDDLE = (0.33, 0.5)
TILE_PX = 27  # the fit's tiles on the phone's 640 x 480 (bench_calibrate)


class CubicRadial:
    """A render-truth map read with a cubic through the four nearest annuli (Lagrange, at the annuli's mid radii)
    instead of linearly between the two around the radius; the map's own reading along focus and beyond its
    annuli."""

    def __init__(self, m):
        self.m = m

    def evaluate(self, radius, frame_d) -> tuple[np.ndarray, np.ndarray]:
        """(object_d, measured): the cubic reading, and where the map says its points bracket the point."""
        return self.object_d(radius, frame_d), self.m.evaluate(radius, frame_d)[1]

    def object_d(self, radius, frame_d) -> np.ndarray:
        radius = np.asarray(radius, np.float64).ravel()
        frame_d = np.asarray(frame_d, np.float64).ravel()
        radius, frame_d = (v.ravel() for v in np.broadcast_arrays(radius, frame_d))
        out = self.m.object_d(radius, frame_d)
        R = self.m.radius
        k = np.clip(np.searchsorted(R, radius) - 2, 0, R.size - 4)  # the four annuli around the radius
        inner = (radius >= R[1]) & (radius <= R[-2])
        for j in np.unique(k[inner]):
            m = inner & (k == j)
            rs = R[j:j + 4]
            vals = np.stack([self.m._annulus(j + i, frame_d[m])[0] for i in range(4)])
            w = np.ones((4, int(m.sum())))
            for a in range(4):
                for b in range(4):
                    if a != b:
                        w[a] *= (radius[m] - rs[b]) / (rs[a] - rs[b])
            out[m] = (w * vals).sum(0)
        return out


class Mean:
    """The mean of truth maps (each with `object_d`)."""

    def __init__(self, maps):
        self.maps = maps

    def object_d(self, radius, frame_d) -> np.ndarray:
        return np.mean([m.object_d(radius, frame_d) for m in self.maps], 0)


def radial_check(m) -> dict:
    """Each interior annulus's own points predicted from the other annuli at their frames (object D, prediction minus
    point), by field radius: linearly from the two neighbours (0.05 either side: twice the spacing a reading between
    mids has at most) and by the cubic through the four nearest others (0.05 and 0.1 either side), where all of
    them hold the frame between their points. Signed: a reading that lies above the renders shows as a positive
    mean."""
    R = m.radius
    lin, cub, rr = [], [], []
    for k in range(2, R.size - 2):
        f, o = m.frame[k], m.object[k]
        vals, ins = zip(*(m._annulus(j, f) for j in (k - 2, k - 1, k + 1, k + 2)))
        ok = np.all(ins, 0)
        lin.append((0.5 * (vals[1] + vals[2]) - o)[ok])
        cub.append((-vals[0] / 6 + 2 * vals[1] / 3 + 2 * vals[2] / 3 - vals[3] / 6 - o)[ok])
        rr.append(np.full(int(ok.sum()), R[k]))
    rr, lin, cub = (np.concatenate(v) for v in (rr, lin, cub))
    return {"linear from the two neighbours": _bins(rr, lin), "cubic from the four nearest others": _bins(rr, cub)}


def annuli_against(m, truth, frame_range=(1 / 0.18, 1 / 0.07)) -> dict:
    """Per annulus of map m (another render truth): its points (frame, plane) against `truth` read at the same
    annulus's mid radius for the same frame: plane minus truth (object D: what a tile peaking where m's texture or
    frames peak reads against `truth`), mean over the points whose frame lies in part a's inside range (7-18 cm)."""
    out = {}
    for k, r in enumerate(m.radius):
        f, o = m.frame[k], m.object[k]
        sel = (f >= frame_range[0]) & (f <= frame_range[1])
        if sel.any():
            d = o[sel] - truth.object_d(np.full(int(sel.sum()), r), f[sel])
            out[f"{r:.3f}"] = {"n": int(sel.sum()), "mean_d": float(d.mean()), "sd_d": float(d.std())}
    return out


def _truth(rig, eff, scale, tmap):
    from benchmarks.probes.tile_bias import Truth

    r = copy.copy(rig)
    r.truth_map = tmap
    return Truth(r, eff, scale)


def run_variant(variant: str, truth_path: str, alts: dict, log) -> dict:
    from aat_deploy.calibrate import in_focus_diopters
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import Observations, fit_family
    from aat_deploy.eval.stats import field_radius
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT
    from benchmarks.probes import phone_map_budget as P
    from benchmarks.probes import tile_bias as TB
    from benchmarks.render_truth_map import load

    t0 = time.time()
    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", variant)
    s = rig.setup
    eff, scale, sweeps, ms, res = P.development_fit(rig, v, log)
    truth = TB.Truth(rig, eff, scale)
    aspect = rig.w / rig.h
    obs = res.observations  # the tiles the outlier pass kept
    per = {}
    for i, m in enumerate(res.measures):  # as fitted: the near chart's tiles at its fitted distance
        _, depth, _ = TB.rendered_scene(rig, i)
        t = TB.tiles(m, 1.0 / depth.astype(np.float64), truth, aspect)
        for j in range(len(t["x"])):
            per[P.tile_key(i, t["x"][j], t["y"][j])] = (t["object_d"][j], t["object_true_d"][j], t["truth_d"][j])
    keys = [P.tile_key(*k) for k in zip(obs.sweep, obs.x, obs.y)]
    missing = [k for k in keys if k not in per]
    if missing:
        raise SystemExit(f"middle_field: {variant}: {len(missing)} kept tiles not among the measured ones")
    od, otrue, tr = (np.array([per[k][c] for k in keys]) for c in range(3))
    if not np.allclose(od, obs.object_d, atol=1e-9):
        raise SystemExit(f"middle_field: {variant}: the kept tiles' objects differ from the measured ones")
    rad = field_radius_of(obs.x, obs.y, aspect)
    e_dist, e_meas = od - otrue, otrue - tr
    mid = (rad >= MIDDLE[0]) & (rad < MIDDLE[1])
    mid_mean = np.zeros(len(obs))
    for sw in np.unique(obs.sweep):
        sel = mid & (obs.sweep == sw)
        mid_mean[sel] = e_meas[sel].mean()
    objects = {"measured tiles": od, "exact tiles": tr, "exact + distance": tr + e_dist,
               "exact + measurement": tr + e_meas, "exact + measurement at 0.33-0.5 only": tr + np.where(mid, e_meas, 0),
               "measured, 0.33-0.5 measurement's mean (per chart) taken out": od - mid_mean}
    fam, order = res.model.focus.family, (res.model.degree, res.model.focus_degree, res.model.radial,
                                          res.model.low_focus_degree)
    r_max = float(np.max(rad))
    inside = s.inside()
    rep_m = inside * scale
    dense = rig.truth(eff, inside).astype(np.float64)  # (S, H, W)
    prad = field_radius(rig.h, rig.w)
    within = prad <= r_max

    def score(pred):
        e = pred.astype(np.float64) - dense
        out = {"within_rms_d": float(np.sqrt(np.mean(e[:, within] ** 2)))}
        for lo, hi in zip(EDGES[:-1], EDGES[1:]):
            m = (prad >= lo) & (prad < hi) & within
            out[f"{lo:g}-{hi:g}"] = {"rms_d": float(np.sqrt(np.mean(e[:, m] ** 2))), "mean_d": float(e[:, m].mean())}
        return out

    maps = {"as fitted (part a's fit)": score(in_focus_diopters(P.held(res.calibration, r_max), rep_m, rig.h, rig.w))}
    for name, o in objects.items():
        ob = Observations(obs.x, obs.y, obs.reported_d, o, obs.sweep, obs.cell, obs.weight, aspect=obs.aspect)
        fe, fp, _ = fit_family(ob, fam, order[0], order[1], radial=order[2], low_focus_degree=order[3])
        cal = dataclasses.replace(res.calibration, focus_error=fe, best_focus=fp)
        maps[f"{name} (the rule's order)"] = score(in_focus_diopters(P.held(cal, r_max), rep_m, rig.h, rig.w))
    meas_against = lambda m: _bins(rad, otrue - _truth(rig, eff, scale, m).at(obs.x, obs.y, obs.reported_d))
    rulers = {"--truth": _bins(rad, e_meas), "--truth, read cubic in radius": meas_against(CubicRadial(rig.truth_map))}
    loaded = {k: load(p) for k, p in alts.items()}
    for k, m in loaded.items():
        rulers[k] = meas_against(m)
        rulers[f"{k}, read cubic in radius"] = meas_against(CubicRadial(m))
    names = list(loaded)
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            mm = [loaded[names[a]], loaded[names[b]]]
            rulers[f"mean of {names[a]} and {names[b]}"] = meas_against(Mean(mm))
            rulers[f"mean of {names[a]} and {names[b]}, read cubic in radius"] = meas_against(
                Mean([CubicRadial(m) for m in mm]))
    per_chart = {}
    for sw in np.unique(obs.sweep):
        sel = obs.sweep == sw
        per_chart[f"{s.distances_m[int(sw)]:g} m"] = {"measurement": _bins(rad[sel], e_meas[sel]),
                                                      "distance": _bins(rad[sel], e_dist[sel])}
    out = {"variant": variant, "tiles": int(len(obs)), "order": {"degree": order[0], "focus_degree": order[1],
           "radial": order[2], "low_focus_degree": order[3], "family": fam}, "tile_radius_max": r_max,
           "distance": _bins(rad, e_dist), "measurement": _bins(rad, e_meas), "per_chart": per_chart,
           "maps": maps, "rulers": rulers, "seconds": time.time() - t0}
    fitted, exact = maps["as fitted (part a's fit)"], maps["exact tiles (the rule's order)"]
    log(f"{variant}: middle field map {fitted['0.33-0.5']['mean_d']:+.4f}, exact tiles "
        f"{exact['0.33-0.5']['mean_d']:+.4f}, measurement there {out['measurement']['0.33-0.5']['mean_d']:+.4f} D "
        f"({time.time() - t0:.0f} s)")
    return out


def _lagrange4(xs: np.ndarray, ys: np.ndarray, x: np.ndarray) -> np.ndarray:
    """ys(x) by a cubic through the four nearest of the ascending xs (linear where fewer than four)."""
    if xs.size < 4:
        return np.interp(x, xs, ys)
    k = np.clip(np.searchsorted(xs, x) - 2, 0, xs.size - 4)
    out = np.zeros(x.shape)
    for a in range(4):
        w = np.ones(x.shape)
        for b in range(4):
            if a != b:
                w *= (x - xs[k + b]) / (xs[k + a] - xs[k + b])
        out += w * ys[k + a]
    return out


def square_draw(od: float, seed: int, log) -> dict:
    """One square plane of the chart's leaves at od (render_truth's `leaves` draw `seed`, its frames and renderer):
    the measure's mean per annulus (R, S) and per 27 px tile (S, ny, nx), cached."""
    from benchmarks.probes import render_truth as RT

    setup = RT.Setup(texture="leaves")
    path = CACHE / f"{setup.key()}_od{od:.3f}_s{seed}.npz"
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    from aat_deploy.calibrate.peaks import TileGrid
    from aat_deploy.focus import FocusConfig
    from aat_deploy.focus.measures import focus_volume
    from benchmarks.probes.truth_renderer import render

    t0 = time.time()
    lens = RT._lens(setup)
    h, w = lens.sensor.height_px, lens.sensor.width_px
    fd = RT.frames_d(setup, od)
    rgb = np.ascontiguousarray(np.repeat(RT.texture(setup, h, w, od, seed)[None], 3, 0) * 0.6, np.float32)
    fr = render(f"shoot{setup.cell_px}", lens, rgb, 1.0 / od, 1.0 / fd, ROOT / setup.psf)
    cfg = FocusConfig()
    vol = focus_volume(fr / max(float(fr.max()), 1e-12), cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px)
    rings = RT.ring_means(vol, setup.r_edges)
    tiles = TileGrid(h, w, TILE_PX).mean(vol)
    d = {"frames_d": fd, "rings": rings, "tiles": tiles}
    CACHE.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **d)
    tmp.replace(path)
    log(f"  square plane {od:g} D draw {seed}: {time.time() - t0:.1f} s")
    return d


def square_planes(planes: list[float], draws: int, truth_path: str, log) -> dict:
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.peaks import TileGrid
    from aat_deploy.focus.estimate import estimate_peak
    from benchmarks.probes import render_truth as RT
    from benchmarks.render_truth_map import load

    setup = RT.Setup(texture="leaves")
    lens = RT._lens(setup)
    h, w = lens.sensor.height_px, lens.sensor.width_px
    g = TileGrid(h, w, TILE_PX)
    tx, ty = g.field()
    trad = field_radius_of(tx, ty, w / h).ravel()
    edges = np.asarray(setup.r_edges)
    mids = 0.5 * (edges[:-1] + edges[1:])
    tmap = load(truth_path)
    rows = {"r": [], "tile_minus_annulus_frame_d": [], "tile_minus_annulus_cubic_frame_d": [],
            "plane_minus_truth_d": [], "annulus_minus_truth_d": [],
            "annulus_r": [], "plane_d": []}
    for od in planes:
        ds = [square_draw(od, s, log) for s in range(1, draws + 1)]
        fd = ds[0]["frames_d"]
        rings = np.sum([d["rings"] for d in ds], 0)  # (R, S)
        tiles = np.sum([d["tiles"] for d in ds], 0)  # (S, ny, nx)
        fa = RT.peaks(fd, rings)  # (R,) frame D, the truth's estimator
        pk = estimate_peak(tiles.astype(np.float32), fd.astype(np.float32), None, "gauss")
        ft = pk.diopters.astype(np.float64).ravel()
        inner = (pk.index.ravel() > 0) & (pk.index.ravel() < len(fd) - 1)
        ok_a = np.isfinite(fa)
        fa_t = np.interp(trad, mids[ok_a], fa[ok_a])  # the annulus peak at the tile's radius, linear between mids
        fa_c = _lagrange4(mids[ok_a], fa[ok_a], trad)  # and cubic through the four nearest annuli
        ok = inner & np.isfinite(fa_t) & (trad >= mids[ok_a][0]) & (trad <= mids[ok_a][-1])
        rows["r"].append(trad[ok])
        rows["tile_minus_annulus_frame_d"].append((ft - fa_t)[ok])
        rows["tile_minus_annulus_cubic_frame_d"].append((ft - fa_c)[ok])
        rows["plane_minus_truth_d"].append(od - tmap.object_d(trad[ok], ft[ok]))
        rows["plane_d"].append(np.full(int(ok.sum()), od))
        rows["annulus_r"].append(mids[ok_a])
        rows["annulus_minus_truth_d"].append(od - tmap.object_d(mids[ok_a], fa[ok_a]))
    cat = {k: np.concatenate(v) for k, v in rows.items()}
    return {"planes_d": planes, "draws": draws, "texture": "leaves (render_truth's, the chart's softened dead leaves)",
            "tiles_minus_annuli_frame_d": _bins(cat["r"], cat["tile_minus_annulus_frame_d"]),
            "tiles_minus_annuli_cubic_frame_d": _bins(cat["r"], cat["tile_minus_annulus_cubic_frame_d"]),
            "tiles_minus_truth_d": _bins(cat["r"], cat["plane_minus_truth_d"]),
            "annuli_minus_truth_d": _bins(cat["annulus_r"], cat["annulus_minus_truth_d"]),
            "by_plane_middle": {f"{od:g}": {
                "tiles_minus_annuli_frame_d": float(np.mean(cat["tile_minus_annulus_frame_d"][
                    (cat["plane_d"] == od) & (cat["r"] >= MIDDLE[0]) & (cat["r"] < MIDDLE[1])])),
                "tiles_minus_truth_d": float(np.mean(cat["plane_minus_truth_d"][
                    (cat["plane_d"] == od) & (cat["r"] >= MIDDLE[0]) & (cat["r"] < MIDDLE[1])]))}
                for od in planes}}


def renders(charts: list[float], truth_path: str, alts: dict, log) -> dict:
    """The nominal lens's charts as swept (noisy, the cache of bench_calibrate) and as `tile_bias` rendered them again
    (its RENDERS: noise-free; finer depth layers; frames twice as dense; the chart square), their counted tiles'
    measurement (rendered object minus a ruler at the tile for its peak) against --truth and the --alt maps, each
    read linearly and by the cubic in radius."""
    from aat_deploy.calibrate.sweep import measure_sweep
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT
    from benchmarks.probes import tile_bias as TB
    from benchmarks.render_truth_map import load

    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", "nominal")
    s = rig.setup
    eff = B.effects_for(s, v)
    aspect = rig.w / rig.h
    maps = {"--truth": rig.truth_map, **{k: load(p) for k, p in alts.items()}}
    rulers = {}
    for k, m in maps.items():
        rulers[k] = TB.Truth(_with(rig, m), eff, 1.0)
        rulers[f"{k}, read cubic in radius"] = TB.Truth(_with(rig, CubicRadial(m)), eff, 1.0)
    rows = {}
    for d in charts:
        if d not in s.distances_m:
            raise SystemExit(f"middle_field: --renders {d:g}: not a chart of cellphone_near ({s.distances_m})")
        i = s.distances_m.index(d)
        sw = B.sweep(rig, v, i, log)
        _, depth, _ = TB.rendered_scene(rig, i)
        hows = {"noisy (as swept)": (sw, 1.0 / depth.astype(np.float64))}
        for name, how in TB.RENDERS.items():
            rs = TB.render_sweep(rig, i, how, log)
            hows[name] = (rs, rs["inv_depth"])
        for name, (sweep, inv) in hows.items():
            m = measure_sweep(B.as_sweep(rig, sweep, v), sweep["layout"], distance_m=d, measure=rig.measure,
                              prefilter_px=rig.prefilter_px)
            t = TB.tiles(m, inv, rulers["--truth"], aspect)
            for rk, ru in rulers.items():
                meas = t["object_true_d"] - ru.at(t["x"], t["y"], t["reported_d"])
                rows.setdefault(name, {}).setdefault(rk, []).append(np.column_stack([t["r"], meas]))
        log(f"  {d:g} m: {len(hows)} renders measured")
    out = {}
    for name, per in rows.items():
        out[name] = {rk: _bins(np.concatenate(v)[:, 0], np.concatenate(v)[:, 1]) for rk, v in per.items()}
    return {"charts_m": charts, "lens": "nominal", "measurement": out}


def part_a_rulers(variant: str, truth_path: str, log) -> dict:
    """Part a of the fit as part a makes it (`bench_calibrate.map_errors`, inside) against --truth read as the
    benchmark reads it (linearly between annuli) and read by the cubic through four annuli (`CubicRadial`): how much
    of part a is the ruler's radial reading. Not a change of the benchmark's truth."""
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT
    from benchmarks.probes import phone_map_budget as P

    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", variant)
    eff, _, _, _, res = P.development_fit(rig, v, log)
    inside = rig.setup.inside()
    keys = ("rms_d", "p95_d", "within_tiles_rms_d", "radius_rms_d")
    out = {}
    for name, r in (("linear, the benchmark's", rig), ("cubic in radius", _with(rig, CubicRadial(rig.truth_map)))):
        e = B.map_errors(r, res.calibration, eff, inside)["calibration"]
        out[name] = {k: e[k] for k in keys if k in e}
    lin = out["linear, the benchmark's"]
    log(f"{variant}: part a {lin['rms_d']:.4f} D read linearly, "
        f"{out['cubic in radius']['rms_d']:.4f} D read by the cubic")
    return out


def _with(rig, tmap):
    r = copy.copy(rig)
    r.truth_map = tmap
    return r


def table(res: dict) -> str:
    bins = [f"{lo:g}-{hi:g}" for lo, hi in zip(EDGES[:-1], EDGES[1:])]
    out = ["| variant | map (mean / RMS of map minus truth, D) | within | " + " | ".join(bins) + " |",
           "|---|---|---|" + "---|" * len(bins)]
    for v in res.get("variants", []):
        for k, m in v["maps"].items():
            out.append(f"| {v['variant']} | {k} | {m['within_rms_d']:.4f} | "
                       + " | ".join(f"{m[b]['mean_d']:+.3f} / {m[b]['rms_d']:.3f}" for b in bins) + " |")
    out += ["", "| variant | tile measurement against (mean, D) | " + " | ".join(bins) + " | all |",
            "|---|---|" + "---|" * (len(bins) + 1)]
    f = lambda b: "-" if b["mean_d"] is None else f"{b['mean_d']:+.3f}"
    for v in res.get("variants", []):
        for k, b in {"distance (fitted minus rendered object)": v["distance"], **v["rulers"]}.items():
            out.append(f"| {v['variant']} | {k} | " + " | ".join(f(b[x]) for x in bins) + f" | {f(b['all'])} |")
    for k, c in res.get("radial_check", {}).items():
        out += ["", f"| {k}: each annulus's points from the others (mean, D) | " + " | ".join(bins) + " | all |",
                "|---|" + "---|" * (len(bins) + 1)]
        for kk, b in c.items():
            out.append(f"| {kk} | " + " | ".join(f(b[x]) for x in bins) + f" | {f(b['all'])} (RMS {b['all']['rms_d']:.3f}) |")
    ann = res.get("annuli_against_truth", {})
    if ann:
        radii = list(next(iter(ann.values())))
        out += ["", "| each annulus's points against --truth at the same frame (mean, D) | " + " | ".join(radii) + " |",
                "|---|" + "---|" * len(radii)]
        for k, a in ann.items():
            out.append(f"| {k} | " + " | ".join(f"{a[x]['mean_d']:+.3f}" if x in a else "-" for x in radii) + " |")
    if "renders" in res:
        out += ["", "| nominal chart renders: tile measurement against (mean, D) | " + " | ".join(bins) + " | all |",
                "|---|" + "---|" * (len(bins) + 1)]
        for name, per in res["renders"]["measurement"].items():
            for rk, b in per.items():
                out.append(f"| {name}; {rk} | " + " | ".join(f(b[x]) for x in bins) + f" | {f(b['all'])} |")
    if "square" in res:
        sq = res["square"]
        out += ["", "| square leaves planes (nominal, noise-free) | " + " | ".join(bins) + " | all |",
                "|---|" + "---|" * (len(bins) + 1)]
        for k in ("tiles_minus_annuli_frame_d", "tiles_minus_annuli_cubic_frame_d", "tiles_minus_truth_d",
                  "annuli_minus_truth_d"):
            out.append(f"| {k} | " + " | ".join(f(sq[k][x]) for x in bins) + f" | {f(sq[k]['all'])} |")
    return "\n".join(out)


def main(argv=None) -> int:
    from benchmarks.probes.tile_bias import chosen_variants
    from benchmarks.render_truth_map import load, load_or_exit

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--truth", required=True, help="a render-truth map (aat-render-truth-map-v1; a repo path)")
    ap.add_argument("--variants", default="nominal,copy", help="bench_calibrate's cellphone_near development variants "
                    "('' for none)")
    ap.add_argument("--alt", default="", help="other rulers for the measurement: name=map;name=map")
    ap.add_argument("--square-planes", default="", help="square leaves planes (object D) to render, the nominal lens")
    ap.add_argument("--square-draws", type=int, default=6)
    ap.add_argument("--part-a", action="store_true", help="with --variants: part a against --truth read linearly "
                    "and by the cubic in radius (instead of the split)")
    ap.add_argument("--renders", default="", help="the nominal lens's charts (m) measured as swept and as tile_bias "
                    "rendered them again (its cache; rendered when missing)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    if Path(a.out).exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    variants = chosen_variants(ap, a.variants)
    alts = {}
    for item in (v for v in a.alt.split(";") if v.strip()):
        if "=" not in item:
            ap.error(f"--alt {item!r}: name=path")
        k, p = item.split("=", 1)
        load_or_exit(p.strip(), "middle_field")
        alts[k.strip()] = p.strip()
    try:
        planes = [float(v) for v in a.square_planes.split(",") if v]
    except ValueError:
        ap.error(f"--square-planes {a.square_planes!r}: object diopters, comma-separated")
    try:
        charts = [float(v) for v in a.renders.split(",") if v]
    except ValueError:
        ap.error(f"--renders {a.renders!r}: chart distances in m, comma-separated")
    if not variants and not planes and not alts and not charts:
        ap.error("nothing to run: --variants, --square-planes, --alt and --renders are all empty")
    load_or_exit(a.truth, "middle_field")
    log = lambda m: print(m, file=sys.stderr, flush=True)
    res = {"what": __doc__.split("\n")[0], "truth": a.truth, "alts": alts,
           "command": "python -m benchmarks.probes.middle_field " + " ".join(argv if argv is not None else sys.argv[1:]),
           "variants": [] if a.part_a else [run_variant(v, a.truth, alts, log) for v in variants]}
    if a.part_a:
        res["part_a"] = {v: part_a_rulers(v, a.truth, log) for v in variants}
    res["radial_check"] = {k: radial_check(load(p)) for k, p in {"--truth": a.truth, **alts}.items()}
    res["annuli_against_truth"] = {k: annuli_against(load(p), load(a.truth)) for k, p in alts.items()}
    if planes:
        res["square"] = square_planes(planes, a.square_draws, a.truth, log)
    if charts:
        res["renders"] = renders(charts, a.truth, alts, log)
    write_text_atomic(a.out, json.dumps(res, indent=1, default=float))
    print(table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
