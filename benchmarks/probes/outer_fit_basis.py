"""The phone's field term fitted to the truth itself, the format's polynomials against radial splines (issue 33;
docs/calibration.md, "24 px tiles, judged on unseen copies", what follows it): is the fit's own error at field radius
0.66-0.92 and beyond the polynomial family's, so that another basis of the field could follow the phone's rise?

    OMP_NUM_THREADS=1 python -m benchmarks.probes.outer_fit_basis --truth results/render_truth_map_cellphone_19p.json \
        --variants nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2 --out results/outer_fit_basis.json
    OMP_NUM_THREADS=1 python -m benchmarks.probes.outer_fit_basis --truth results/render_truth_map_cellphone_19p.json \
        --variants nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2 --measured 27,16 \
        --out results/outer_fit_basis_measured.json
    OMP_NUM_THREADS=1 python -m benchmarks.probes.outer_fit_basis --truth results/render_truth_map_cellphone_19p.json \
        --variants nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2 --measured 27 \
        --extra 0.128:-6:5,0.083:10:-4 --out results/outer_fit_basis_6charts.json

No render, no tile, no scene: per variant (bench_calibrate's `cellphone_near` development variants) the truth
(`Rig.truth_at`, against --truth) on a dense grid (every DENSE_PX px of the 640 x 480 frame) at part a's 10 inside
settings (7-18 cm), as the field term (object diopters minus the true focus, in diopters), fitted by least squares
with each of BASES (the field's functions times Legendre polynomials of the true focus, and an on-axis term per
degree: `exact_tiles_order._design`'s form), on two regions:

- **the tiles' disc** (field radius <= R_TILES, where the fit's 27 px tile centres reach; also DISCS' 0.942 and
  0.972, where 24 and 16 px tiles reach): the fit there, in-sample, and beyond it held along the radius (as
  `aat-calibrate fit` holds it): what a basis can do with data where the tiles are, at best;
- **the whole frame** (corners included): whether the basis can represent the phone's rise at all.

The error is RMS (and mean) by field radius bin (BINS), and over every point (the part-a-like total on this grid).
With --measured, the same bases (but the finest) fitted to part a's measured tiles instead (`measured_maps`); with
--extra, to the tiles of the four charts and extra ones (their distances fitted), with the edge quartic and quintic
in focus too (EXTRA_BASES).

The truth fits are a floor, not a fit of measured tiles: the tiles see each field point only where a chart's object is in focus
(four bands), with their noise and texture scatter, and the fit's cross-validation would have to choose the basis.
"""

from __future__ import annotations

import sys
import time

import numpy as np

DENSE_PX = 8
R_TILES = 0.920  # the fit's 27 px grid's farthest tile centre on the phone's 640 x 480
DISCS = (0.920, 0.942, 0.972)  # the farthest tile centres of 27, 24 and 16 px grids (docs/calibration.md, "The tile size")
BINS = ((0.0, 0.66), (0.66, 0.75), (0.75, 0.84), (0.84, 0.92), (0.92, 1.0))
KNOTS = (0.5, 0.6, 0.7, 0.8, 0.88)
FINE_KNOTS = tuple(round(0.3 + 0.05 * k, 2) for k in range(14))  # 0.3, 0.35, ..., 0.95
# (name, kind, parameters): "poly" = exact_tiles_order._design's (degree, radial, focus degree, edge powers' focus
# degree; the format's richest is 6/12/2/3: quadratic in focus, cubic for the edge powers); "spline" = monomials to
# `degree` (focus degree `fdeg`) plus rho^4, rho^6 and the truncated cubics (rho - k)_+^3 at `knots` (focus degree
# `edeg`): a radial shape that can bend where the phone's field rises, the monomials' asymmetry (tilt, decentre) kept
BASES = (("poly 6/12, focus 2/3 (the format's richest)", "poly", (6, 12, 2, 3)),
         ("poly 6/20, focus 2/3 (radial beyond the format)", "poly", (6, 20, 2, 3)),
         ("poly 6/12, focus 4/5 (focus beyond the format)", "poly", (6, 12, 4, 5)),
         ("spline 3 + 5 knots, focus 2/3", "spline", (3, 2, 3, KNOTS)),
         ("spline 3 + 5 knots, focus 2/5", "spline", (3, 2, 5, KNOTS)),
         ("spline 6 + 14 knots, focus 6/8 (anything smooth)", "spline", (6, 6, 8, FINE_KNOTS)))


def spline_design(x, y, t, aspect: float, t_range: tuple, degree: int, fdeg: int, edeg: int, knots) -> np.ndarray:
    """(N, K) the monomials of the field to `degree` times Legendre polynomials of the true focus t to fdeg, rho^4,
    rho^6 (when the monomials do not hold them) and (rho - k)_+^3 for each knot times Legendre polynomials to edeg,
    and an on-axis term per focus degree (to fdeg): `exact_tiles_order._design`'s form with a radial spline."""
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import FieldBasis

    rho = field_radius_of(x, y, aspect)
    tau = 2 * (t - t_range[0]) / (t_range[1] - t_range[0]) - 1
    leg = np.polynomial.legendre.legvander(tau, max(fdeg, edeg))
    mono = FieldBasis(degree, 0, aspect).columns(x, y)
    cols = [mono[:, k] * leg[:, j] for k in range(mono.shape[1]) for j in range(fdeg + 1)]
    radial = [rho ** p for p in (4, 6) if p > degree] + [np.clip(rho - k, 0.0, None) ** 3 for k in knots]
    cols += [f * leg[:, j] for f in radial for j in range(edeg + 1)]
    cols += [leg[:, j] for j in range(fdeg + 1)]
    return np.column_stack(cols)


def design(kind: str, params: tuple, x, y, t, aspect: float, t_range: tuple) -> np.ndarray:
    from benchmarks.probes.exact_tiles_order import _design

    if kind == "poly":
        return _design(x, y, t, aspect, t_range, params)
    return spline_design(x, y, t, aspect, t_range, *params)


def held_xy(x: np.ndarray, y: np.ndarray, aspect: float, r_max: float) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) moved in along the radius to r_max where their field radius is beyond it (the fit's hold)."""
    from aat_deploy.calibrate.format import field_radius_of

    rho = field_radius_of(x, y, aspect)
    s = np.where(rho > r_max, r_max / np.maximum(rho, 1e-12), 1.0)
    return x * s, y * s


def by_bin(err: np.ndarray, rho: np.ndarray) -> dict:
    """{bin: {rms_d, mean_d, share}} and "all": the error (S, N) by field radius (N,) bin (the last bin's end in)."""
    out = {}
    for lo, hi in BINS:
        m = (rho > lo) & (rho <= hi) if lo > 0 else rho <= hi
        if m.any():
            e = err[:, m]
            out[f"{lo:g}-{hi:g}"] = {"rms_d": float(np.sqrt(np.mean(e ** 2))), "mean_d": float(e.mean()),
                                     "share": float(np.sum(e ** 2) / np.sum(err ** 2))}
    out["all"] = {"rms_d": float(np.sqrt(np.mean(err ** 2))), "mean_d": float(err.mean()), "share": 1.0}
    return out


def fit_floors(x, y, t_set, target: np.ndarray, aspect: float, bases=BASES, discs=DISCS) -> dict:
    """Per basis: least squares to target (S, N) (the field term at focus settings t_set (S,), diopters, at field
    points x, y (N,)) on each disc of field radius r in discs (held beyond r: "disc r") and on the whole frame; the
    error by bin. The first disc's is also "tiles' disc, held beyond" (the fit's 27 px reach)."""
    from aat_deploy.calibrate.format import field_radius_of

    rho = field_radius_of(x, y, aspect)
    s, n = target.shape
    xs, ys, ts = np.tile(x, s), np.tile(y, s), np.repeat(t_set, n)
    t_range = (float(t_set.min()), float(t_set.max()))
    out = {}
    for name, kind, params in bases:
        a = design(kind, params, xs, ys, ts, aspect, t_range)
        row = {"columns": int(a.shape[1])}
        for r_disc in discs:
            disc = np.tile(rho <= r_disc, s)
            hx, hy = held_xy(x, y, aspect, r_disc)
            sol, *_ = np.linalg.lstsq(a[disc], target.ravel()[disc], rcond=None)
            held = design(kind, params, np.tile(hx, s), np.tile(hy, s), ts, aspect, t_range) @ sol
            row[f"disc {r_disc:.3f}"] = by_bin(held.reshape(s, n) - target, rho)
        row["tiles' disc, held beyond"] = row[f"disc {discs[0]:.3f}"]
        sol, *_ = np.linalg.lstsq(a, target.ravel(), rcond=None)
        row["whole frame"] = by_bin((a @ sol).reshape(s, n) - target, rho)
        out[name] = row
    return out


def run(variant: str, truth_path: str, log) -> dict:
    from aat_deploy.calibrate.format import field_grid
    from benchmarks import bench_calibrate as B
    from benchmarks.probes.tile_size import rig_for

    t0 = time.time()
    rig, v = rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), variant)
    eff = B.effects_for(rig.setup, v)
    gx, gy = field_grid(rig.h, rig.w)
    sel = np.zeros((rig.h, rig.w), bool)
    sel[DENSE_PX // 2::DENSE_PX, DENSE_PX // 2::DENSE_PX] = True
    x, y = gx[sel].astype(np.float64), gy[sel].astype(np.float64)
    inside = rig.setup.inside()
    t_set = 1.0 / inside
    target = rig.truth_at(eff, x, y, inside) - t_set[:, None]
    out = {"variant": variant, "points": int(x.size), "settings": int(t_set.size),
           "floors": fit_floors(x, y, t_set, target, rig.w / rig.h), "seconds": time.time() - t0}
    for name, r in out["floors"].items():
        d, w = r["tiles' disc, held beyond"], r["whole frame"]
        log(f"{variant}, {name} ({r['columns']} columns): disc {d['all']['rms_d']:.4f} D (0.66-0.92 "
            f"{', '.join(format(d[k]['rms_d'], '.3f') for k in ('0.66-0.75', '0.75-0.84', '0.84-0.92'))}, beyond "
            f"{d['0.92-1']['rms_d']:.3f}); whole frame {w['all']['rms_d']:.4f} D (beyond 0.92 {w['0.92-1']['rms_d']:.3f})")
    return out


# on measured tiles: the rule's usual order (degree 2, radial to 12) and the format's richest, each against a radial
# spline with as many monomials, and the spline with the edge quintic in focus (four charts: four bands of focus)
MEASURED_BASES = (("poly 2/12, focus 2/3 (the rule's usual order, fixed)", "poly", (2, 12, 2, 3)),
                  ("spline 2 + 5 knots, focus 2/3", "spline", (2, 2, 3, KNOTS)),
                  BASES[0], BASES[3], BASES[4])


# with extra charts (--extra): more bands of focus at every field point, so the edge's quartic and quintic in focus
EXTRA_BASES = MEASURED_BASES + (("spline 3 + 5 knots, focus 2/4", "spline", (3, 2, 4, KNOTS)),)


def with_charts(rig, extra: list):
    """The rig with extra charts [(distance m, (tilt x, tilt y) deg)] appended after the four (which keep their
    sweeps, seeds and tapes), their distances fitted from the tape start (`~`), as `more_charts --fit-extra` adds
    them; part a's frames unchanged (`inside_m` fixed)."""
    import dataclasses

    s = rig.setup
    n0 = len(s.distances_m)
    return rig.with_setup(dataclasses.replace(
        s, distances_m=tuple(s.distances_m) + tuple(d for d, _ in extra),
        tilts=tuple(s.tilts) + tuple(t for _, t in extra),
        inside_m=s.inside_m or (min(s.distances_m), max(s.distances_m)),
        fit_distance=tuple(s.fit_distance) + tuple(range(n0, n0 + len(extra)))))


def measured_maps(variant: str, truth_path: str, tile_px: int, log, bases=MEASURED_BASES, extra=()) -> dict:
    """Part a's fit (bench_calibrate's sweeps and tapes, tiles of tile_px, `fit_calibration` without bootstrap) and,
    on its kept tiles with its focus error fixed (each tile's on-axis diopters t = the fit's g(reported)), each basis
    fitted by weighted least squares to the tiles' object minus t, held beyond the farthest kept tile's radius as
    the fit holds it; every map scored as part a scores it (inside, 7-18 cm, against the truth; RMS by BINS). No
    cross-validation chooses among them: each basis at its fixed order."""
    from aat_deploy.calibrate.fit import fit_calibration
    from aat_deploy.calibrate.format import field_grid, field_radius_of, in_focus_diopters, on_axis_diopters
    from benchmarks import bench_calibrate as B
    from benchmarks.probes.tile_size import rig_for

    t0 = time.time()
    rig, v = rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), variant)
    if extra:
        rig = with_charts(rig, list(extra))
    s = rig.setup
    eff = B.effects_for(s, v)
    sweeps = [B.sweep(rig, v, i, log) for i in range(len(s.distances_m))]
    res = fit_calibration(B.measures(rig, sweeps, v, tile_px=tile_px), n_boot=0)
    cal, o = res.calibration, res.observations
    aspect = rig.w / rig.h
    r_max = float(field_radius_of(o.x, o.y, o.aspect).max())
    inside = s.inside()
    rep_m = inside * (B.SCALE if any(e.startswith("focus_metadata") for e in eff) else 1.0)
    truth = rig.truth(eff, inside).astype(np.float64)
    gx, gy = field_grid(rig.h, rig.w)
    prad = field_radius_of(gx, gy, aspect)
    score = lambda m: by_bin((m - truth).reshape(len(inside), -1), prad.ravel())
    out = {"variant": variant, "tile_px": tile_px, "charts_m": list(s.distances_m),
           "charts_fitted_mm": [float(1000 * m.chart_distance_m) for m in res.measures],
           "kept": int(len(o)), "r_max": r_max,
           "order": [res.model.degree, res.model.radial, res.model.focus_degree, res.model.low_focus_degree],
           "maps": {"the fit (its orders blended, as part a)": score(
               in_focus_diopters(cal, rep_m, rig.h, rig.w).astype(np.float64))}}
    lo, hi = cal.best_focus.focus_range_d
    t_tile = np.clip(cal.focus_error.true_diopters(o.reported_d), lo, hi)
    w = np.sqrt(np.asarray(o.weight, np.float64))
    t_map = on_axis_diopters(cal, rep_m)
    hx, hy = held_xy(gx.ravel().astype(np.float64), gy.ravel().astype(np.float64), aspect, r_max)
    for name, kind, params in bases:
        a = design(kind, params, o.x, o.y, t_tile, o.aspect, (lo, hi))
        sol, *_ = np.linalg.lstsq(a * w[:, None], (o.object_d - cal.focus_error.true_diopters(o.reported_d)) * w,
                                  rcond=None)
        maps = [tm + design(kind, params, hx, hy, np.full(hx.size, np.clip(tm, lo, hi)), aspect, (lo, hi)) @ sol
                for tm in t_map]
        out["maps"][name] = score(np.stack(maps).reshape(truth.shape))
    out["seconds"] = time.time() - t0
    log(f"{variant} {tile_px} px (r_max {r_max:.3f}): " + "; ".join(
        f"{k} {m['all']['rms_d']:.4f}" for k, m in out["maps"].items()) + f" D ({out['seconds']:.0f} s)")
    return out


def measured_table(rows: list[dict]) -> str:
    out = ["| variant | tiles (px) | map | part a inside: all / 0-0.66 / 0.66-0.75 / 0.75-0.84 / 0.84-0.92 / beyond "
           "0.92 (RMS, D) |", "|---|---|---|---|"]
    for r in rows:
        for name, m in r["maps"].items():
            out.append(f"| {r['variant']} | {r['tile_px']} | {name} | " + " / ".join(
                f"{m[k]['rms_d']:.4f}" for k in ("all", "0-0.66", "0.66-0.75", "0.75-0.84", "0.84-0.92", "0.92-1"))
                + " |")
    return "\n".join(out)


def table(rows: list[dict]) -> str:
    out = ["| variant | basis | columns | fitted on the tiles' disc, held beyond: all / 0-0.66 / 0.66-0.75 / 0.75-0.84 / "
           "0.84-0.92 / beyond 0.92 (RMS, D) | all / beyond 0.92, fitted to radius 0.942 / to 0.972, held beyond | "
           "fitted on the whole frame: all / 0.84-0.92 / beyond 0.92 |", "|---|---|---|---|---|---|"]
    for r in rows:
        for name, f in r["floors"].items():
            d, w = f["tiles' disc, held beyond"], f["whole frame"]
            out.append(f"| {r['variant']} | {name} | {f['columns']} | " + " / ".join(
                f"{d[k]['rms_d']:.3f}" for k in ("all", "0-0.66", "0.66-0.75", "0.75-0.84", "0.84-0.92", "0.92-1"))
                + " | " + " / ".join(f"{f[f'disc {r:.3f}'][k]['rms_d']:.3f}" for r in DISCS[1:] for k in ("all", "0.92-1"))
                + " | " + " / ".join(f"{w[k]['rms_d']:.3f}" for k in ("all", "0.84-0.92", "0.92-1")) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    from benchmarks.probes import calibrate_probe_cli as cli
    from benchmarks.probes.tile_bias import VARIANTS

    ap = cli.parser(__doc__, ",".join(VARIANTS), "the development variants (no judging copy: this is development)")
    ap.add_argument("--measured", default="", help="tile sizes (px, comma-separated): instead of the truth, part a's "
                    "fit of the measured tiles at each and MEASURED_BASES fitted to its kept tiles (renders the sweeps)")
    ap.add_argument("--extra", default="", help="with --measured: extra charts, distance_m:tilt_x:tilt_y,... "
                    "(`more_charts`'s syntax), their distances fitted; then EXTRA_BASES")
    a = ap.parse_args(argv)
    from benchmarks.probes.more_charts import parse_extra

    try:
        extra = parse_extra(a.extra)
    except ValueError as e:
        ap.error(str(e))
    if extra and not a.measured:
        ap.error("--extra goes with --measured")
    try:
        sizes = [int(t) for t in a.measured.split(",") if t]
    except ValueError:
        ap.error(f"--measured {a.measured!r}: whole numbers of pixels, comma-separated")
    if any(not 8 <= t <= 96 for t in sizes):
        ap.error(f"--measured {a.measured!r}: sizes of 8 to 96 px")
    cli.refuse_existing_out(ap, a.out)
    variants = cli.variants_of(ap, a.variants, VARIANTS)
    cli.load_truth(a.truth, "outer_fit_basis")
    if sizes:
        bases = EXTRA_BASES if extra else MEASURED_BASES
        rows = [measured_maps(v, a.truth, t, cli.log, bases, extra) for v in variants for t in sizes]
        cli.write_result(a.out, "outer_fit_basis", __doc__, a.truth, argv, rows, extra=extra,
                         bases=[[n, k, list(p[:3]) + ([list(p[3])] if k == "spline" else [p[3]])]
                                for n, k, p in bases])
        print(measured_table(rows))
        return 0
    rows = [run(v, a.truth, cli.log) for v in variants]
    cli.write_result(a.out, "outer_fit_basis", __doc__, a.truth, argv, rows,
                     bases=[[n, k, list(p[:3]) + ([list(p[3])] if k == "spline" else [p[3]])] for n, k, p in BASES])
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
