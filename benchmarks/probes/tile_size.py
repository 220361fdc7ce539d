"""Part a on the phone against the fit's tile size: can smaller tiles reach the corners (issue 33; docs/calibration.md,
"The tile size and the corners").

    OMP_NUM_THREADS=1 python -m benchmarks.probes.tile_size --truth results/render_truth_map_cellphone_19p.json \
        [--variants nominal,copy] [--tiles-px 16,20,24,27,32] --out results/tile_size.json

bench_calibrate's `cellphone_near` development sweeps (the nominal lens, the hand-chosen copy and the declared
random copies of seed 2026) or the 24 px declaration's judging copies (JUDGING: copies 0-5 of seed 2027); no scene,
held-out or not, measured as `bench_calibrate.measures` measures them (the
same tapes) but with tiles of each --tiles-px (`measure_sweep(tile_px=...)`; the fit's own is 27 px on the 640 px
frame: `sweep.tile_px_for`), the fit's centred grid, and fitted as part a fits them (`fit_calibration`, no
bootstrap). Per tile size: the grid, the farthest kept tile's field radius (where the field term starts to be held)
and the share of the pixels beyond it, the tiles counted and kept, and part a (inside, 7-18 cm, against --truth:
`bench_calibrate.map_errors`) overall, within and beyond the farthest tile's radius and by field radius, in fixed
regions (within and beyond radius 0.920, the 27 px grid's farthest tile centre, and 0.66-0.920), and on the depth
schedule (0.07-0.5 m). With --exact, also the same kept tiles made exact (`exact_fit`): what the model alone does
with tiles that reach that far.
"""

from __future__ import annotations

import sys
import time

import numpy as np

FIXED_R = 0.920  # the fit's 27 px grid's farthest tile centre on the phone's 640 x 480
# The judging copies of the 24 px declaration (docs/calibration.md, "24 px tiles, judged on unseen copies"): random
# copies of a seed no result had used (the development variants are the seed 2026's), drawn as bench_calibrate's
# random copies are (benchmarks/calibrate_copies.py), fixed before any of them was rendered.
JUDGE_SEED, JUDGE_COPIES = 2027, 6
JUDGING = tuple(f"copy_s{JUDGE_SEED}_{k}" for k in range(JUDGE_COPIES))


def tile_grid(h: int, w: int, tile_px: int, aspect: float) -> dict:
    """The fit's centred grid of tile_px tiles on an h x w frame: its shape, border and farthest centre's radius."""
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.peaks import TileGrid

    g = TileGrid(h, w, tile_px)
    x, y = g.field()
    rows, cols = g.starts
    return {"grid": list(g.shape), "border_px": [int(cols[0]), int(rows[0])],
            "farthest_centre_r": float(field_radius_of(x, y, aspect).max())}


def r_max_of(res) -> float:
    from aat_deploy.calibrate.format import field_radius_of

    o = res.observations
    return float(field_radius_of(o.x, o.y, o.aspect).max())


def exact_fit(rig, eff: list[str], res, r_max: float, fixed: dict) -> dict:
    """The fit's kept tiles made exact (`phone_map_budget`'s ideal tiles: each tile's object, at the chart distance as
    fitted, with the peak where the truth has it in focus), fitted by `model.fit_model` (order chosen on them), the
    field term held beyond r_max: part a in the fixed regions (RMS, D). What the tiles' measurement costs there: with
    exact tiles the rest is the model's."""
    import dataclasses

    from aat_deploy.calibrate import in_focus_diopters
    from aat_deploy.calibrate.model import fit_model
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import phone_map_budget as P

    scale = B.SCALE if any(x.startswith("focus_metadata") for x in eff) else 1.0
    res.sweeps_measured = res.measures
    tiles = P.tile_table(res, rig, eff, scale)
    keep = P.kept_tiles(tiles, res.observations) & np.isfinite(tiles["ideal_d"])
    ideal = P.observations_of(tiles, keep, tiles["ideal_d"], rig.w / rig.h)
    m = fit_model(ideal)
    cal = P.held(dataclasses.replace(res.calibration, focus_error=m.focus, best_focus=m.field), r_max)
    inside = rig.setup.inside()
    d = in_focus_diopters(cal, inside * scale, rig.h, rig.w).astype(np.float64) - rig.truth(eff, inside).astype(
        np.float64)
    return {"tiles": int(keep.sum()), "order": [m.degree, m.radial, m.focus_degree, m.low_focus_degree],
            "rms_d": float(np.sqrt(np.mean(d ** 2))),
            "fixed_regions_rms_d": {k: float(np.sqrt(np.mean(d[:, msk] ** 2))) for k, msk in fixed.items()}}


def rig_for(base_rig, variant: str):
    """(rig, variant as bench_calibrate names it): the development variants as `chart_texture.rig_for` makes them
    (the softened chart), a judging copy (JUDGING) drawn from JUDGE_SEED with the same chart."""
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import elements
    from benchmarks import bench_calibrate as B
    from benchmarks import calibrate_copies as C
    from benchmarks.probes import chart_texture as CT

    if variant not in JUDGING:
        return CT.rig_for(base_rig, "soft leaves", variant)
    rig, _ = CT.rig_for(base_rig, "soft leaves", "nominal")
    s = rig.setup
    n_el = len(elements(load_lens(B.ROOT / s.lens)))
    k = JUDGING.index(variant)
    return rig.with_setup(C.copy_setup(s, JUDGE_SEED, C.draw_copy(s, n_el, JUDGE_SEED, k))), "copy"


def run(variant: str, truth_path: str, tile_px: int, log, exact: bool = False) -> dict:
    from aat_deploy.calibrate.fit import fit_calibration
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.eval.stats import field_radius
    from benchmarks import bench_calibrate as B

    t0 = time.time()
    rig, v = rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), variant)
    s = rig.setup
    eff = B.effects_for(s, v)
    sweeps = [B.sweep(rig, v, i, log) for i in range(len(s.distances_m))]
    ms = B.measures(rig, sweeps, v, tile_px=tile_px)  # the benchmark's tapes, at this tile size
    res = fit_calibration(ms, n_boot=0)
    cal = res.calibration
    e = B.map_errors(rig, cal, eff, s.inside())["calibration"]
    sched = B.map_errors(rig, cal, eff, s.schedule())["calibration"]
    # fixed regions, the same for every tile size: within and beyond the 27 px grid's farthest centre (0.920)
    from aat_deploy.calibrate import in_focus_diopters

    inside = s.inside()
    d = in_focus_diopters(cal, inside * B.SCALE if any(x.startswith("focus_metadata") for x in eff) else inside,
                          rig.h, rig.w).astype(np.float64) - rig.truth(eff, inside).astype(np.float64)
    prad = field_radius(rig.h, rig.w)
    fixed = {f"r <= {FIXED_R:g}": prad <= FIXED_R, f"r > {FIXED_R:g}": prad > FIXED_R,
             f"0.66 < r <= {FIXED_R:g}": (prad > 0.66) & (prad <= FIXED_R)}
    fixed_rms = {k: float(np.sqrt(np.mean(d[:, m] ** 2))) for k, m in fixed.items()}
    obs = res.observations
    r_max = float(field_radius_of(obs.x, obs.y, obs.aspect).max())
    if exact:  # the same kept tiles made exact (each peaking where the truth has its object in focus), fitted
        out_exact = exact_fit(rig, eff, res, r_max_of(res), fixed)
    out = {"variant": variant, "tile_px": tile_px, **tile_grid(rig.h, rig.w, tile_px, rig.w / rig.h),
           "counted": int(sum(int((m.peaks.why == "").sum()) for m in ms)), "kept": int(len(obs)),
           "kept_r_max": r_max, "beyond_share": float((field_radius(rig.h, rig.w) > r_max).mean()),
           "order": [res.model.degree, res.model.radial, res.model.focus_degree, res.model.low_focus_degree],
           "family": cal.focus_error.family,
           "near_chart_mm": float(1000 * ms[s.fit_distance[0]].chart_distance_m) if s.fit_distance else None,
           "near_chart_fitted_mm": float(1000 * res.measures[s.fit_distance[0]].chart_distance_m)
           if s.fit_distance else None,
           "part_a": {k: e[k] for k in ("rms_d", "p95_d", "within_tiles_rms_d", "beyond_tiles_rms_d",
                                         "radius_rms_d") if k in e},
           "part_a_fixed_regions_rms_d": fixed_rms,
           "schedule": {k: sched[k] for k in ("rms_d", "p95_d", "within_tiles_rms_d", "beyond_tiles_rms_d")
                        if k in sched},
           "seconds": time.time() - t0}
    if exact:
        out["exact"] = out_exact
    log(f"{variant} {tile_px} px: grid {out['grid']}, farthest kept tile r {r_max:.3f} ({100 * out['beyond_share']:.2f} "
        f"% beyond), kept {len(obs)}; part a {e['rms_d']:.4f} D (within {e.get('within_tiles_rms_d', float('nan')):.4f}, "
        f"beyond {e.get('beyond_tiles_rms_d', float('nan')):.3f}) ({out['seconds']:.0f} s)"
        + (f"; exact tiles {out['exact']['rms_d']:.4f} D, fixed regions " + " / ".join(
            f"{v:.3f}" for v in out['exact']['fixed_regions_rms_d'].values()) if exact else ""))
    return out


def table(rows: list[dict]) -> str:
    out = ["| variant | tile (px) | grid (rows x cols) | farthest kept tile's radius | pixels beyond | tiles kept | "
           "part a inside RMS (D) | within the tiles' radius | beyond it | r <= 0.92 / r > 0.92 / 0.66-0.92 (fixed) | "
           "the depth schedule (D) | near chart (mm) | order |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        a = r["part_a"]
        out.append(f"| {r['variant']} | {r['tile_px']} | {r['grid'][0]} x {r['grid'][1]} | {r['kept_r_max']:.3f} | "
                   f"{100 * r['beyond_share']:.2f} % | {r['kept']} | {a['rms_d']:.4f} | "
                   f"{a.get('within_tiles_rms_d', float('nan')):.4f} | {a.get('beyond_tiles_rms_d', float('nan')):.3f} | "
                   f"{' / '.join(format(v, '.4f') for v in r['part_a_fixed_regions_rms_d'].values())} | "
                   f"{r['schedule']['rms_d']:.4f} | {r['near_chart_fitted_mm']:.2f} | {'/'.join(str(v) for v in r['order'])} |")
    return "\n".join(out)


def main(argv=None) -> int:
    from benchmarks.probes import calibrate_probe_cli as cli
    from benchmarks.probes.tile_bias import VARIANTS

    ap = cli.parser(__doc__, "nominal,copy")
    ap.add_argument("--tiles-px", default="16,20,24,27,32", help="tile sizes (px, comma-separated)")
    ap.add_argument("--exact", action="store_true", help="also the kept tiles made exact (peaking where the truth has "
                    "their object in focus) and fitted: what the model alone does at each tile size")
    a = ap.parse_args(argv)
    try:
        sizes = [int(t) for t in a.tiles_px.split(",") if t]
    except ValueError:
        ap.error(f"--tiles-px {a.tiles_px!r}: whole numbers of pixels, comma-separated")
    if not sizes or any(not 8 <= t <= 96 for t in sizes):
        ap.error(f"--tiles-px {a.tiles_px!r}: sizes of 8 to 96 px")
    cli.refuse_existing_out(ap, a.out)
    variants = cli.variants_of(ap, a.variants, VARIANTS + JUDGING)
    cli.load_truth(a.truth, "tile_size")
    rows = [run(v, a.truth, t, cli.log, a.exact) for v in variants for t in sizes]
    cli.write_result(a.out, "tile_size", __doc__, a.truth, argv, rows)
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
