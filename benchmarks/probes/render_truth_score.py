"""Part a of the phone against the render-consistent truth (issue 33; docs/calibration.md, "A render-consistent truth
map"): the same fits scored against the best-focus map (the benchmark's truth until now) and against a render-truth
map (`benchmarks/render_truth_map.py`), paired, with the fit's own error against each.

    OMP_NUM_THREADS=1 python -m benchmarks.probes.render_truth_score --truth results/render_truth_map_cellphone.json \
        [--variants nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2] [--no-ideal] [--out results/...json]

bench_calibrate's `cellphone_near` development sweeps (cached; the nominal lens, the hand-chosen copy and the three
declared random copies of seed 2026; no held-out scene), fitted as part a fits them (`bench_calibrate.fit`, no
bootstrap: the map is the point fit's). Per variant and truth, over part a's 10 "inside" settings (7-18 cm) and the
8-frame depth schedule (0.07-0.5 m): the calibration's RMS and p95 |error| (D) overall, within the farthest tile's
radius, where the calibration measured and where it flags extrapolation (`measured_mask`), where the render truth is
between its points, and by field radius; the prescription's map and the thin lens beside it. With ideal tiles
(`phone_map_budget.run_variant`: the fit's counted tiles each peaking exactly where that truth has its object in
focus) the fit's own error against that truth, within the tiles' radius. A copy's render truth applies the nominal
lens's points at each pixel's own focus, as the benchmark's truth does (`Rig.truth`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic

VARIANTS = ("nominal", "copy", "copy_s2026_0", "copy_s2026_1", "copy_s2026_2")


def _cal_stats(e: dict) -> dict:
    keep = ("rms_d", "p95_d", "radius_rms_d", "radius_mean_d")
    return {k: v for k, v in e.items() if k in keep or k.endswith(("_share", "_rms_d", "_p95_d"))}


def run(variant: str, truth: str, ideal: bool, log) -> dict:
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT

    out = {"variant": variant, "truths": {}}
    rigs = {"best-focus map": CT.rig_for(B.Rig(B.LENSES["cellphone_near"]), "soft leaves", variant),
            "render truth": CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth), "soft leaves", variant)}
    rig, v = rigs["best-focus map"]
    s = rig.setup
    eff = B.effects_for(s, v)
    sweeps = [B.sweep(rig, v, i, log) for i in range(len(s.distances_m))]
    res = B.fit(rig, v, sweeps, 0)
    cal = res.calibration
    out["fit"] = {"family": cal.focus_error.family, "degree": res.model.degree, "radial": res.model.radial,
                  "focus_degree": res.model.focus_degree, "tiles": cal.residuals["tiles"],
                  "radius_max": cal.best_focus.radius_max}
    for tname, (r, _) in rigs.items():
        t = {}
        for part, true_m in (("inside", s.inside()), ("schedule", s.schedule())):
            e = B.map_errors(r, cal, eff, true_m)
            t[part] = {"calibration": _cal_stats(e["calibration"]),
                       "prescription map": {"rms_d": e["prescription map"]["rms_d"],
                                            "p95_d": e["prescription map"]["p95_d"]},
                       "thin lens": {"rms_d": e["thin lens"]["rms_d"], "p95_d": e["thin lens"]["p95_d"]}}
        out["truths"][tname] = t
        c = t["inside"]["calibration"]
        log(f"{variant} vs {tname}: inside {c['rms_d']:.4f} (p95 {c['p95_d']:.4f}), within the tiles "
            f"{c['within_tiles_rms_d']:.4f}, measured {c['cal_measured_rms_d']:.4f}")
    # the two truths' difference over the same pixel-frames (inside)
    a = rigs["best-focus map"][0].truth(eff, s.inside())
    b = rigs["render truth"][0].truth(eff, s.inside())
    ok = rigs["render truth"][0].truth_measured(eff, s.inside())
    d = b - a
    out["render_minus_map_inside"] = {"rms_d": float(np.sqrt(np.mean(d ** 2))), "mean_d": float(d.mean()),
                                      "rms_truth_measured_d": float(np.sqrt(np.mean(d[ok] ** 2))),
                                      "truth_measured_share": float(ok.mean())}
    if ideal:
        from benchmarks.probes import phone_map_budget as P

        out["ideal_tiles"] = {}
        for tname, (r, vv) in rigs.items():
            pv = P.run_variant(r, vv, {tname: None}, log)
            sc = pv["scores"][tname]
            out["ideal_tiles"][tname] = {k: sc[k] for k in ("measured, held beyond the tiles",
                                                            "ideal tiles, held beyond the tiles") if k in sc}
            out["ideal_tiles"][tname]["tile_bias"] = pv["tile_bias"]
            out["ideal_tiles"][tname]["tile_bias_rms_d"] = pv["tile_bias_rms_d"]
            out["ideal_tiles"][tname]["fits"] = pv["fits"]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--truth", required=True, help="a render-truth map (aat-render-truth-map-v1; a repo path)")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--no-ideal", action="store_true", help="skip the ideal tiles (the fit's own error)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    if Path(a.out).exists():  # a committed result is never overwritten
        ap.error(f"{a.out}: exists (choose another --out)")
    bad = [v for v in a.variants.split(",") if v not in VARIANTS]
    if bad:  # before any variant's sweeps: a typo late in the list would lose the earlier ones' minutes
        ap.error(f"--variants: {', '.join(bad)} not of {', '.join(VARIANTS)}")
    from benchmarks.render_truth_map import load_or_exit

    load_or_exit(a.truth, "render_truth_score")
    log = lambda m: print(m, file=sys.stderr, flush=True)
    rows = [run(v, a.truth, not a.no_ideal, log) for v in a.variants.split(",")]
    write_text_atomic(a.out, json.dumps({"what": __doc__.split("\n")[0], "truth": a.truth, "rows": rows}, indent=1,
                                        default=float))
    print(table(rows))
    return 0


def table(rows: list[dict]) -> str:
    out = ["| variant | truth | inside RMS / p95 | within the tiles' radius RMS / p95 | calibration-measured RMS / p95 "
           "(share) | flagged RMS (share) | render truth between its points: RMS (share) | schedule RMS / p95 | "
           "prescription map, inside | ideal tiles (the fit's own): within the tiles' hull (all) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for t, v in r["truths"].items():
            c, sc = v["inside"]["calibration"], v["schedule"]["calibration"]
            tm = (f"{c['truth_measured_rms_d']:.4f} ({100 * c['truth_measured_share']:.1f} %)"
                  if "truth_measured_rms_d" in c else "-")
            it = r.get("ideal_tiles", {}).get(t, {}).get("ideal tiles, held beyond the tiles")
            itv = "-" if not it else f"{it['covered_rms_d']:.4f} (all {it['rms_d']:.4f})"
            out.append(f"| {r['variant']} | {t} | {c['rms_d']:.4f} / {c['p95_d']:.4f} | {c['within_tiles_rms_d']:.4f} / "
                       f"{c['within_tiles_p95_d']:.4f} | {c['cal_measured_rms_d']:.4f} / {c['cal_measured_p95_d']:.4f} "
                       f"({100 * c['cal_measured_share']:.1f} %) | {c['cal_flagged_rms_d']:.4f} "
                       f"({100 * c['cal_flagged_share']:.1f} %) | {tm} | {sc['rms_d']:.4f} / {sc['p95_d']:.4f} | "
                       f"{v['inside']['prescription map']['rms_d']:.4f} | {itv} |")
    return "\n".join(out)


if __name__ == "__main__":
    sys.exit(main())
