"""Where the phone's tile bias against the render-consistent truth comes from (issue 33; docs/calibration.md,
"The tiles' bias against the render truth, and the fit's own
error").

    OMP_NUM_THREADS=1 python -m benchmarks.probes.tile_bias --truth results/render_truth_map_cellphone.json \
        [--variants nominal,copy] [--renders 0.1,0.07] [--until 22:40] --out results/tile_bias.json

A counted tile's bias is its object (D, from the sensor plane) minus the truth's in-focus object at the tile for the
frame where its focus curve peaked (`phone_map_budget`'s definition: what a fit through the tile reads minus the
truth). The truth is a render-truth map (`benchmarks/render_truth_map.py`: where the runtime's measure peaks on flat
planes of photographs, square to the camera, noise-free, per annulus, in the benchmark's renderer). Each candidate
cause is changed alone, on bench_calibrate's `cellphone_near` development sweeps (the nominal lens, the hand-chosen
copy, the declared random copies of seed 2026; no held-out scene), and the bias is reported by field radius:

- **distance**: the tile's object as fitted (the tape's distance, or the fit's for the near chart `~`) minus its
  object as rendered (the mean of 1/depth over the tile's pixels in the rendered scene): the charts' distances and
  the markers' pose; the rest, **measurement** = rendered object minus the truth, is what the tile's peak does;
- **field position**: the truth read at the tile's measure-weighted centroid (the measure at the tile's sharpest
  frame) instead of its centre;
- **frame spacing**: the same sweeps with every other frame (1.1 D steps, both phases): an interpolation bias of the
  peak estimator grows as the step squared;
- **tile size**: tiles of 54 px instead of 27 (the truth's photo blocks are 64 px);
- **pooling**: per sweep, truth annulus (width 0.05) and 0.1 D bin of rendered object, the counted tiles' curves
  averaged and one peak found, as the truth pools its annulus, against the mean of the tiles' own peaks;
- **renders** (`--renders`, the nominal lens only, rendered here and cached under cache/tile_bias/): the chart
  sweeps again without noise; without noise and with depth layers 4 x finer (`shoot(layer_blur_px=0.25)`: the
  layered renderer splits a pixel's light between two depth layers about 1 px of blur apart, while the truth's flat
  planes fall on one layer); without noise with frames twice as dense (0.27 D: the estimator's interpolation);
  and without noise with the chart square to the camera (one depth, one layer). Paired tile by tile against the
  cached noisy sweep of the same chart (the square chart's tiles see other objects: not paired).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks import ROOT

CACHE = ROOT / "cache" / "tile_bias"
VARIANTS = ("nominal", "copy", "copy_s2026_0", "copy_s2026_1", "copy_s2026_2")
EDGES = (0.0, 0.33, 0.5, 0.66, 0.75, 0.84, 0.92)  # bench_calibrate's bins, to the farthest tile (0.92)
ANNULI = np.round(np.arange(0.0, 0.951, 0.05), 3)  # the render truth's annuli
POOL_D = 0.1  # pooling: tiles of one annulus within this many diopters of rendered object
RENDERS = {"noise-free": {"noise": False, "layer_blur_px": 1.0, "square": False},
           "noise-free, layers 4x finer": {"noise": False, "layer_blur_px": 0.25, "square": False},
           "noise-free, frames 2x denser": {"noise": False, "layer_blur_px": 1.0, "square": False, "step": 0.5},
           "noise-free, chart square": {"noise": False, "layer_blur_px": 1.0, "square": True}}


def _bins(r: np.ndarray, v: np.ndarray) -> dict:
    out = {}
    for lo, hi in zip(EDGES[:-1], EDGES[1:]):
        m = (r >= lo) & (r < hi if hi < EDGES[-1] else r <= hi) & np.isfinite(v)
        out[f"{lo:g}-{hi:g}"] = {"n": int(m.sum()), "mean_d": float(v[m].mean()) if m.any() else None,
                                 "sd_d": float(v[m].std()) if m.any() else None}
    ok = np.isfinite(v)
    out["all"] = {"n": int(ok.sum()), "mean_d": float(v[ok].mean()) if ok.any() else None,
                  "rms_d": float(np.sqrt(np.mean(v[ok] ** 2))) if ok.any() else None}
    return out


def rendered_scene(rig, i: int, square: bool = False):
    """(rgb (3, H, W), depth_m (H, W), layout) of the setup's chart i as bench_calibrate renders it (square: tilt 0)."""
    from aat_deploy.calibrate.pose import ChartPose
    from aat_deploy.calibrate.scene import chart_scene
    from benchmarks import bench_calibrate as B

    s = rig.setup
    d, (tx, ty) = s.distances_m[i], s.tilts[i]
    img, layout = B.chart_for(rig, d)
    rgb, depth = chart_scene(img, layout, ChartPose(d, 0.0 if square else tx, 0.0 if square else ty), rig.w, rig.h,
                             rig.f_px, rig.pupil)
    return rgb, depth, layout


def render_sweep(rig, i: int, how: dict, log) -> dict:
    """Chart i of the nominal lens rendered `how` (RENDERS), cached: bench_calibrate.sweep's dict."""
    from aat_deploy.capture.virtual import shoot
    from benchmarks import bench_calibrate as B

    step = how.get("step", 1.0)
    if step != 1.0:  # the sweep's frames `step` x as far apart (in px of blur; bench_calibrate.sweep_diopters)
        rig = rig.with_setup(dataclasses.replace(rig.setup, step_px=rig.setup.step_px * step))
    s = rig.setup
    d = s.distances_m[i]
    name = f"{s.sweep_key or s.key}_nominal_{d:g}m_step{s.step_px:g}px_soft{s.chart_soften_px:g}px" \
           f"_noise{int(how['noise'])}_layers{how['layer_blur_px']:g}px{'_square' if how['square'] else ''}.npz"
    f = CACHE / name
    rgb, depth, layout = rendered_scene(rig, i, how["square"])
    if f.is_file():
        z = np.load(f)
        return {"frames": z["frames"].astype(np.float32), "reported_m": z["reported_m"], "true_m": z["true_m"],
                "layout": layout, "distance_m": d, "inv_depth": 1.0 / depth.astype(np.float64)}
    dd = 1.0 / depth
    fd = B.sweep_diopters(rig, float(dd.max()), float(dd.min()))
    true_m = 1.0 / fd
    t0 = time.time()
    frames, reported = shoot(rig.lens, rgb * 0.6, depth, true_m, ["noise"] if how["noise"] else [], rig.src,
                             seed=1000 + i, workers=1, cell_px=s.cell_px, layer_blur_px=how["layer_blur_px"])
    log(f"  rendered {name}: {len(fd)} frames in {time.time() - t0:.0f} s")
    CACHE.mkdir(parents=True, exist_ok=True)
    from aat_deploy.io.atomic import atomic_file

    with atomic_file(f) as tmp:
        np.savez(tmp, frames=frames.astype(np.float16), reported_m=reported, true_m=true_m)
    return {"frames": frames.astype(np.float16).astype(np.float32), "reported_m": reported, "true_m": true_m,
            "layout": layout, "distance_m": d, "inv_depth": 1.0 / depth.astype(np.float64)}


class Truth:
    """The truth's in-focus object at field points for reported focus (the copy's reported distance is SCALE x the
    true one), read on phone_map_budget's focus grid."""

    def __init__(self, rig, eff: list[str], scale: float):
        self.rig, self.eff, self.scale = rig, eff, scale

    def at(self, x: np.ndarray, y: np.ndarray, reported_d: np.ndarray) -> np.ndarray:
        from benchmarks.probes import phone_map_budget as P

        t = self.rig.truth_at(self.eff, x, y, 1.0 / P.F_GRID_D)  # (F, N)
        return P.truth_at_reported(t, reported_d, self.scale)


def tiles(m, inv_depth: np.ndarray, truth: Truth, aspect: float, centroid: bool = False) -> dict:
    """Per counted tile of a SweepMeasurement: x, y, r, row, col, reported peak, object as measured and as rendered,
    the truth at the centre for the peak's frame (and at the measure-weighted centroid)."""
    from aat_deploy.calibrate.format import field_radius_of

    pk = m.peaks
    g = pk.grid
    c = pk.why == ""
    x, y = g.field()
    rows, cols = np.nonzero(c)
    out = {"x": x[c], "y": y[c], "row": rows, "col": cols, "reported_d": pk.peak_d[c], "object_d": m.object_d[c],
           "object_true_d": g.mean(inv_depth)[c], "curves": pk.curves[:, c], "frames_d": pk.reported_d}
    out["r"] = field_radius_of(out["x"], out["y"], aspect)
    out["truth_d"] = truth.at(out["x"], out["y"], out["reported_d"])
    if centroid:
        from aat_deploy.focus.measures import focus_volume

        vol = focus_volume(m.sweep.frames, "mlap2", 15.0, prefilter_px=1.0)
        row, col = g.owner()
        w = np.take_along_axis(vol, pk.sharpest[row[:, None], col[None, :]][None], 0)[0].astype(np.float64)
        h, wd = w.shape
        u, v = np.meshgrid(np.arange(wd, dtype=np.float64), np.arange(h, dtype=np.float64))
        sw = g.mean(w)
        uc, vc = g.mean(w * u) / sw, g.mean(w * v) / sw
        xc, yc = (2 * (uc + 0.5) / wd - 1)[c], (1 - 2 * (vc + 0.5) / h)[c]
        out["centroid_shift_px"] = np.hypot((xc - out["x"]) * wd / 2, (yc - out["y"]) * h / 2)
        out["truth_centroid_d"] = truth.at(xc, yc, out["reported_d"])
    return out


def pooled(t: dict, truth_fn) -> np.ndarray:
    """Per tile: its group's pooled bias (the curves of one sweep's tiles in one truth annulus and one POOL_D bin of
    rendered object averaged, one peak by the fit's estimator; each tile's rendered object minus the truth at the
    tile for that peak), NaN where the pooled curve peaks at an end or the group is one tile. A tilted chart's
    objects differ by up to 1 D around an annulus; the bin keeps the pooled curves' peaks together, as the truth's
    flat planes do."""
    from aat_deploy.focus.estimate import estimate_peak

    out = np.full(len(t["r"]), np.nan)
    k = np.clip(np.searchsorted(ANNULI, t["r"], side="right") - 1, 0, len(ANNULI) - 2)
    k = k * 100_000 + np.floor(t["object_true_d"] / POOL_D).astype(np.int64)
    s = len(t["frames_d"])
    for a in np.unique(k):
        sel = k == a
        if sel.sum() < 2:
            continue
        curve = t["curves"][:, sel].mean(1)
        p = estimate_peak(curve[:, None, None].astype(np.float32), t["frames_d"].astype(np.float32), None, "gauss")
        if p.index[0, 0] in (0, s - 1):
            continue
        f = np.full(int(sel.sum()), float(p.diopters[0, 0]))
        out[sel] = t["object_true_d"][sel] - truth_fn(t["x"][sel], t["y"][sel], f)
    return out


def _paired(a: dict, b: dict, va: np.ndarray, vb: np.ndarray) -> dict:
    """b's value minus a's, tile by tile (matched by row and column), by radius bin."""
    ka = {(int(r), int(c)): j for j, (r, c) in enumerate(zip(a["row"], a["col"]))}
    ja, jb = [], []
    for j, (r, c) in enumerate(zip(b["row"], b["col"])):
        if (int(r), int(c)) in ka:
            ja.append(ka[(int(r), int(c))])
            jb.append(j)
    ja, jb = np.array(ja, int), np.array(jb, int)
    return _bins(b["r"][jb], vb[jb] - va[ja])


def run_variant(variant: str, truth_path: str, log) -> dict:
    from aat_deploy.calibrate.sweep import measure_sweep
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT
    from benchmarks.probes import phone_map_budget as P

    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", variant)
    s = rig.setup
    eff, scale, sweeps, ms, res = P.development_fit(rig, v, log)
    truth = Truth(rig, eff, scale)
    aspect = rig.w / rig.h
    fitted = {i: m for i, m in enumerate(res.measures)}
    rng = np.random.default_rng(7)  # bench_calibrate.measures' tape draws, again
    tapes = [sw["distance_m"] + rng.normal(0, B.TAPE_SD_MM / 1000) for sw in sweeps]
    rows = {"base": [], "centroid": [], "pooled": [], "step 1.1 D": [], "54 px tiles": []}
    per_chart = []
    for i, sw in enumerate(sweeps):
        _, depth, _ = rendered_scene(rig, i)
        inv = 1.0 / depth.astype(np.float64)
        t = tiles(fitted[i], inv, truth, aspect, centroid=True)
        bias = t["object_d"] - t["truth_d"]
        dist = t["object_d"] - t["object_true_d"]
        meas = t["object_true_d"] - t["truth_d"]
        rows["base"].append(np.column_stack([t["r"], bias, dist, meas]))
        rows["centroid"].append(np.column_stack([t["r"], t["object_true_d"] - t["truth_centroid_d"],
                                                 t["centroid_shift_px"]]))
        rows["pooled"].append(np.column_stack([t["r"], pooled(t, truth.at)]))
        free = i in s.fit_distance
        for first in (0, 1):
            mm = measure_sweep(B.as_sweep(rig, sw, v, 2, first), sw["layout"], distance_m=tapes[i],
                               measure=rig.measure, prefilter_px=rig.prefilter_px, fit_distance=free)
            tt = tiles(mm, inv, truth, aspect)
            va = {(int(r), int(c)): j for j, (r, c) in enumerate(zip(t["row"], t["col"]))}
            both = [(va[(int(r), int(c))], j) for j, (r, c) in enumerate(zip(tt["row"], tt["col"]))
                    if (int(r), int(c)) in va]
            ja, jb = (np.array([p[k] for p in both], int) for k in (0, 1))
            rows["step 1.1 D"].append(np.column_stack([t["r"][ja], meas[ja],
                                                       tt["object_true_d"][jb] - tt["truth_d"][jb]]))
        mm = measure_sweep(B.as_sweep(rig, sw, v), sw["layout"], distance_m=tapes[i], measure=rig.measure,
                           prefilter_px=rig.prefilter_px, fit_distance=free, tile_px=54)
        tt = tiles(mm, inv, truth, aspect)
        rows["54 px tiles"].append(np.column_stack([tt["r"], tt["object_true_d"] - tt["truth_d"]]))
        per_chart.append({"distance_m": sw["distance_m"], "tape_m": float(tapes[i]),
                          "fitted_m": float(fitted[i].chart_distance_m), "tiles": int(len(t["r"])),
                          "bias": _bins(t["r"], bias), "distance": _bins(t["r"], dist),
                          "measurement": _bins(t["r"], meas)})
        log(f"{variant} chart {sw['distance_m']:g} m: {len(t['r'])} tiles, bias {np.mean(bias):+.3f}, distance "
            f"{np.mean(dist):+.3f}, measurement {np.mean(meas):+.3f} D")
    cat = {k: np.concatenate(v) for k, v in rows.items()}
    b, c, p, st, t54 = (cat[k] for k in ("base", "centroid", "pooled", "step 1.1 D", "54 px tiles"))
    out = {"variant": variant, "per_chart": per_chart,
           "bias": _bins(b[:, 0], b[:, 1]), "distance": _bins(b[:, 0], b[:, 2]),
           "measurement": _bins(b[:, 0], b[:, 3]),
           "measurement at the centroid": _bins(c[:, 0], c[:, 1]),
           "centroid shift px": _bins(c[:, 0], c[:, 2]),
           "measurement, annulus pooled": _bins(p[:, 0], p[:, 1]),
           "measurement, the pooled tiles' own": _bins(p[:, 0], np.where(np.isfinite(p[:, 1]), b[:, 3], np.nan)),
           "measurement, same tiles, 0.55 D": _bins(st[:, 0], st[:, 1]),
           "measurement, same tiles, 1.1 D": _bins(st[:, 0], st[:, 2]),
           "1.1 D minus 0.55 D, paired": _bins(st[:, 0], st[:, 2] - st[:, 1]),
           "measurement, 54 px tiles": _bins(t54[:, 0], t54[:, 1])}
    return out


def run_renders(charts: list[float], truth_path: str, until: str | None, log) -> dict:
    """The nominal lens's charts (distances m) rendered per RENDERS; paired against the cached noisy sweep."""
    from aat_deploy.calibrate.sweep import measure_sweep
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT

    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", "nominal")
    s = rig.setup
    truth = Truth(rig, B.effects_for(s, v), 1.0)
    aspect = rig.w / rig.h
    out = {}
    for d in charts:
        if d not in s.distances_m:
            raise SystemExit(f"tile_bias: --renders {d:g}: not a chart of cellphone_near ({s.distances_m})")
        i = s.distances_m.index(d)
        sw = B.sweep(rig, v, i, log)
        _, depth, _ = rendered_scene(rig, i)
        m0 = measure_sweep(B.as_sweep(rig, sw, v), sw["layout"], distance_m=d, measure=rig.measure,
                           prefilter_px=rig.prefilter_px)
        t0 = tiles(m0, 1.0 / depth.astype(np.float64), truth, aspect)
        meas0 = t0["object_true_d"] - t0["truth_d"]
        row = {"noisy (cached)": _bins(t0["r"], meas0)}
        for name, how in RENDERS.items():
            if until and datetime.now(timezone.utc).strftime("%H:%M") >= until:
                log(f"  --until {until}: {d:g} m {name} not rendered")
                continue
            rs = render_sweep(rig, i, how, log)
            mm = measure_sweep(B.as_sweep(rig, rs, v), rs["layout"], distance_m=d, measure=rig.measure,
                               prefilter_px=rig.prefilter_px)
            tt = tiles(mm, rs["inv_depth"], truth, aspect)
            meas = tt["object_true_d"] - tt["truth_d"]
            row[name] = _bins(tt["r"], meas)
            if not how["square"]:
                row[f"{name} minus noisy, paired"] = _paired(t0, tt, meas0, meas)
            log(f"  {d:g} m {name}: measurement {np.nanmean(meas):+.3f} D (noisy {np.mean(meas0):+.3f})")
        out[f"{d:g} m"] = row
    return out


def table(res: dict) -> str:
    keys = ("bias", "distance", "measurement", "measurement at the centroid", "measurement, annulus pooled",
            "measurement, the pooled tiles' own",
            "measurement, same tiles, 0.55 D", "measurement, same tiles, 1.1 D", "measurement, 54 px tiles")
    bins = [f"{lo:g}-{hi:g}" for lo, hi in zip(EDGES[:-1], EDGES[1:])]
    f = lambda b: "-" if b["mean_d"] is None else f"{b['mean_d']:+.3f}"
    out = ["| variant | what (mean, D of object) | " + " | ".join(bins) + " | all |", "|---" * (len(bins) + 3) + "|"]
    for r in res["rows"]:
        for k in keys:
            out.append(f"| {r['variant']} | {k} | " + " | ".join(f(r[k][b]) for b in bins) + f" | {f(r[k]['all'])} |")
    for d, row in res.get("renders", {}).items():
        for k, v in row.items():
            out.append(f"| nominal {d} | {k} | " + " | ".join(f(v[b]) for b in bins) + f" | {f(v['all'])} |")
    return "\n".join(out)


def chosen_variants(ap, text: str) -> list[str]:
    """--variants (comma-separated; '' for none) checked against VARIANTS: ap.error names any unknown one."""
    variants = [v for v in text.split(",") if v]
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        ap.error(f"--variants: {', '.join(bad)} not of {', '.join(VARIANTS)}")
    return variants


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--truth", required=True, help="a render-truth map (aat-render-truth-map-v1; a repo path)")
    ap.add_argument("--variants", default="nominal,copy", help=f"of {', '.join(VARIANTS)} ('' for none)")
    ap.add_argument("--renders", default="", help="charts (m) of the nominal lens to render again (RENDERS)")
    ap.add_argument("--until", default=None, help="UTC HH:MM: render nothing new from then")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    if Path(a.out).exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    variants = chosen_variants(ap, a.variants)
    try:
        charts = [float(v) for v in a.renders.split(",") if v]
    except ValueError:
        ap.error(f"--renders {a.renders!r}: chart distances in m, comma-separated")
    if not variants and not charts:
        ap.error("nothing to run: --variants and --renders are both empty")
    if a.until is not None:
        try:
            a.until = datetime.strptime(a.until, "%H:%M").strftime("%H:%M")  # compared as text: zero-padded
        except ValueError:
            ap.error(f"--until {a.until!r}: a UTC time as HH:MM")
    from benchmarks.render_truth_map import load_or_exit

    load_or_exit(a.truth, "tile_bias")
    log = lambda m: print(m, file=sys.stderr, flush=True)
    res = {"what": __doc__.split("\n")[0], "truth": a.truth, "command": "python -m benchmarks.probes.tile_bias "
           + " ".join(argv if argv is not None else sys.argv[1:]),
           "rows": [run_variant(v, a.truth, log) for v in variants]}
    if charts:
        res["renders"] = run_renders(charts, a.truth, a.until, log)
    write_text_atomic(a.out, json.dumps(res, indent=1, default=float))
    print(table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
