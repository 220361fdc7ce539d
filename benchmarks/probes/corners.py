"""Why the phone's map is 0.44 D off beyond the farthest tile (field radius 0.92; issue 33; docs/calibration.md,
"The corners beyond the farthest tile").

    OMP_NUM_THREADS=1 python -m benchmarks.probes.corners --truth results/render_truth_map_cellphone_19p.json \
        [--variants nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2] [--beyond linear] \
        --out results/corners.json

bench_calibrate's `cellphone_near` development sweeps only (the nominal lens, the hand-chosen copy and the declared
random copies of seed 2026; no scene, held-out or not), fitted as part a fits them (`phone_map_budget.development_fit`).
Per variant:

1. **Where the tiles reach**: the fit's tile grid (its farthest centre's field radius and the border no tile
   covers), and per chart sweep the codes of the tiles beyond radius 0.84 and of the four corner tiles (counted,
   off the chart, flat, unbracketed), the farthest counted and kept tile, and the kept tiles' reported focus and
   objects beyond radius 0.84 (which frames measure the edge, and at which objects).
2. **What part a and the depth schedule count there**: the pixels beyond the farthest kept tile's radius (r_max), their
   share of the pixels and of the squared error, and that error split along each pixel's ray: the map at a pixel p
   beyond r_max is the field term at q, the point of radius r_max on p's ray (`FieldPoly.radius_max`: held), so
   map(p) - truth(p) = [map(q) - truth(q)] - [truth(p) - truth(q)]: the map's own error at the edge it holds
   (*edge*) minus what the truth rises beyond it (*rise*, what holding cannot follow). By frame, for part a's 10
   "inside" settings (7-18 cm) and the depth schedule's 8 (0.07-0.5 m). Also where the truth is itself
   extrapolated there (the render truth beyond its last annulus, 0.925: the base map's shape with its correction
   held).
3. **Part b's outer field** (field radius > 0.66, `aat_deploy.eval.stats.zone_masks`): the share of its pixels
   beyond r_max.
4. With `--beyond MODE` (`FieldPoly.beyond`, e.g. linear: continued to first order along the radius): the same fit
   scored both ways, paired (the fit is the same; only the field term beyond r_max differs): part a as part a
   scores it (`bench_calibrate.map_errors`, inside and on the depth schedule) and section 2's split, with the
   continuation (the map at p minus the map at q) beside it. `--beyond rectangle` (held at the nearest point of the
   kept tile centres' rectangle, `fit.tile_rectangle`) also changes pixels within r_max but outside that rectangle
   (the *band*): both ways, its share of the pixels and its error are in `band` (held: the polynomial there).
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

EDGE_R = 0.84  # the tiles "at the edge" (bench_calibrate's outermost bins)


def ray_points(x: np.ndarray, y: np.ndarray, aspect: float, r_max: float) -> tuple[np.ndarray, np.ndarray]:
    """(xq, yq): each normalised field point moved along its ray from the centre to field radius r_max, where it
    lies beyond (unchanged inside): the point whose field term a held calibration uses."""
    from aat_deploy.calibrate.format import field_radius_of

    r = field_radius_of(x, y, aspect)
    s = np.where(r > r_max, r_max / np.maximum(r, 1e-300), 1.0)
    return x * s, y * s


def outside_rectangle(x: np.ndarray, y: np.ndarray, rect) -> np.ndarray:
    """bool: normalised field points outside the rectangle (x_lo, x_hi, y_lo, y_hi), its edges inside."""
    x0, x1, y0, y1 = rect
    return (x < x0) | (x > x1) | (y < y0) | (y > y1)


def split_along_rays(pred_p: np.ndarray, pred_q: np.ndarray, truth_p: np.ndarray, truth_q: np.ndarray) -> dict:
    """(S, N) maps and truths at N pixels p beyond r_max and at their points q on r_max: the error, the map's error at
    the edge it holds (edge = pred_q - truth_q) and the truth's rise beyond it (rise = truth_p - truth_q), RMS and
    mean, overall and per frame. error = pred_p - truth_p; for a held field term pred_p = pred_q and
    error = edge - rise exactly."""
    e, edge, rise, cont = pred_p - truth_p, pred_q - truth_q, truth_p - truth_q, pred_p - pred_q
    st = lambda v: {"rms_d": float(np.sqrt(np.mean(v ** 2))), "mean_d": float(np.mean(v))}
    return {"error": st(e), "edge": st(edge), "rise": st(rise), "continuation": st(cont),
            "per_frame": [{"error": st(e[i]), "edge": st(edge[i]), "rise": st(rise[i]), "continuation": st(cont[i])}
                          for i in range(len(e))]}


def tile_reach(ms: list, obs, distances_m, aspect: float) -> dict:
    """Per sweep: the tile grid's farthest centre, the codes beyond EDGE_R and at the four corner tiles, the farthest
    counted and kept tile, and the kept tiles' reported focus and objects beyond EDGE_R."""
    from aat_deploy.calibrate.format import field_radius_of

    out = []
    for i, m in enumerate(ms):
        pk = m.peaks
        x, y = pk.grid.field()
        r = field_radius_of(x, y, aspect)
        ny, nx = r.shape
        codes = lambda sel: {c or "counted": int(n) for c, n in zip(*np.unique(pk.why[sel], return_counts=True))}
        k = obs.sweep == i
        rk = field_radius_of(obs.x[k], obs.y[k], aspect)
        edge = rk > EDGE_R
        counted = pk.why == ""
        out.append({"distance_m": float(distances_m[i]), "grid": [int(ny), int(nx)],
                    "tile_px": int(pk.grid.tile_px), "farthest_centre_r": float(r.max()),
                    "border_px": [int(pk.grid.starts[0][0]), int(pk.grid.starts[1][0])],
                    "corner_tiles": {f"{a}{b}": (pk.why[j, c] or "counted") for a, j in (("top", 0), ("bottom", -1))
                                     for b, c in (("left", 0), ("right", -1))},
                    "beyond_edge_r": codes(r > EDGE_R),
                    "counted_r_max": float(r[counted].max()) if counted.any() else None,
                    "kept_r_max": float(rk.max()) if k.any() else None,
                    "kept_beyond_edge_r": int(edge.sum()),
                    "kept_reported_d_beyond_edge_r": [float(obs.reported_d[k][edge].min()),
                                                      float(obs.reported_d[k][edge].max())] if edge.any() else None,
                    "kept_object_d_beyond_edge_r": [float(obs.object_d[k][edge].min()),
                                                    float(obs.object_d[k][edge].max())] if edge.any() else None})
    return {"sweeps": out}


def beyond_split(rig, cal, eff: list[str], true_m: np.ndarray, scale: float, rect=None) -> dict:
    """Section 2 for frames truly focused at true_m (reported scale x): part a's error beyond r_max and its split;
    with rect (the tile centres' rectangle), the error in the band within r_max but outside it."""
    from aat_deploy.calibrate import in_focus_diopters
    from aat_deploy.calibrate.format import field_grid, field_radius_of
    from benchmarks.bench_calibrate import map_errors

    h, w = rig.h, rig.w
    fp = cal.best_focus
    r_max, aspect = fp.radius_max, fp.aspect
    rep = true_m * scale
    x, y = field_grid(h, w)
    r = field_radius_of(x, y, aspect)
    beyond = r > r_max
    pred = in_focus_diopters(cal, rep, h, w).astype(np.float64)  # (S, H, W)
    truth = rig.truth(eff, true_m).astype(np.float64)
    xp, yp = x[beyond], y[beyond]
    xq, yq = ray_points(xp, yp, aspect, r_max)
    tp = rig.truth_at(eff, xp, yp, true_m)  # (S, N)
    tq = rig.truth_at(eff, xq, yq, true_m)
    on_axis = cal.focus_error.true_diopters(1.0 / rep)
    pq = on_axis[:, None] + dataclasses.replace(fp, beyond="held", rectangle=None)(xq, yq, on_axis)  # the map at q
    e = pred - truth
    out = {"frames_true_m": [float(v) for v in true_m], "r_max": float(r_max),
           "beyond_share": float(beyond.mean()), "rms_d": float(np.sqrt(np.mean(e ** 2))),
           "within_rms_d": float(np.sqrt(np.mean(e[:, ~beyond] ** 2))),
           "beyond_sq_share": float(np.sum(e[:, beyond] ** 2) / np.sum(e ** 2)),
           "truth_at_matches_truth_d": float(np.max(np.abs(tp - truth[:, beyond]))),
           "map_at_q_matches_map_d": float(np.max(np.abs(pq - pred[:, beyond])))}  # held: 0 (float32 aside)
    keys = ("rms_d", "p95_d", "within_tiles_rms_d", "beyond_tiles_rms_d", "radius_rms_d")
    out["part_a"] = {k: v for k, v in map_errors(rig, cal, eff, true_m)["calibration"].items() if k in keys}
    out.update(split_along_rays(pred[:, beyond], pq, tp, tq))
    if rect is not None:
        band = outside_rectangle(x, y, rect) & ~beyond
        eb = e[:, band]
        out["band"] = {"rectangle": [float(v) for v in rect], "share": float(band.mean()),
                       "sq_share": float(np.sum(eb ** 2) / np.sum(e ** 2)),
                       "rms_d": float(np.sqrt(np.mean(eb ** 2))), "mean_d": float(np.mean(eb))}
    ok = rig.truth_measured(eff, true_m)
    if ok is not None:
        out["truth_extrapolated_share_beyond"] = float(1.0 - ok[:, beyond].mean())
    return out


def run_variant(variant: str, truth_path: str, beyond: str | None, log) -> dict:
    from aat_deploy.calibrate.fit import tile_rectangle
    from aat_deploy.eval.stats import field_radius, zone_masks
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT
    from benchmarks.probes import phone_map_budget as P

    t0 = time.time()
    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", variant)
    eff, scale, _, _, res = P.development_fit(rig, v, log)
    cal = res.calibration
    s = rig.setup
    fp = cal.best_focus
    outer = zone_masks(rig.h, rig.w)["outer"]
    beyond_px = field_radius(rig.h, rig.w) > fp.radius_max  # square pixels: the same radius as the fit's
    rect = tile_rectangle(res.observations) if beyond == "rectangle" else None
    out = {"variant": variant,
           "order": {"degree": res.model.degree, "radial": res.model.radial, "focus_degree": res.model.focus_degree,
                     "family": cal.focus_error.family},
           "reach": tile_reach(res.measures, res.observations, s.distances_m, fp.aspect),
           "part_a_inside": beyond_split(rig, cal, eff, s.inside(), scale, rect),
           "schedule": beyond_split(rig, cal, eff, s.schedule(), scale, rect),
           "part_b_outer_beyond_share": float(beyond_px[outer].mean())}
    a = out["part_a_inside"]
    log(f"{variant}: r_max {a['r_max']:.3f}; beyond {100 * a['beyond_share']:.1f} % of pixels, "
        f"{100 * a['beyond_sq_share']:.0f} % of the squared error; error {a['error']['rms_d']:.3f} "
        f"(mean {a['error']['mean_d']:+.3f}) = edge {a['edge']['mean_d']:+.3f} - rise {a['rise']['mean_d']:+.3f} D")
    if beyond is not None:
        c = dataclasses.replace(cal, best_focus=dataclasses.replace(fp, beyond=beyond, rectangle=rect))
        out["beyond"] = {"mode": beyond, "part_a_inside": beyond_split(rig, c, eff, s.inside(), scale, rect),
                         "schedule": beyond_split(rig, c, eff, s.schedule(), scale, rect)}
        b = out["beyond"]
        log(f"{variant}: part a inside {a['part_a']['rms_d']:.4f} held -> {b['part_a_inside']['part_a']['rms_d']:.4f} "
            f"{beyond}; schedule {out['schedule']['part_a']['rms_d']:.4f} -> {b['schedule']['part_a']['rms_d']:.4f} D")
    out["seconds"] = time.time() - t0
    return out


def table(res: dict) -> str:
    out = ["| variant | r_max | beyond: pixels / squared error | error RMS (mean) | edge RMS (mean) | rise RMS (mean) "
           "| schedule: error / edge / rise RMS | outer field beyond |", "|---|---|---|---|---|---|---|---|"]
    for v in res["variants"]:
        a, sc = v["part_a_inside"], v["schedule"]
        out.append(f"| {v['variant']} | {a['r_max']:.3f} | {100 * a['beyond_share']:.1f} % / "
                   f"{100 * a['beyond_sq_share']:.0f} % | {a['error']['rms_d']:.3f} ({a['error']['mean_d']:+.3f}) | "
                   f"{a['edge']['rms_d']:.3f} ({a['edge']['mean_d']:+.3f}) | {a['rise']['rms_d']:.3f} "
                   f"({a['rise']['mean_d']:+.3f}) | {sc['error']['rms_d']:.3f} / {sc['edge']['rms_d']:.3f} / "
                   f"{sc['rise']['rms_d']:.3f} | {100 * v['part_b_outer_beyond_share']:.1f} % |")
    rows = [v for v in res["variants"] if "beyond" in v]
    if rows:
        out += ["", f"| variant | part a inside: held -> {rows[0]['beyond']['mode']} (RMS, D) | beyond the tiles' radius "
                "| within | schedule | beyond, error mean: held -> mode |", "|---|---|---|---|---|---|"]
        for v in rows:
            h, b = v["part_a_inside"], v["beyond"]["part_a_inside"]
            hs, bs = v["schedule"], v["beyond"]["schedule"]
            out.append(f"| {v['variant']} | {h['part_a']['rms_d']:.4f} -> {b['part_a']['rms_d']:.4f} | "
                       f"{h['part_a']['beyond_tiles_rms_d']:.3f} -> {b['part_a']['beyond_tiles_rms_d']:.3f} | "
                       f"{h['part_a']['within_tiles_rms_d']:.4f} -> {b['part_a']['within_tiles_rms_d']:.4f} | "
                       f"{hs['part_a']['rms_d']:.4f} -> {bs['part_a']['rms_d']:.4f} | "
                       f"{h['error']['mean_d']:+.3f} -> {b['error']['mean_d']:+.3f} |")
    band = [v for v in rows if "band" in v["part_a_inside"]]
    if band:
        out += ["", f"| variant | band within r_max outside the tile centres' rectangle: pixels | part a there: held -> "
                f"{band[0]['beyond']['mode']} (RMS, mean, D) | schedule there |", "|---|---|---|---|"]
        for v in band:
            h, b = v["part_a_inside"]["band"], v["beyond"]["part_a_inside"]["band"]
            hs, bs = v["schedule"]["band"], v["beyond"]["schedule"]["band"]
            out.append(f"| {v['variant']} | {100 * h['share']:.1f} % | {h['rms_d']:.3f} ({h['mean_d']:+.3f}) -> "
                       f"{b['rms_d']:.3f} ({b['mean_d']:+.3f}) | {hs['rms_d']:.3f} -> {bs['rms_d']:.3f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    from benchmarks.probes.tile_bias import chosen_variants
    from benchmarks.render_truth_map import load_or_exit

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--truth", required=True, help="a render-truth map (aat-render-truth-map-v1; a repo path)")
    ap.add_argument("--variants", default="nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2")
    ap.add_argument("--beyond", default=None, help="also score the fit with its field term beyond r_max "
                    "as FieldPoly.beyond names (paired against the hold)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    from aat_deploy.calibrate.format import BEYOND

    if a.beyond is not None and a.beyond not in BEYOND[1:]:
        ap.error(f"--beyond {a.beyond!r}: one of {', '.join(BEYOND[1:])}")
    if Path(a.out).exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    variants = chosen_variants(ap, a.variants)
    if not variants:
        ap.error("nothing to run: --variants is empty")
    load_or_exit(a.truth, "corners")
    log = lambda m: print(m, file=sys.stderr, flush=True)
    res = {"what": __doc__.split("\n")[0], "truth": a.truth,
           "command": "python -m benchmarks.probes.corners " + " ".join(argv if argv is not None else sys.argv[1:]),
           "variants": [run_variant(v, a.truth, a.beyond, log) for v in variants]}
    write_text_atomic(a.out, json.dumps(res, indent=1, default=float))
    print(table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
