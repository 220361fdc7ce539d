"""Does the field model's basis or order limit the phone's map where the tiles are exact? (issue 33; docs/calibration.md,
"The tiles' bias against the render truth, and the fit's own error").

    OMP_NUM_THREADS=1 python -m benchmarks.probes.exact_tiles_order --truth results/render_truth_map_cellphone.json \
        [--variants nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2] [--options ...] \
        [--measured "true distances;true distances, near fitted"] \
        --out results/exact_tiles_order.json

bench_calibrate's `cellphone_near` development sweeps (the nominal lens, the hand-chosen copy, the declared random
copies of seed 2026; no held-out scene). Exact tiles (`phone_map_budget`'s ideal tiles: the fit's counted and kept
tiles, each peaking where the render truth has its object in focus) are fitted by `model.fit_model` under each
option (OPTIONS: module constants of `aat_deploy.calibrate.model` changed for the fit alone), the field term held
beyond the farthest tile as the fit holds it, and scored against the render truth over part a's 10 "inside"
settings within the tiles' hull, by field radius. Options named in --measured are also run as part a runs them
(`fit_calibration` on the measured sweeps, outlier pass and fitted near-chart distance included) and scored as part
a scores them (`bench_calibrate.map_errors`); "true distances" there puts every chart at its rendered distance
(no tape error, nothing fitted), "true distances, near fitted" the measured charts there and the near chart's
distance fitted from its tape start. Beside them: exact tiles at the rendered distances with the near chart's
distance an unknown (what the model alone pulls it to), and the model fitted to the truth itself on a dense grid
inside the tiles' hull (the basis's floor: where the tiles lie is then no limit). With --bases, field bases richer
than the format holds (BASES), fitted by least squares with the focus error known, to the exact tiles and to the
truth itself: whether the basis or the tiles' coverage limits the map.
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys

import numpy as np

from benchmarks.probes.tile_bias import VARIANTS

OPTIONS = {
    "as is": {},
    "degree to 8": {"DEGREES": (2, 3, 4, 5, 6, 7, 8)},  # the monomials' degree chosen up to 8 (as is: 6)
    "radial 8/10/12": {"RADIAL": (0, 8, 10, 12)},  # the radial powers' highest chosen among these (as is: 0, 8, 12)
    "edge from rho^6": {"EDGE_POWER": 6},  # rho^6 follows focus as the edge powers do (as is: from rho^8)
    "no blend": {"ORDER_BAND": 1e-9, "EDGE_BAND": 1e-9},  # the rule's order alone (the fit before the blend)
    "edge cubic if better": {"EDGE_BAND": 1e6},  # the edge cubic wherever its frame-cell CV is better at all
    # radial powers beyond the format's ceiling (total degree 12): the file's limits raised with them (format.*)
    "radial to 20": {"RADIAL": (0, 8, 12, 16, 20), "format.MAX_DEGREE": 20, "format.MAX_TERMS": 128},
    # the field term beyond the farthest tile continued to first order along the radius (as is: held)
    "beyond linear": {"fit.BEYOND_TILES": "linear"},
    # the field term held at the nearest point of the tile centres' rectangle outside it (as is: held on the radius)
    "beyond rectangle": {"fit.BEYOND_TILES": "rectangle"},
    # tiles of 1/32 of the frame's width (as is: 1/24; 20 px instead of 27 on the phone's 640): the sweeps' measuring
    # (`measure_sweep` through `tile_px_for`), so only runs that measure the sweeps see it (patched_bench, --measured)
    "tiles 1/32": {"sweep.TILES_PER_WIDTH": 32},
    # tiles of 1/27 of the frame's width (24 px on the phone's and the paper lens's 640, 36 on the RF50's and EF50's
    # 960; as is: 27 and 40), declared 2026-11-28 (docs/calibration.md, "24 px tiles, judged on unseen copies")
    "tiles 1/27": {"sweep.TILES_PER_WIDTH": 27},
}


MEASURED_ONLY = ("true distances", "true distances, near fitted")  # --measured: the charts at their rendered distances


@contextlib.contextmanager
def patched(changes: dict):
    """Module constants of aat_deploy.calibrate.model (NAME), .format (format.NAME), .fit (fit.NAME) or .sweep
    (sweep.NAME) changed inside the block."""
    from aat_deploy.calibrate import fit as FIT
    from aat_deploy.calibrate import format as F
    from aat_deploy.calibrate import model as M
    from aat_deploy.calibrate import sweep as SW

    mods = {"format": F, "fit": FIT, "sweep": SW}
    where = lambda k: (mods[k.split(".", 1)[0]], k.split(".", 1)[1]) if k.split(".", 1)[0] in mods else (M, k)
    old = {k: getattr(*where(k)) for k in changes}
    try:
        for k, v in changes.items():
            setattr(*where(k), v)
        yield
    finally:
        for k, v in old.items():
            setattr(*where(k), v)


def edge_weight_patched(changes: dict):
    """EDGE_BAND 1e6 means "the cubic whenever its CV is better at all": edge_weight's band would make it ~0."""
    from aat_deploy.calibrate import model as M

    if changes.get("EDGE_BAND") != 1e6:
        return contextlib.nullcontext()
    orig = M.edge_weight

    def cubic_if_better(table):
        cv = table["cv_rms_d"]
        base, edge = cv[next(k for k in cv if not k.startswith("edge"))], cv[f"edge {M.EDGE_FOCUS_DEGREE}"]
        return 1.0 if np.isfinite(edge) and edge < base else 0.0

    @contextlib.contextmanager
    def cm():
        M.edge_weight = cubic_if_better
        try:
            yield
        finally:
            M.edge_weight = orig

    return cm()


def _design(x, y, t, aspect: float, t_range: tuple, basis: tuple) -> np.ndarray:
    """(N, K) a field term's columns for `basis` = (degree, radial, focus degree, edge powers' focus degree): the
    monomials to degree and the even radial powers beyond it to radial (`model.FieldBasis`'s, without the format's
    ceiling of 12), times Legendre polynomials of the true focus t over t_range, and an on-axis term per degree."""
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import EDGE_POWER, FieldBasis

    deg, radial, fdeg, edeg = basis
    r2 = field_radius_of(x, y, aspect) ** 2
    tau = 2 * (t - t_range[0]) / (t_range[1] - t_range[0]) - 1
    leg = np.polynomial.legendre.legvander(tau, max(fdeg, edeg))
    mono = FieldBasis(deg, 0, aspect).columns(x, y)
    cols = [mono[:, k] * leg[:, j] for k in range(mono.shape[1]) for j in range(fdeg + 1)]
    for p in range(deg + 2 - deg % 2, radial + 1, 2):
        cols += [r2 ** (p // 2) * leg[:, j] for j in range((edeg if p >= EDGE_POWER else fdeg) + 1)]
    cols += [leg[:, j] for j in range(fdeg + 1)]
    return np.column_stack(cols)


def basis_floors(rig, eff: list[str], ideal, scale: float, covered: np.ndarray, inside: np.ndarray) -> dict:
    """Per BASES entry, the field term alone (the focus error known: each tile's true focus) fitted by least squares
    (a) to the exact tiles: their residual and the map's error within the tiles' hull, and (b) to the truth itself
    on a dense grid in the hull (every DENSE_PX px at part a's 10 settings): what the basis can reach at all."""
    from aat_deploy.calibrate.format import field_grid

    t_tile = ideal.reported_d * scale  # the exact tiles' true focus
    gx, gy = field_grid(rig.h, rig.w)
    sel = np.zeros_like(covered)
    sel[DENSE_PX // 2::DENSE_PX, DENSE_PX // 2::DENSE_PX] = True
    sel &= covered
    xs, ys = gx[sel].astype(np.float64), gy[sel].astype(np.float64)
    ft = 1.0 / inside
    obj = rig.truth_at(eff, xs, ys, inside)  # (10, N)
    x, y, t = np.tile(xs, len(ft)), np.tile(ys, len(ft)), np.repeat(ft, len(xs))
    target = (obj - ft[:, None]).ravel()
    t_range = (float(min(t_tile.min(), ft.min())), float(max(t_tile.max(), ft.max())))
    out = {}
    for b in BASES:
        a = _design(ideal.x, ideal.y, t_tile, ideal.aspect, t_range, b)
        sol, *_ = np.linalg.lstsq(a, ideal.object_d - t_tile, rcond=None)
        dense = _design(x, y, t, ideal.aspect, t_range, b)
        e = dense @ sol - target
        sol2, *_ = np.linalg.lstsq(dense, target, rcond=None)
        out["/".join(str(v) for v in b)] = {
            "params": int(a.shape[1]),
            "tile_residual_rms_d": float(np.sqrt(np.mean((a @ sol - (ideal.object_d - t_tile)) ** 2))),
            "map_rms_d": float(np.sqrt(np.mean(e ** 2))),
            "dense_rms_d": float(np.sqrt(np.mean((dense @ sol2 - target) ** 2)))}
    return out


def run(variant: str, truth_path: str, options: list[str], measured: list[str], log, bases: bool = False) -> dict:
    from aat_deploy.calibrate import in_focus_diopters
    from aat_deploy.calibrate.fit import fit_calibration
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import fit_model
    from aat_deploy.calibrate.sweep import measure_sweep
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT
    from benchmarks.probes import phone_map_budget as P

    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", variant)
    s = rig.setup
    eff, scale, sweeps, ms, res = P.development_fit(rig, v, log)
    res.sweeps_measured = res.measures
    obs = res.observations
    tiles = P.tile_table(res, rig, eff, scale)
    fit_kept = P.kept_tiles(tiles, obs)
    ideal = P.observations_of(tiles, fit_kept & np.isfinite(tiles["ideal_d"]), tiles["ideal_d"], rig.w / rig.h)
    inside = s.inside()
    rep_m = inside * scale
    truth = rig.truth(eff, inside)
    covered = P.covered_mask(obs.x, obs.y, rig.h, rig.w)
    r_max = float(np.max(field_radius_of(obs.x, obs.y, obs.aspect)))
    out = {"variant": variant, "exact": {}, "measured": {}}
    for name in options:
        with patched(OPTIONS[name]), edge_weight_patched(OPTIONS[name]):  # the format's limits too, while scored
            m = fit_model(ideal)
            cal = P.held(dataclasses.replace(res.calibration, focus_error=m.focus, best_focus=m.field), r_max)
            e = P.errors(in_focus_diopters(cal, rep_m, rig.h, rig.w), truth, covered)
        rt = field_radius_of(ideal.x, ideal.y, ideal.aspect)
        resid = {f"{lo:g}-{hi:g}": float(np.sqrt(np.mean(m.residual_d[(rt >= lo) & (rt < hi)] ** 2)))
                 for lo, hi in zip(P_EDGES[:-1], P_EDGES[1:]) if np.any((rt >= lo) & (rt < hi))}
        out["exact"][name] = {"covered_rms_d": e["covered_rms_d"], "rms_d": e["rms_d"],
                              "radius_rms_d": e["radius_rms_d"], "tile_residual_rms_d": resid,
                              "order": [m.degree, m.radial, m.focus_degree, m.low_focus_degree],
                              "blend": len(m.blend)}
        log(f"{variant} exact tiles, {name}: within the hull {e['covered_rms_d']:.4f} D "
            f"(order {m.degree}/{m.radial}/{m.focus_degree}/{m.low_focus_degree}, {len(m.blend)} blended)")
    # the near chart's fitted distance with exact tiles: every chart at its rendered distance, the tiles exact, and
    # the near chart's distance an unknown (from its tape start) or known: what the model pulls it to
    true_ms = [measure_sweep(B.as_sweep(rig, sw, v), sw["layout"], distance_m=sw["distance_m"], measure=rig.measure,
                             prefilter_px=rig.prefilter_px, fit_distance=i in s.fit_distance)
               for i, sw in enumerate(sweeps)]
    true_res = dataclasses.replace(res, measures=true_ms)
    true_res.sweeps_measured = true_ms
    tt = P.tile_table(true_res, rig, eff, scale)
    ok = tt["counted"] & np.isfinite(tt["ideal_d"])
    dz = np.concatenate([m.object_dz()[(m.peaks.why == "") | (m.peaks.why == "unbracketed")] if m.fit_distance
                         else np.zeros(int(np.sum((m.peaks.why == "") | (m.peaks.why == "unbracketed"))))
                         for m in true_ms])
    o_true = P.observations_of(tt, ok, tt["ideal_d"], rig.w / rig.h)
    for name, o in (("exact tiles at the rendered distances, the near chart's fitted",
                     dataclasses.replace(o_true, dz=dz[np.flatnonzero(ok)])),
                    ("exact tiles at the rendered distances, all known", o_true)):
        m = fit_model(o)
        cal = P.held(dataclasses.replace(res.calibration, focus_error=m.focus, best_focus=m.field), r_max)
        e = P.errors(in_focus_diopters(cal, rep_m, rig.h, rig.w), truth, covered)
        out["exact"][name] = {"covered_rms_d": e["covered_rms_d"], "rms_d": e["rms_d"],
                              "radius_rms_d": e["radius_rms_d"], "shifts_mm": m.shifts_mm,
                              "order": [m.degree, m.radial, m.focus_degree, m.low_focus_degree], "blend": len(m.blend)}
        log(f"{variant} {name}: within the hull {e['covered_rms_d']:.4f} D, shifts {m.shifts_mm} mm")
    # the basis's floor: the model fitted to the truth itself on a dense grid inside the tiles' hull (every DENSE_PX,
    # DENSE_F reported focus settings over part a's range), so that where the tiles are is no limit
    gx, gy = np.meshgrid(np.arange(DENSE_PX / 2, rig.w, DENSE_PX), np.arange(DENSE_PX / 2, rig.h, DENSE_PX))
    inn = covered[gy.astype(int), gx.astype(int)]
    xs, ys = (2 * (gx[inn] + 0.5) / rig.w - 1), (1 - 2 * (gy[inn] + 0.5) / rig.h)
    inn = field_radius_of(xs, ys, rig.w / rig.h) <= r_max
    xs, ys = xs[inn], ys[inn]
    rep_d = np.linspace((1 / inside / scale).min(), (1 / inside / scale).max(), DENSE_F)
    obj = rig.truth_at(eff, xs, ys, 1.0 / (rep_d * scale))  # (F, N)
    nf, npts = obj.shape
    from aat_deploy.calibrate.model import Observations

    sweep = np.repeat(np.arange(nf) % 4, npts)  # four "sweeps" (the edge cubic needs four)
    o_dense = Observations(np.tile(xs, nf), np.tile(ys, nf), np.repeat(rep_d, npts), obj.ravel(), sweep,
                           sweep * 10_000 + np.repeat(np.arange(nf), npts), aspect=rig.w / rig.h)
    m = fit_model(o_dense)
    cal = P.held(dataclasses.replace(res.calibration, focus_error=m.focus, best_focus=m.field), r_max)
    e = P.errors(in_focus_diopters(cal, rep_m, rig.h, rig.w), truth, covered)
    out["exact"]["the truth itself, dense"] = {"covered_rms_d": e["covered_rms_d"], "rms_d": e["rms_d"],
                                               "radius_rms_d": e["radius_rms_d"], "points": int(len(o_dense)),
                                               "order": [m.degree, m.radial, m.focus_degree, m.low_focus_degree],
                                               "blend": len(m.blend)}
    log(f"{variant} the truth itself, dense ({len(o_dense)} points): within the hull {e['covered_rms_d']:.4f} D")
    if bases:
        out["bases"] = basis_floors(rig, eff, ideal, scale, covered, inside)
        for k, b in out["bases"].items():
            log(f"{variant} basis {k}: exact tiles' residual {b['tile_residual_rms_d']:.4f}, map within the hull "
                f"{b['map_rms_d']:.4f}; fitted to the truth itself {b['dense_rms_d']:.4f} D")
    out["near_chart"] = {"rendered_m": float(s.distances_m[s.fit_distance[0]]),
                         "fitted_m": float(res.measures[s.fit_distance[0]].chart_distance_m)}
    for name in measured:
        if name.startswith("true distances"):
            near = name == "true distances, near fitted"  # the near chart's distance fitted from its tape start
            tapes = [m.chart_distance_m for m in ms]
            mt = [measure_sweep(B.as_sweep(rig, sw, v), sw["layout"],
                                distance_m=tapes[i] if near and i in s.fit_distance else sw["distance_m"],
                                measure=rig.measure, prefilter_px=rig.prefilter_px,
                                fit_distance=near and i in s.fit_distance) for i, sw in enumerate(sweeps)]
            r = fit_calibration(mt, n_boot=0)
            e = B.map_errors(rig, r.calibration, eff, inside)["calibration"]
        else:
            with patched(OPTIONS[name]), edge_weight_patched(OPTIONS[name]):  # the format's limits too, while scored
                r = fit_calibration(ms, n_boot=0)
                e = B.map_errors(rig, r.calibration, eff, inside)["calibration"]
        out["measured"][name] = {k: e[k] for k in ("rms_d", "p95_d", "within_tiles_rms_d", "radius_rms_d")
                                 if k in e}
        out["measured"][name]["near_chart_fitted_m"] = float(r.measures[s.fit_distance[0]].chart_distance_m)
        log(f"{variant} measured, {name}: part a {e['rms_d']:.4f} D (within the tiles {e['within_tiles_rms_d']:.4f})")
    return out


P_EDGES = (0.0, 0.33, 0.5, 0.66, 0.75, 0.84, 0.92)
DENSE_PX, DENSE_F = 16, 16  # the basis's floor: field points every 16 px, 16 reported focus settings
# --bases: (monomials' degree, radial powers' highest, degree in focus, the edge powers' degree in focus); the fit's
# own is 6/12/2/3 at most (the format stores total degree <= 12); the rest go beyond it
BASES = ((6, 12, 2, 3), (3, 12, 2, 3), (6, 12, 4, 4), (6, 16, 2, 3), (6, 20, 2, 3), (6, 24, 2, 3), (6, 24, 4, 5),
         (8, 24, 4, 5))


def table(rows: list[dict]) -> str:
    out = ["| variant | option | exact tiles: map within the hull (D) | by radius 0-0.33 / 0.33-0.5 / 0.5-0.66 / "
           "0.66-0.75 / 0.75-0.84 / 0.84-0.9 | order (degree/radial/focus/low) | part a, measured tiles (D) |",
           "|---|---|---|---|---|---|"]
    for r in rows:
        for name in dict.fromkeys([*r["exact"], *r["measured"]]):
            e, m = r["exact"].get(name), r["measured"].get(name)
            rad = "-" if not e else " / ".join(f"{e['radius_rms_d'][b]:.3f}" for b in
                                               ("0-0.33", "0.33-0.5", "0.5-0.66", "0.66-0.75", "0.75-0.84", "0.84-0.9"))
            out.append(f"| {r['variant']} | {name} | {'-' if not e else format(e['covered_rms_d'], '.4f')} | {rad} | "
                       f"{'-' if not e else '/'.join(str(v) for v in e['order'])} | "
                       f"{'-' if not m else format(m['rms_d'], '.4f')} |")
    return "\n".join(out)


def main(argv=None) -> int:
    from benchmarks.probes import calibrate_probe_cli as cli

    ap = cli.parser(__doc__, ",".join(VARIANTS))
    ap.add_argument("--options", default=",".join(OPTIONS), help=f"of: {'; '.join(OPTIONS)} (comma-separated)")
    ap.add_argument("--measured", default="", help="options (or MEASURED_ONLY's) also fitted on the measured tiles "
                    "(';'-separated)")
    ap.add_argument("--bases", action="store_true", help="also each of BASES fitted by least squares (the floors)")
    a = ap.parse_args(argv)
    cli.refuse_existing_out(ap, a.out)
    variants = [v for v in a.variants.split(",") if v]
    options = [o for o in a.options.split(",") if o]
    measured = [o for o in a.measured.split(";") if o]
    bad = [v for v in variants if v not in VARIANTS] + [o for o in options if o not in OPTIONS] + \
        [o for o in measured if o not in OPTIONS and o not in MEASURED_ONLY]
    if bad:
        ap.error(f"not a variant or option: {', '.join(bad)}")
    cli.load_truth(a.truth, "exact_tiles_order")
    rows = [run(v, a.truth, options, measured, cli.log, a.bases) for v in variants]
    cli.write_result(a.out, "exact_tiles_order", __doc__, a.truth, argv, rows, options=OPTIONS)
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
