"""Every effect's best fit, closeness and share, round by round, for one capture set of the diagnosis benchmark
(`bench_diagnose.py`): what BENCHMARKS.md quotes for the two-effect set.

    python -m benchmarks.diagnose_one_set cache/bench_diagnose/sets_v2/set21 [--model aat|thin] [--rounds 3]
    python -m benchmarks.diagnose_one_set cache/bench_diagnose/sets_v2/set21 --stored   # the benchmark's own answer
    python -m benchmarks.diagnose_one_set cache/bench_diagnose_shipped/sets_v3/set20 --stored   # v3: verdicts too
    python -m benchmarks.diagnose_one_set cache/bench_diagnose_shipped/sets_v3/set03 --variant shipped --torch-free \
        --rounds 1   # diagnose a v3 set again with the current code

--stored prints the `diagnosis.json` that `bench_diagnose.py` left in the set's folder instead of diagnosing again.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from aat_deploy.diagnose.inputs import load_capture_data
from aat_deploy.diagnose.lookup import find_lens, find_surrogate
from aat_deploy.diagnose.search import DiagnoseConfig, diagnose
from aat_deploy.diagnose.session import make_renderer
from aat_deploy.infer.model import DfFModel

ROOT = Path(__file__).resolve().parents[1]
SETUP = ROOT / "cache" / "bench_diagnose"


def model_files(variant: str, key: str) -> tuple[Path, Path, Path]:
    """(model, lens, PSF surrogate) of a benchmark variant (bench_diagnose.variant_files)."""
    if variant == "shipped":
        return (ROOT / "models" / f"dff_dfvnet_{key}.onnx", ROOT / "lenses" / "canon_rf50mm_f1.8.json",
                ROOT / "models" / "psf_rf50.onnx")
    setup = SETUP if variant == "full" else ROOT / "cache" / f"bench_diagnose_{variant}"
    return setup / f"diag_dfv_{key}.onnx", setup / "rf50_288x192.json", setup / "psf.onnx"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("folder", help="a capture set (folder of capture folders)")
    ap.add_argument("--model", choices=["aat", "thin"], default="aat")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--effects", help="only these effects (comma-separated)")
    ap.add_argument("--stored", action="store_true", help="print the benchmark's stored diagnosis.json")
    ap.add_argument("--variant", choices=["full", "crop4", "shipped"], default="full", help="the set's models")
    ap.add_argument("--torch-free", action="store_true", help="torch-free twins (bench_diagnose --torch-free)")
    a = ap.parse_args()
    if a.stored:
        show(json.loads((Path(a.folder) / "diagnosis.json").read_text()))
        return
    model, lens_path, psf = model_files(a.variant, a.model)
    m = DfFModel(model, threads=2)
    lens, _ = find_lens(m, lens_path)
    twins = make_renderer(m, lens, find_surrogate(lens, psf), a.torch_free)
    caps = [load_capture_data(p, m) for p in sorted(Path(a.folder).iterdir()) if p.is_dir()]
    cfg = DiagnoseConfig(n_boot=300, max_effects=a.rounds, effects=a.effects.split(",") if a.effects else None)
    res, _, _ = diagnose(m, twins, caps, cfg)
    show(res)


def show(res: dict) -> None:
    g = res["gap"]
    print(f"gap {g['gap_m']:+.3f} m ({g['ci_low']:+.3f} … {g['ci_high']:+.3f}), significant: {res['gap_significant']}")
    print("| round | effect | fitted settings | closeness (95 %) | image closeness | lighting closeness (95 %) | "
          "share of gap (95 %) | explains the gap |")
    print("|---|---|---|---|---|---|---|---|")
    for e in res["effects_evaluated"]:
        params = str(e["params"] or "—")
        params = params if len(params) <= 90 else params[:87] + "..."  # misalignment: per-frame shifts
        if e.get("closeness") is None:  # v3: fitted, nothing found or not scored at full resolution
            print(f"| {e['round']} | {e['effect']} | {params} | — | — | — | — | {e.get('note') or ''} |")
            continue
        share = "—" if e["share_of_gap"] is None else f"{e['share_of_gap']:.2f} ({e['ci_low']:.2f} … {e['ci_high']:.2f})"
        bri = e.get("brightness_closeness_ci")
        lit = "—" if bri is None else f"{e['brightness_closeness']:.3f} ({bri[0]:.3f} … {bri[1]:.3f})"
        ci = e.get("closeness_ci")
        close = f"{e['closeness']:.3f}" + (f" ({ci[0]:.3f} … {ci[1]:.3f})" if ci else "")
        img = "—" if e.get("image_closeness") is None else f"{e['image_closeness']:.3f}"
        explains = {True: "yes", False: "no", None: "—"}[e.get("explains_gap")]
        print(f"| {e['round']} | {e['effect']} | {params} | {close} | {img} | {lit} | {share} | {explains} |")
    print("named:", [e["effect"] for e in res["ranked_effects"]], "seen:", [e["effect"] for e in res["image_effects"]])
    if "verdict" in res:  # v3
        u = res.get("unexplained_share") or {}
        print(f"verdict: {res['verdict']}; causes: {res.get('causes')}; unexplained share: "
              + ("—" if u.get("share") is None else f"{u['share']:.2f} ({u['ci_low']:.2f} … {u['ci_high']:.2f})"))
        if res.get("focus"):
            f = res["focus"]
            print(f"focus metadata: family {f['family']}, settings {f['params']}, support {f['support']}")

if __name__ == "__main__":
    main()
