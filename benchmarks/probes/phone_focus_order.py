"""Would a field term of higher order in focus help the phone? (issue 33, part a): bench_calibrate's `cellphone_near`
sweeps (cached; four charts, so a cubic in focus is possible), fitted with the order in focus chosen by
cross-validation (at most quadratic, `model.fit_model`) and forced to 1, 2 and 3 (the spatial order then chosen by
cross-validation), with part a's map RMS inside and on the schedule, by field radius.

    OMP_NUM_THREADS=1 python -m benchmarks.probes.phone_focus_order [--variant copy]   # 1 min, sweeps cached
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from benchmarks import RESULTS


def main(argv=None) -> int:
    from aat_deploy.calibrate.fit import fit_calibration
    from benchmarks import bench_calibrate as B

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", default="copy")
    ap.add_argument("--out", default=str(RESULTS / "phone_focus_order.json"))
    a = ap.parse_args(argv)
    log = lambda m: print(m, file=sys.stderr, flush=True)
    setup = B.LENSES["cellphone_near"]
    rig = B.Rig(setup)
    ms = B.measured_setup(rig, a.variant, log)
    eff = B.effects_for(setup, a.variant)
    rows = []
    for fd in (None, 1, 2, 3):
        res = fit_calibration(ms, n_boot=0, focus_degree=fd)
        e = B.map_errors(rig, res.calibration, eff, setup.inside())["calibration"]
        es = B.map_errors(rig, res.calibration, eff, setup.schedule())["calibration"]
        rows.append({"focus_degree_asked": fd, "degree": res.model.degree, "radial": res.model.radial,
                     "focus_degree": res.model.focus_degree, "family": res.calibration.focus_error.family,
                     "residual_rms_d": res.calibration.residuals["rms_d"], "inside_rms_d": e["rms_d"],
                     "schedule_rms_d": es["rms_d"], "radius_rms_d": e["radius_rms_d"]})
        print(json.dumps({k: v for k, v in rows[-1].items() if k != "radius_rms_d"}), flush=True)
    from aat_deploy.io.atomic import write_text_atomic

    write_text_atomic(Path(a.out), json.dumps({"setup": setup.key, "variant": a.variant, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
