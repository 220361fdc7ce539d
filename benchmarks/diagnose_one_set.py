"""Every effect's best fit, closeness and share, round by round, for one capture set of the diagnosis benchmark
(`bench_diagnose.py`): what BENCHMARKS.md quotes for the two-effect set.

    python benchmarks/diagnose_one_set.py cache/bench_diagnose/sets_v2/set21 [--model aat|thin] [--rounds 3]
    python benchmarks/diagnose_one_set.py cache/bench_diagnose/sets_v2/set21 --stored   # the benchmark's own answer

--stored prints the `diagnosis.json` that `bench_diagnose.py` left in the set's folder instead of diagnosing again.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from aat_deploy.diagnose.inputs import load_capture_data
from aat_deploy.diagnose.search import DiagnoseConfig, diagnose
from aat_deploy.diagnose.session import make_renderer
from aat_deploy.model import DfFModel
from aat_deploy.diagnose.lookup import find_lens, find_surrogate

SETUP = Path(__file__).resolve().parents[1] / "cache" / "bench_diagnose"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("folder", help="a capture set (folder of capture folders)")
    ap.add_argument("--model", choices=["aat", "thin"], default="aat")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--effects", help="only these effects (comma-separated)")
    ap.add_argument("--stored", action="store_true", help="print the benchmark's stored diagnosis.json")
    a = ap.parse_args()
    if a.stored:
        show(json.loads((Path(a.folder) / "diagnosis.json").read_text()))
        return
    m = DfFModel(SETUP / f"diag_dfv_{a.model}.onnx", threads=2)
    lens, _ = find_lens(m, SETUP / "rf50_288x192.json")
    twins = make_renderer(m, lens, find_surrogate(lens, SETUP / "psf.onnx"))
    caps = [load_capture_data(p, m) for p in sorted(Path(a.folder).iterdir()) if p.is_dir()]
    cfg = DiagnoseConfig(n_boot=300, max_effects=a.rounds, effects=a.effects.split(",") if a.effects else None)
    res, _, _ = diagnose(m, twins, caps, cfg)
    show(res)


def show(res: dict) -> None:
    g = res["gap"]
    print(f"gap {g['gap_m']:+.3f} m ({g['ci_low']:+.3f} … {g['ci_high']:+.3f}), significant: {res['gap_significant']}")
    print("| round | effect | fitted settings | closeness (95 %) | lighting closeness (95 %) | share of gap (95 %) |")
    print("|---|---|---|---|---|---|")
    for e in res["effects_evaluated"]:
        share = "—" if e["share_of_gap"] is None else f"{e['share_of_gap']:.2f} ({e['ci_low']:.2f} … {e['ci_high']:.2f})"
        bri = e.get("brightness_closeness_ci")
        lit = "—" if bri is None else f"{e['brightness_closeness']:.3f} ({bri[0]:.3f} … {bri[1]:.3f})"
        print(f"| {e['round']} | {e['effect']} | {e['params']} | {e['closeness']:.3f} "
              f"({e['closeness_ci'][0]:.3f} … {e['closeness_ci'][1]:.3f}) | {lit} | {share} |")
    print("named:", [e["effect"] for e in res["ranked_effects"]], "seen:", [e["effect"] for e in res["image_effects"]])


if __name__ == "__main__":
    main()
