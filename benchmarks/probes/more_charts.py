"""Part a on the phone with more chart distances: do more bands of focus at every field point take the fit's error
at field radius 0.66-0.92 down (issue 33; docs/calibration.md, "The error at field radius 0.66-0.92, split")?

    OMP_NUM_THREADS=1 python -m benchmarks.probes.more_charts --truth results/render_truth_map_cellphone_19p.json \
        [--variants nominal,copy] [--extra "0.128:-6:5,0.083:10:-4"] --out results/more_charts.json

bench_calibrate's `cellphone_near` development setup only (the nominal lens, the hand-chosen copy and the declared
random copies of seed 2026; no scene, held-out or not): its four charts (7, 10, 18 cm measured, 5.5 cm fitted) and
the same with extra charts (--extra: distance m : tilt x deg : tilt y deg, comma-separated), appended after the four
so that those keep their sweeps, seeds and tape errors (`bench_calibrate.measures` draws the tapes in order); each
extra chart is rendered and measured as the others (its distance taped, or with --fit-extra an unknown of the fit
from its tape start, as the 5.5 cm chart's), and both are fitted as part a fits them
(`fit_calibration`, no bootstrap) and scored on part a's 7-18 cm (the same frames: `inside_m` is fixed) against
--truth, by field radius, and on the depth schedule. Not a candidate for adoption: what a user gains by shooting more
charts (issue 33's part c), measured.
"""

from __future__ import annotations

import dataclasses
import sys
import time


def parse_extra(text: str) -> list[tuple[float, tuple[float, float]]]:
    """"d:tx:ty,..." -> [(distance m, (tilt x, tilt y) deg)]; ValueError naming the bad item."""
    out = []
    for item in (t for t in text.split(",") if t):
        parts = item.split(":")
        try:
            d, tx, ty = (float(v) for v in parts)
        except ValueError:
            raise ValueError(f"--extra {item!r}: distance_m:tilt_x_deg:tilt_y_deg") from None
        if not 0.055 <= d <= 0.5 or abs(tx) > 30 or abs(ty) > 30:
            raise ValueError(f"--extra {item!r}: a distance of 0.055-0.5 m and tilts within 30 degrees")
        out.append((d, (tx, ty)))
    return out


def run(variant: str, truth_path: str, extra: list, log, fit_extra: bool = False) -> dict:
    from aat_deploy.calibrate.fit import fit_calibration
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT

    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", variant)
    out = {"variant": variant}
    more = f"plus {len(extra)} charts" + (", their distances fitted (~)" if fit_extra else ", taped")
    for name, add in (("the four charts", []), (more, extra)):
        t0 = time.time()
        s = rig.setup
        n0 = len(s.distances_m)
        s2 = dataclasses.replace(s, distances_m=tuple(s.distances_m) + tuple(d for d, _ in add),
                                 tilts=tuple(s.tilts) + tuple(t for _, t in add), inside_m=s.inside_m or (
                                     min(s.distances_m), max(s.distances_m)),
                                 fit_distance=tuple(s.fit_distance) + (tuple(range(n0, n0 + len(add)))
                                                                       if fit_extra else ()))
        r2 = rig.with_setup(s2)
        eff = B.effects_for(s2, v)
        sweeps = [B.sweep(r2, v, i, log) for i in range(len(s2.distances_m))]
        ms = B.measures(r2, sweeps, v)
        res = fit_calibration(ms, n_boot=0)
        e = B.map_errors(r2, res.calibration, eff, s2.inside())["calibration"]
        sc = B.map_errors(r2, res.calibration, eff, s2.schedule())["calibration"]
        out[name] = {"distances_m": list(s2.distances_m), "kept": int(len(res.observations)),
                     "order": [res.model.degree, res.model.radial, res.model.focus_degree,
                               res.model.low_focus_degree], "family": res.calibration.focus_error.family,
                     "near_chart_fitted_mm": float(1000 * res.measures[s2.fit_distance[0]].chart_distance_m),
                     "charts_as_fitted_mm": [float(1000 * m.chart_distance_m) for m in res.measures],
                     "part_a": {k: e[k] for k in ("rms_d", "p95_d", "within_tiles_rms_d", "beyond_tiles_rms_d",
                                                  "radius_rms_d") if k in e},
                     "schedule_rms_d": sc["rms_d"], "seconds": time.time() - t0}
        log(f"{variant}, {name}: part a {e['rms_d']:.4f} D (within the tiles {e['within_tiles_rms_d']:.4f}), "
            f"schedule {sc['rms_d']:.4f} D ({time.time() - t0:.0f} s)")
    return out


def table(rows: list[dict]) -> str:
    bins = ("0.66-0.75", "0.75-0.84", "0.84-0.9", "0.9-1")
    out = ["| variant | charts | part a inside RMS (D) | within the tiles' radius | " + " / ".join(bins) +
           " | the depth schedule | near chart (mm) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        for name, v in r.items():
            if name == "variant":
                continue
            a = v["part_a"]
            out.append(f"| {r['variant']} | {name} | {a['rms_d']:.4f} | {a['within_tiles_rms_d']:.4f} | "
                       + " / ".join(f"{a['radius_rms_d'][b]:.3f}" for b in bins)
                       + f" | {v['schedule_rms_d']:.4f} | {v['near_chart_fitted_mm']:.2f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    from benchmarks.probes import calibrate_probe_cli as cli
    from benchmarks.probes.tile_bias import VARIANTS

    ap = cli.parser(__doc__, "nominal,copy")
    ap.add_argument("--extra", default="0.128:-6:5,0.083:10:-4", help="extra charts: distance_m:tilt_x:tilt_y,...")
    ap.add_argument("--fit-extra", action="store_true", help="the extra charts' distances fitted (`~`: their tape "
                    "only a start) instead of taped")
    a = ap.parse_args(argv)
    try:
        extra = parse_extra(a.extra)
    except ValueError as e:
        ap.error(str(e))
    if not extra:
        ap.error("--extra: no chart given")
    cli.refuse_existing_out(ap, a.out)
    variants = cli.variants_of(ap, a.variants, VARIANTS)
    cli.load_truth(a.truth, "more_charts")
    rows = [run(v, a.truth, extra, cli.log, a.fit_extra) for v in variants]
    cli.write_result(a.out, "more_charts", __doc__, a.truth, argv, rows, extra=extra)
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
