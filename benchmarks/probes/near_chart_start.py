"""Does the fitted distance of the phone's near chart depend on where the fit starts? (issue 33; `aat-calibrate fit
--distance-m ...,~D`): bench_calibrate's `cellphone_near` sweeps (cached), the 5.5 cm chart's tape value replaced
by each start, the fit's distance and part a's map RMS (inside, D) for each.

--pose: the near chart's start from its marker pose instead (a bare `~`, no tape: `measure_sweep(distance_m=None,
fit_distance=True)`), against the benchmark's tape start, on the hand-chosen copy and (--copies K) the first K of
the phone's declared random copies (seed 2026). Two poses: with the focal length in pixels a user has from the EXIF
focal length and --sensor-mm (the virtual camera's), and from the chart's perspective alone (or its one-line
refusal).

    OMP_NUM_THREADS=1 python -m benchmarks.probes.near_chart_start [--variant copy] [--starts-mm 50,53.22,55,58,62]
    OMP_NUM_THREADS=1 python -m benchmarks.probes.near_chart_start --pose [--copies 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from benchmarks import RESULTS

COPY_SEED = 2026  # the phone's random copies: their seed and number, declared before any was rendered (f2eb611)
DECLARED_COPIES = 3


def fitted(rig, ms: list, free: int, effects: list[str]) -> dict:
    """The fit from these measured sweeps: the free chart's start and fitted distance (m), the family, part a's
    map RMS inside (D)."""
    from aat_deploy.calibrate.fit import fit_calibration
    from benchmarks import bench_calibrate as B

    res = fit_calibration(ms, n_boot=0)
    ps = res.calibration.residuals["per_sweep"][free]
    e = B.map_errors(rig, res.calibration, effects, rig.setup.inside())["calibration"]
    return {"start_m": round(ms[free].chart_distance_m, 6), "fitted_m": ps["chart_distance_m"],
            "start_from": ps.get("distance_start_from", "tape"), "family": res.calibration.focus_error.family,
            "map_rms_inside_d": e["rms_d"]}


def pose_start_rows(rig, variant: str, log) -> dict:
    """One copy: the near chart's fit from the benchmark's tape start, from its marker pose with the EXIF focal
    length and the sensor size, and from its marker pose with the focal length from the chart's perspective alone
    (its one-line refusal when the perspective does not give it within 10 %)."""
    from aat_deploy.calibrate.sweep import SweepError, measure_sweep
    from benchmarks import bench_calibrate as B

    setup = rig.setup
    free = setup.fit_distance[0]
    eff = B.effects_for(setup, variant)
    ms = B.measured_setup(rig, variant, log)
    sw = B.sweep(rig, variant, free, log)
    out = {"copy": setup.copy_name, "effects": eff, "true_m": setup.distances_m[free], "rows": {}}
    out["rows"]["tape"] = fitted(rig, ms, free, eff)
    log(f"  {setup.copy_name} tape: {json.dumps(out['rows']['tape'])}")
    for name, sensor in (("marker pose, EXIF focal length and --sensor-mm", B.sensor_mm(rig)),
                         ("marker pose, the chart's perspective", None)):
        try:
            m = measure_sweep(B.as_sweep(rig, sw, variant), sw["layout"], distance_m=None, sensor_mm=sensor,
                              measure=rig.measure, prefilter_px=rig.prefilter_px, fit_distance=True)
        except SweepError as e:
            out["rows"][name] = {"refused": str(e)}
            log(f"  {setup.copy_name} {name}: refused: {e}")
            continue
        m2 = list(ms)
        m2[free] = m
        row = fitted(rig, m2, free, eff)
        row["f_px"] = m.geometry.f_px
        row["f_px_true"] = rig.f_px
        # the pose is measured from the entrance pupil, which the fit places a focal length in front of the sensor
        # without --pupil-to-sensor-mm (as the tape rows): the lens's own distance, for what that moves the start
        row["pupil_to_sensor_mm"] = m.geometry.pupil_to_sensor_mm
        row["pupil_to_sensor_mm_true"] = rig.pupil
        row["notes"] = m.geometry.notes
        out["rows"][name] = row
        log(f"  {setup.copy_name} {name}: {json.dumps(row)}")
    return out


def pose_starts(rig, variant: str, n_copies: int, out_path: Path, log) -> int:
    from aat_deploy.io.atomic import write_text_atomic
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import elements
    from benchmarks import bench_calibrate as B
    from benchmarks import calibrate_copies as C

    res = {"setup": rig.setup.key, "variant": variant, "copy_seed": COPY_SEED, "copies": []}
    res["copies"].append(pose_start_rows(rig, variant, log))
    n_el = len(elements(load_lens(B.ROOT / rig.setup.lens)))
    for k in range(n_copies):
        res["copies"].append(pose_start_rows(
            rig.with_setup(C.copy_setup(rig.setup, COPY_SEED, C.draw_copy(rig.setup, n_el, COPY_SEED, k))), "copy", log))
    write_text_atomic(out_path, json.dumps(res, indent=1))
    print(pose_table(res))
    return 0


def pose_table(res: dict) -> str:
    """Markdown: per copy, each start (mm), the fitted distance (mm) and the map RMS inside (D)."""
    lines = ["| copy | start | start (mm) | fitted (mm) | map RMS inside (D) |", "|---|---|---|---|---|"]
    for c in res["copies"]:
        for name, r in c["rows"].items():
            if "refused" in r:
                lines.append(f"| {c['copy']} | {name} | refused: {r['refused']} | | |")
            else:
                lines.append(f"| {c['copy']} | {name} | {1000 * r['start_m']:.2f} | {1000 * r['fitted_m']:.2f} | "
                             f"{r['map_rms_inside_d']:.4f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    from benchmarks import bench_calibrate as B

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", default="copy")
    ap.add_argument("--starts-mm", default="50,53.22,55,58,62")
    ap.add_argument("--pose", action="store_true", help="the start from the chart's marker pose (a bare ~) against "
                    "the tape's (default --out results/phone_near_chart_pose_start.json)")
    ap.add_argument("--copies", type=int, default=0, help="with --pose, also the first K of the phone's declared "
                    f"random copies (seed {COPY_SEED}, at most {DECLARED_COPIES})")
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    log = lambda m: print(m, file=sys.stderr, flush=True)
    setup = B.LENSES["cellphone_near"]
    rig = B.Rig(setup)
    if a.pose:
        if not 0 <= a.copies <= DECLARED_COPIES:
            raise SystemExit(f"near_chart_start: --copies {a.copies}: the phone has {DECLARED_COPIES} declared random "
                             "copies (docs/calibration.md); no others are drawn")
        return pose_starts(rig, a.variant, a.copies, Path(a.out or RESULTS / "phone_near_chart_pose_start.json"), log)
    if a.copies:
        raise SystemExit("near_chart_start: --copies goes with --pose")
    ms = B.measured_setup(rig, a.variant, log)
    free = setup.fit_distance[0]
    eff = B.effects_for(setup, a.variant)
    rows = []
    for start in (float(v) / 1000 for v in a.starts_mm.split(",")):
        m2 = list(ms)
        m2[free] = dataclasses.replace(ms[free].at_distance(start, "tape"), fit_distance=True)
        rows.append(fitted(rig, m2, free, eff))
        print(json.dumps(rows[-1]), flush=True)
    from aat_deploy.io.atomic import write_text_atomic

    write_text_atomic(Path(a.out or RESULTS / "phone_near_chart_start.json"),
                      json.dumps({"variant": a.variant, "true_m": setup.distances_m[free], "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
