"""What the phone's chart calibration error is made of (issue 33, part a: 0.210 D RMS on the copy against 0.02 D):
the fit, the tiles, the truth's definition and the corners no tile sees, each measured on bench_calibrate's own
phone sweeps and fit.

    OMP_NUM_THREADS=1 python -m benchmarks.probes.phone_map_budget [--variants nominal,copy] [--setup cellphone] \
        [--truth-map results/cellphone_map_crop16.json] [--out results/phone_map_budget.json]   # 1-3 min, sweeps cached

Per variant (bench_calibrate's phone setup, 64 px anchors, its sweeps from cache/calibrate/):

- **measured**: the fit on the measured tiles, exactly part a's (`bench_calibrate.fit`);
- **ideal tiles**: the same counted tiles (positions, objects, sweeps, outliers dropped as the fit dropped them),
  each peaking exactly where the truth puts its object in focus (`Rig.truth_at`): the fit's own error (field model
  order, interpolation between tiles, extrapolation beyond them), with no measurement in it;
- **ideal tiles, every chart tile**: also the tiles the sweeps left unbracketed (their peak beyond the sweep): what
  tiles in the corners would buy;
- **the tiles' bias**: each measured tile against the truth: the tile's object minus the truth's in-focus object at
  the tile for the frame of its measured peak (D of object: what a fit through the tile reads minus the truth, the
  sign of the map's error), by field radius: the chart's rendering, texture and the measure, which no fit removes;
- **held beyond the tiles**: either fit with its field term held along the radius beyond the farthest counted tile
  (the stored calibration's `field_radius_max`), instead of extrapolated;
- **the truth's definition** (with --truth-map): the same fits scored against a second truth map (e.g. the one
  calibrated on 16 px crops instead of 64, `aat-lens focus-map --calibrate-crop-px 16`), and the RMS of the two
  truths' difference.

Errors are RMS over the pixels and the 10 reported focus settings of part a's "inside" (the charts' range), split
into pixels **covered** (inside the convex hull of the counted tiles' centres, over all sweeps) and **beyond** (the
corners), and by field radius (bench_calibrate's bins).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks import RESULTS

F_GRID_D = np.round(np.arange(0.5, 19.99 + 1e-9, 0.01), 6)  # true focus (D) searched for a tile's ideal peak (the focus table: 5 cm)


def ideal_reported_d(t: np.ndarray, object_d: np.ndarray, scale: float) -> np.ndarray:
    """(N,) the reported focus (D) at which the truth t (F, N) over true focus F_GRID_D has each tile's object in
    focus: the first crossing (NaN when the object is never in focus over F_GRID_D)."""
    out = np.full(len(object_d), np.nan)
    for j, o in enumerate(object_d):
        col = t[:, j]
        k = int(np.argmax(col >= o))
        if col[k] >= o and k > 0 and col[k] > col[k - 1]:
            out[j] = F_GRID_D[k - 1] + (o - col[k - 1]) / (col[k] - col[k - 1]) * (F_GRID_D[k] - F_GRID_D[k - 1])
    return out / scale  # reported distance = scale x true: reported diopters = true / scale


def truth_at_reported(t: np.ndarray, reported_d: np.ndarray, scale: float) -> np.ndarray:
    """(N,) the truth's in-focus object at each tile for a frame reporting reported_d (its true focus scale x)."""
    return np.array([np.interp(r * scale, F_GRID_D, t[:, j]) if np.isfinite(r) else np.nan
                     for j, r in enumerate(reported_d)])


def tile_table(res, rig, effects, scale) -> dict:
    """Every on-chart textured tile of every sweep: x, y, object_d, sweep, cell, counted, measured reported_d."""
    cols = {k: [] for k in ("x", "y", "object_d", "sweep", "counted", "reported_d", "frames_d")}
    for i, m in enumerate(res.sweeps_measured):
        pk = m.peaks
        keep = (pk.why == "") | (pk.why == "unbracketed")
        x, y = pk.grid.field()
        cols["x"].append(x[keep])
        cols["y"].append(y[keep])
        cols["object_d"].append(m.object_d[keep])
        cols["sweep"].append(np.full(int(keep.sum()), i))
        cols["counted"].append((pk.why == "")[keep])
        cols["reported_d"].append(pk.peak_d[keep])
        cols["frames_d"].append([pk.reported_d] * int(keep.sum()))
    out = {k: (np.concatenate(v) if k != "frames_d" else sum(v, [])) for k, v in cols.items()}
    out["truth_f"] = rig.truth_at(effects, out["x"], out["y"], 1.0 / F_GRID_D)  # (F, N), rising along F
    out["ideal_d"] = ideal_reported_d(out["truth_f"], out["object_d"], scale)
    return out


def observations_of(tiles: dict, keep: np.ndarray, reported: np.ndarray, aspect: float):
    from aat_deploy.calibrate.model import Observations

    idx = np.flatnonzero(keep)
    cell = np.array([tiles["sweep"][j] * 10_000 + int(np.clip(np.searchsorted(tiles["frames_d"][j], reported[j]), 0,
                                                                 len(tiles["frames_d"][j]))) for j in idx], np.int64)
    return Observations(tiles["x"][idx], tiles["y"][idx], reported[idx], tiles["object_d"][idx],
                        tiles["sweep"][idx].astype(np.int64), cell, aspect=aspect)


def tile_key(sweep, x, y) -> tuple:
    """A tile's identity across `tile_table` and the fit's observations: its sweep and field position."""
    return int(sweep), round(float(x), 6), round(float(y), 6)


def kept_tiles(tiles: dict, obs) -> np.ndarray:
    """(N,) bool over `tile_table`'s tiles: counted and kept by the fit (its outlier pass dropped some; `obs`, the
    fit's observations, matched by sweep and position)."""
    kept = {tile_key(*v) for v in zip(obs.sweep, obs.x, obs.y)}
    return np.array([bool(tiles["counted"][j]) and tile_key(tiles["sweep"][j], tiles["x"][j], tiles["y"][j]) in kept
                     for j in range(len(tiles["x"]))], dtype=bool)


def covered_mask(x, y, h: int, w: int) -> np.ndarray:
    """(H, W) pixels inside the convex hull of tile centres x, y (normalised field)."""
    from scipy.spatial import Delaunay

    from aat_deploy.calibrate.format import field_grid

    gx, gy = field_grid(h, w)
    tri = Delaunay(np.column_stack([x, y]), qhull_options="QJ")
    return tri.find_simplex(np.column_stack([gx.ravel(), gy.ravel()])).reshape(h, w) >= 0


def observed_mask(obs, reported_d: np.ndarray, h: int, w: int, step: int = 4) -> np.ndarray:
    """(S, H, W) pixel-frames inside the convex hull of the counted tiles' (x, y, reported focus): where the
    surface D(x, y, F) was measured. A chart shows objects of a few diopters' range; under strong field curvature
    the edge of a frame focused near has a nearer object in focus than any chart showed there, and the field term
    there is extrapolated in focus though the frame lies inside the calibrated on-axis range. Computed every
    step px."""
    from scipy.spatial import Delaunay

    from aat_deploy.calibrate.format import field_grid

    gx, gy = field_grid(h, w)
    gx, gy = gx[::step, ::step], gy[::step, ::step]
    tri = Delaunay(np.column_stack([obs.x, obs.y, obs.reported_d]), qhull_options="QJ")
    out = []
    for r in reported_d:
        pts = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, r)])
        m = (tri.find_simplex(pts) >= 0).reshape(gx.shape)
        out.append(np.repeat(np.repeat(m, step, 0), step, 1)[:h, :w])
    return np.stack(out)


def errors(pred: np.ndarray, truth: np.ndarray, covered: np.ndarray, observed: np.ndarray | None = None) -> dict:
    from aat_deploy.eval.stats import field_radius
    from benchmarks.bench_calibrate import RADIUS_EDGES

    h, w = truth.shape[1:]
    rad = field_radius(h, w)
    d = pred - truth
    rms = lambda m: float(np.sqrt(np.mean(d[:, m] ** 2))) if m.any() else None
    bins = {f"{lo:g}-{hi:g}": (rad >= lo) & (rad < hi if hi < 1 else rad <= hi)
            for lo, hi in zip(RADIUS_EDGES[:-1], RADIUS_EDGES[1:])}
    ex = {}
    if observed is not None:
        ex = {"observed_rms_d": float(np.sqrt(np.mean(d[observed] ** 2))) if observed.any() else None,
              "unobserved_rms_d": float(np.sqrt(np.mean(d[~observed] ** 2))) if (~observed).any() else None,
              "observed_share": float(observed.mean())}
    return {"rms_d": float(np.sqrt(np.mean(d ** 2))), "covered_rms_d": rms(covered), "beyond_rms_d": rms(~covered),
            **ex, "radius_rms_d": {k: rms(m) for k, m in bins.items()},
            "radius_mean_d": {k: float(np.mean(d[:, m])) for k, m in bins.items()}}


def held(cal, radius_max: float):
    """The calibration with its field term held along the radius beyond radius_max (`FieldPoly.radius_max`)."""
    w, h = cal.size_px
    return dataclasses.replace(cal, best_focus=dataclasses.replace(cal.best_focus, radius_max=float(radius_max),
                                                                   aspect=w / h))


def extrapolated(cal):
    """The calibration with its field term extrapolated everywhere (no radius_max)."""
    return dataclasses.replace(cal, best_focus=dataclasses.replace(cal.best_focus, radius_max=None))


def development_fit(rig, variant: str, log) -> tuple:
    """(effects, the reported focus's scale, sweeps, measured sweeps, fit) of `variant` (bench_calibrate's names:
    nominal or copy) on `rig`'s setup: its cached sweeps measured with the tapes and fitted as part a fits them,
    without the bootstrap."""
    from aat_deploy.calibrate.fit import fit_calibration
    from benchmarks import bench_calibrate as B

    eff = B.effects_for(rig.setup, variant)
    scale = B.SCALE if any(e.startswith("focus_metadata") for e in eff) else 1.0
    sweeps = [B.sweep(rig, variant, i, log) for i in range(len(rig.setup.distances_m))]
    ms = B.measures(rig, sweeps, variant)
    return eff, scale, sweeps, ms, fit_calibration(ms, n_boot=0)


def run_variant(rig, variant: str, truths: dict, log, keep: dict | None = None) -> dict:
    """keep: a dict that receives the measured fit (`fit_calibration`'s result) under "fit" (probes/chart_texture)."""
    from aat_deploy.calibrate import in_focus_diopters
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import fit_model
    from benchmarks import bench_calibrate as B

    s = rig.setup
    eff, scale, sweeps, ms, res = development_fit(rig, variant, log)
    if keep is not None:
        keep["fit"] = res
    res.sweeps_measured = res.measures  # as fitted: a chart whose distance the fit found has its tiles' objects there
    obs = res.observations  # after the fit's outlier pass
    tiles = tile_table(res, rig, eff, scale)
    aspect = rig.w / rig.h
    fit_kept = kept_tiles(tiles, obs)
    ok_ideal = np.isfinite(tiles["ideal_d"])
    inside = s.inside()
    rep_m = inside * scale
    covered = covered_mask(obs.x, obs.y, rig.h, rig.w)
    observed = observed_mask(obs, 1.0 / rep_m, rig.h, rig.w)
    r_max = float(np.max(field_radius_of(obs.x, obs.y, obs.aspect)))
    fits = {"measured": extrapolated(res.calibration)}
    info = {"measured": {"tiles": int(len(obs)), "degree": res.model.degree, "radial": res.model.radial,
                         "focus_degree": res.model.focus_degree, "family": res.calibration.focus_error.family}}
    for name, keep in (("ideal tiles", fit_kept & ok_ideal),
                       ("ideal tiles, every chart tile", ok_ideal)):
        o = observations_of(tiles, keep, tiles["ideal_d"], aspect)
        m = fit_model(o)
        fits[name] = dataclasses.replace(res.calibration, focus_error=m.focus, best_focus=m.field)
        info[name] = {"tiles": int(len(o)), "degree": m.degree, "radial": m.radial, "focus_degree": m.focus_degree,
                      "family": m.focus.family, "residual_rms_d": float(np.sqrt(np.mean(m.residual_d ** 2)))}
        log(f"  {variant} {name}: {len(o)} tiles, order {m.degree}/{m.radial}/{m.focus_degree}, {m.focus.family}")
    fits["measured, held beyond the tiles"] = held(res.calibration, r_max)
    fits["ideal tiles, held beyond the tiles"] = held(fits["ideal tiles"], r_max)
    out = {"variant": variant, "fits": info, "tile_radius_max": r_max, "covered_share": float(covered.mean()),
           "scores": {}}
    for tname, fmap in truths.items():
        truth = _with_map(rig, fmap).truth(eff, inside)
        out["scores"][tname] = {k: errors(in_focus_diopters(c, rep_m, rig.h, rig.w), truth, covered, observed)
                                for k, c in fits.items()}
    out["observed_share"] = float(observed.mean())
    # the tiles' bias: the tile's object minus the truth's in-focus object at the tile for its measured peak's frame
    # (what a fit through the tile reads minus the truth: the sign of the map's error)
    c = tiles["counted"] & fit_kept
    xs, ys, od = tiles["x"][c], tiles["y"][c], tiles["object_d"][c]
    bias = od - truth_at_reported(tiles["truth_f"][:, c], tiles["reported_d"][c], scale)
    rad = field_radius_of(xs, ys, aspect)
    edges = B.RADIUS_EDGES
    out["tile_bias"] = {f"{lo:g}-{hi:g}": {"n": int(np.sum(sel := (rad >= lo) & (rad < hi if hi < 1 else rad <= hi))),
                                           "mean_d": float(np.mean(bias[sel])) if sel.any() else None,
                                           "sd_d": float(np.std(bias[sel])) if sel.any() else None}
                        for lo, hi in zip(edges[:-1], edges[1:])}
    out["tile_bias_rms_d"] = float(np.sqrt(np.mean(bias ** 2)))
    un = ~tiles["counted"]
    out["unbracketed"] = {"n": int(un.sum()), "of": int(len(un)),
                          "radius": [float(v) for v in np.quantile(field_radius_of(tiles["x"][un], tiles["y"][un],
                                                                                   aspect), [0, 0.5, 1])]
                          if un.any() else None,
                          "per_sweep": [int(np.sum(un & (tiles["sweep"] == i))) for i in range(len(sweeps))]}
    if len(truths) > 1:
        names = list(truths)
        t0 = _with_map(rig, truths[names[0]]).truth(eff, inside)
        t1 = _with_map(rig, truths[names[1]]).truth(eff, inside)
        out["truths_differ"] = errors(t1, t0, covered, observed)
    return out


def _with_map(rig, path):
    import copy

    from aat_deploy.focus.bestfocus import load_json
    from benchmarks.bench_calibrate import ROOT

    if path is None:
        return rig
    r = copy.copy(rig)
    r.fmap = load_json(ROOT / path)
    return r


def main(argv=None) -> int:
    from benchmarks import bench_calibrate as B

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", default="nominal,copy")
    ap.add_argument("--setup", default="cellphone", help="bench_calibrate's setup (cellphone_near: a fourth chart at "
                    "5.5 cm)")
    ap.add_argument("--truth-map", default=None, help="a second truth map scored beside the lens's (a repo path)")
    ap.add_argument("--out", default=str(RESULTS / "phone_map_budget.json"))
    a = ap.parse_args(argv)
    log = lambda m: print(m, file=sys.stderr, flush=True)
    rig = B.Rig(B.LENSES[a.setup])
    truths = {"lens map (64 px crops)": None}
    if a.truth_map:
        truths[Path(a.truth_map).stem] = a.truth_map
    res = {"setup": a.setup, "distances_m": list(rig.setup.distances_m), "truths": {k: v or "lenses/best_focus/cellphone_asphere.json" for k, v in truths.items()},
           "variants": [run_variant(rig, v, truths, log) for v in a.variants.split(",")]}
    from aat_deploy.io.atomic import write_text_atomic

    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(a.out), json.dumps(res, indent=1, default=float))
    print(table(res))
    return 0


def table(res: dict) -> str:
    out = []
    for v in res["variants"]:
        out.append(f"\n{v['variant']}: counted tiles reach field radius {v['tile_radius_max']:.3f}; "
                   f"{100 * v['covered_share']:.1f} % of the pixels inside their hull, {100 * v['observed_share']:.1f} % "
                   f"of the pixel-frames inside their (x, y, F) hull; unbracketed "
                   f"{v['unbracketed']['n']} of {v['unbracketed']['of']} chart tiles (per sweep "
                   f"{v['unbracketed']['per_sweep']}, radius {v['unbracketed']['radius']}); tiles' bias RMS "
                   f"{v['tile_bias_rms_d']:.3f} D")
        for tname, sc in v["scores"].items():
            out.append(f"\nagainst {tname}:\n")
            bins = list(next(iter(sc.values()))["radius_rms_d"])
            out.append("| fit | RMS (D) | covered (x, y) | beyond | observed (x, y, F) | not observed | "
                       + " | ".join(bins) + " |")
            out.append("|---|---|---|---|---|---|" + "---|" * len(bins))
            for k, e in sc.items():
                cells = [f"{e['radius_rms_d'][b]:.3f} ({e['radius_mean_d'][b]:+.2f})" for b in bins]
                beyond = "-" if e["beyond_rms_d"] is None else f"{e['beyond_rms_d']:.3f}"
                nob = "-" if e.get("unobserved_rms_d") is None else f"{e['unobserved_rms_d']:.3f}"
                out.append(f"| {k} | {e['rms_d']:.3f} | {e['covered_rms_d']:.3f} | {beyond} | "
                           f"{e['observed_rms_d']:.3f} | {nob} | " + " | ".join(cells) + " |")
        if "truths_differ" in v:
            e = v["truths_differ"]
            out.append(f"\nthe two truths differ by {e['rms_d']:.3f} D RMS (covered {e['covered_rms_d']:.3f}, "
                       f"observed {e['observed_rms_d']:.3f})")
        out.append("\ntiles' bias (D of object, measured against the truth), by field radius: " + ", ".join(
            f"{k} {b['mean_d']:+.3f} (SD {b['sd_d']:.3f}, n {b['n']})" for k, b in v["tile_bias"].items() if b["n"]))
    return "\n".join(out)


if __name__ == "__main__":
    raise SystemExit(main())
