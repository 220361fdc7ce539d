"""Does the fitted distance of the phone's near chart depend on where the fit starts? (issue 33; `aat-calibrate fit
--distance-m ...,~D`): bench_calibrate's `cellphone_near` sweeps (cached), the 5.5 cm chart's tape value replaced
by each start, the fit's distance and part a's map RMS (inside, D) for each.

    OMP_NUM_THREADS=1 python -m benchmarks.probes.near_chart_start [--variant copy] [--starts-mm 50,53.22,55,58,62]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from benchmarks import RESULTS


def main(argv=None) -> int:
    from aat_deploy.calibrate.fit import fit_calibration
    from benchmarks import bench_calibrate as B

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", default="copy")
    ap.add_argument("--starts-mm", default="50,53.22,55,58,62")
    ap.add_argument("--out", default=str(RESULTS / "phone_near_chart_start.json"))
    a = ap.parse_args(argv)
    log = lambda m: print(m, file=sys.stderr, flush=True)
    setup = B.LENSES["cellphone_near"]
    rig = B.Rig(setup)
    ms = B.measured_setup(rig, a.variant, log)
    free = setup.fit_distance[0]
    eff = B.effects_for(setup, a.variant)
    rows = []
    for start in (float(v) / 1000 for v in a.starts_mm.split(",")):
        m2 = list(ms)
        m2[free] = dataclasses.replace(ms[free].at_distance(start, "tape"), fit_distance=True)
        res = fit_calibration(m2, n_boot=0)
        e = B.map_errors(rig, res.calibration, eff, setup.inside())["calibration"]
        rows.append({"start_m": start, "fitted_m": res.calibration.residuals["per_sweep"][free]["chart_distance_m"],
                     "family": res.calibration.focus_error.family, "map_rms_inside_d": e["rms_d"]})
        print(json.dumps(rows[-1]), flush=True)
    from aat_deploy.io.atomic import write_text_atomic

    write_text_atomic(Path(a.out), json.dumps({"variant": a.variant, "true_m": setup.distances_m[free],
                                                "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
