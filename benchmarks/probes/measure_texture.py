"""How much the focus measure's peak moves with the texture, per measure (issue 33: the phone lens's map cannot be
calibrated to 0.02 D while its peak depends on what the chart shows).

    python -m benchmarks.probes.measure_texture [--photos 7] [--out results/measure_texture.json]   # ~10 min once

A patch (112 px) at field radius 0 and 0.75 (on the diagonal) of the phone lens focused near 10 cm and of the
RF50 near 1 m, rendered through each lens's surrogate over a dense sweep (101 frames, +-5 px of blur) for the
chart's dead leaves and `--photos` training photographs (`calibrate_phone_offset.floor_stacks`, cached under
cache/phone_offset/); for each measure of `aat_deploy.focus.measures` listed here, where it peaks on each texture
(`floor_peaks`): the spread between textures (max - min and SD, D), the curve's width at half height, and how far
the chart sweep's step (1.39 px) moves the peak. Training photographs only: nothing here is a test scene.

With `--chart-fit`, the measure on the chart fit itself (bench_calibrate's nominal phone sweeps, noise on, and
sweeps twice as dense, `calibrate_phone_offset.part_step`; ~5 min on lane B): the map's RMS error by field zone
against a truth map calibrated with the same measure, and the tiles' peaks against it by chart and zone, for `mlap2` (lenses/best_focus/) and `narrowband` without
pre-filter (results/cellphone_map_narrowband.json, made by `aat-lens focus-map lenses/cellphone_asphere.json
--recalibrate lenses/best_focus/cellphone_asphere.json --psf models/psf_cellphone.onnx --calibrate-at
0.07,0.1,0.15,0.3,0.5 --sweep-d 5.5 --calibrate-radii 0,0.3,0.5,0.6,0.65,0.7,0.75,0.8,0.85,0.9,0.95
--calibrate-textures 12 --calibrate-measure narrowband --calibrate-prefilter-px 0 --out
results/cellphone_map_narrowband.json --force`, 3 min).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks import RESULTS
from benchmarks import bench_calibrate as bc
from benchmarks.bench_calibrate import ROOT
from benchmarks.probes.calibrate_phone_offset import floor_peaks, floor_stacks, part_step, part_tiles_vs_truth

SETTINGS = (("cellphone", 0.1, 0.0), ("cellphone", 0.1, 0.75), ("rf50", 1.0, 0.0), ("rf50", 1.0, 0.75))
# (measure, pyramid levels, pre-filter px): the runtime's measure and its 1 px pre-filter; `narrowband` is a
# band-pass itself, and a pre-filter tilts its band toward coarse detail (at 1 px it passes a tenth of its
# 0.35 cycles/px and most of its lower flank), so it is also run without one
VARIANTS = (("mlap2", 1, 1.0), ("multiscale", 3, 1.0), ("narrowband", 1, 1.0), ("narrowband", 1, 0.0))
# the chart fit with each measure and a truth map calibrated with it (None: the lens's own, the runtime's measure)
CHART_FITS = (("mlap2", 1.0, None), ("narrowband", 0.0, "results/cellphone_map_narrowband.json"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos", type=int, default=7, help="training photographs besides the chart's dead leaves")
    ap.add_argument("--variants", default=",".join(f"{m}:{lv}:{p:g}" for m, lv, p in VARIANTS),
                    help="measure:levels:prefilter_px, comma-separated")
    ap.add_argument("--chart-fit", type=float, default=None, metavar="STEP_PX",
                    help="also fit the nominal phone sweeps with each measure, the benchmark's and STEP_PX apart")
    ap.add_argument("--tiles", action="store_true", help="only the tiles' peaks against each measure's truth (2 min)")
    ap.add_argument("--out", default=str(RESULTS / "measure_texture.json"))
    a = ap.parse_args(argv)
    variants = [(v.split(":")[0], int(v.split(":")[1]), float(v.split(":")[2])) for v in a.variants.split(",")]
    rows = []
    for key, obj, rad in SETTINGS:
        rig, fd, stacks = floor_stacks(key, obj, radius=rad, photos=a.photos, cache=ROOT / "cache" / "phone_offset")
        print(f"  {key} at {obj:g} m, radius {rad:g}: {len(stacks)} textures", file=sys.stderr, flush=True)
        for meas, lev, pf in variants:
            r = floor_peaks(rig, fd, stacks, obj, measure=meas, levels=lev, prefilter_px=pf)
            t = r["textures"].values()
            r.update(lens=key, object_m=obj, radius=rad,
                     half_width_mean_d=float(np.mean([v["half_max_width_d"] for v in t])),
                     coarse_shift_max_d=float(max(max(abs(v["coarse_max_d"] - v["dense_peak_d"]),
                                                      abs(v["coarse_min_d"] - v["dense_peak_d"])) for v in t)))
            rows.append(r)
    fits = []
    if a.chart_fit or a.tiles:
        for meas, pf, truth_map in CHART_FITS:
            steps = {} if a.tiles else part_step(a.chart_fit, measure=meas, prefilter_px=pf, truth_map=truth_map)
            for label, r in steps.items():
                fits.append({"sweeps": label, **r})
                print(f"  chart fit, {meas}, {label} sweeps: {r['rms_d']:.3f} D", file=sys.stderr, flush=True)
            # where its tiles' peaks lie against its truth, by chart and field zone (the benchmark's sweeps)
            rig = bc.Rig(bc.LENSES["cellphone"], truth_map, meas, pf)
            sweeps = [bc.sweep(rig, "nominal", i, lambda m: None) for i in range(3)]
            for t in part_tiles_vs_truth(rig, bc.measures(rig, sweeps, "nominal")):
                fits.append({"tiles_vs_truth": True, "measure": meas, **t})
    from aat_deploy.io.atomic import write_text_atomic

    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(a.out), json.dumps({"photos": a.photos, "rows": rows, "chart_fits": fits}, indent=1))
    print(table(rows))
    if fits:
        print("\n| measure, pre-filter | nominal sweeps | step (px / D) | family | tile residual RMS (D) | map RMS inside "
              "(D) | centre / middle / outer (D) |\n|---|---|---|---|---|---|---|")
        for f in (f for f in fits if "tiles_vs_truth" not in f):
            z = f["zone_rms_d"]
            print(f"| {f['measure']}, {f['prefilter_px']:g} px | {f['sweeps']} | {f['step_px']:g} / {f['step_d']:.2f} | "
                  f"{f['family']} | {f['residual_rms_d']:.3f} | {f['rms_d']:.3f} | {z['centre']:.3f} / "
                  f"{z['middle']:.3f} / {z['outer']:.3f} |")
        print("\n| measure | chart (m) | field radius | tiles | tile peak - its truth's: mean (SD) (D) |\n|---|---|---|---|---|")
        for f in (f for f in fits if "tiles_vs_truth" in f):
            print(f"| {f['measure']} | {f['chart_m']:g} | {f['zone'][0]:g}-{min(f['zone'][1], 1):g} | {f['tiles']} | "
                  f"{f['mean_d']:+.3f} ({f['sd_d']:.3f}) |")
    return 0


def table(rows: list[dict]) -> str:
    out = ["| lens | object | field radius | measure (levels), pre-filter | peak - object, mean over textures (D) | spread "
           "max - min (D) | SD (D) | half-height width (D) | chart step moves the peak by up to (D) |",
           "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        peaks = [v["dense_peak_d"] for v in r["textures"].values()]
        lev = f" ({r['levels']})" if r["measure"] == "multiscale" else ""
        out.append(f"| {r['lens']} ({r['blur_px_per_d']:.2f} px/D) | {r['object_m']:g} m | {r['radius']:g} | "
                   f"{r['measure']}{lev}, {r['prefilter_px']:g} px | {np.mean(peaks):+.3f} | {r['dense_spread_d']:.3f} | {r['dense_sd_d']:.3f} | "
                   f"{r['half_width_mean_d']:.3f} | {r['coarse_shift_max_d']:.3f} |")
    return "\n".join(out)


if __name__ == "__main__":
    raise SystemExit(main())
