"""How much of the phone's map the calibration flags as extrapolated (`aat_deploy.calibrate.measured_mask`), and its
error there and elsewhere (issue 33, part a: 0.47-0.49 D beyond the farthest tile against 0.08 D within).

    OMP_NUM_THREADS=1 python -m benchmarks.probes.measured_share [--variants ...] [--out results/measured_share.json]

bench_calibrate's `cellphone_near` development sweeps (cached; the nominal lens, the hand-chosen copy and the three
declared random copies of seed 2026; no held-out scene), fitted as part a fits them; over part a's 10 "inside" focus
settings and the 8-frame depth schedule: the share of pixel-frames flagged, and the map's RMS error against the
truth on the flagged and the measured ones (D).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks import RESULTS

VARIANTS = ("nominal", "copy", "copy_s2026_0", "copy_s2026_1", "copy_s2026_2")


def run(variant: str) -> dict:
    from aat_deploy.calibrate import in_focus_diopters, measured_mask
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT

    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"]), "soft leaves", variant)
    s = rig.setup
    eff = B.effects_for(s, v)
    scale = B.SCALE if any(e.startswith("focus_metadata") for e in eff) else 1.0
    sweeps = [B.sweep(rig, v, i, lambda *_: None) for i in range(len(s.distances_m))]
    cal = B.fit(rig, v, sweeps, 0).calibration
    out = {"variant": variant, "field_radius_max": cal.best_focus.radius_max,
           "object_range_d": cal.fit.get("object_range_d")}
    for name, true_m in (("inside", s.inside()), ("schedule", s.schedule())):
        rep = true_m * scale
        d = in_focus_diopters(cal, rep, rig.h, rig.w)
        e = d - rig.truth(eff, true_m)
        m = measured_mask(cal, rep, rig.h, rig.w, d)
        rms = lambda sel: float(np.sqrt(np.mean(e[sel] ** 2))) if sel.any() else None
        out[name] = {"flagged_share": float(1 - m.mean()), "rms_all_d": rms(np.ones_like(m)),
                     "rms_measured_d": rms(m), "rms_flagged_d": rms(~m)}
    print(json.dumps(out), flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--out", default=str(RESULTS / "measured_share.json"))
    a = ap.parse_args(argv)
    if Path(a.out).exists():  # a committed result is never overwritten
        ap.error(f"{a.out}: exists (choose another --out)")
    rows = [run(v) for v in a.variants.split(",")]
    write_text_atomic(a.out, json.dumps({"what": __doc__.split("\n")[0], "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
