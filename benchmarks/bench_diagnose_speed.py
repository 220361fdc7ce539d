"""How long `aat-diagnose` takes at full frame: the fitted, reduced-resolution search against the grid search it
replaced (every candidate setting of every effect rendered at full resolution), in one run on the same captures
and model.

    python -m benchmarks.bench_diagnose_speed [ROOT] [--model M.onnx] [--psf PSF.onnx] [--rounds 3]
        [--grid-rounds 1]

Three timings, torch-free (as a runtime-only install; `chromatic` has no per-wavelength surrogates for the
shipped model and is skipped in all three):
- the complete diagnosis: every registered effect, `--rounds` greedy rounds, fitted search;
- the same-effect comparison: the effects the grid search had (aberrations, chromatic, focus_breathing,
  focus_metadata, noise, raw_pipeline, sensor_tilt, vignetting), `--grid-rounds` rounds, fitted search and grid
  search; their ratio is the speed-up (the grid search takes about 5 minutes a round for one 960 x 640 capture,
  so by default it runs one round). `--grid-rounds 0` skips it.
Prints the load average at the start and the end: the machine is shared, and the times are wall clock.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GRID_EFFECTS = ("aberrations", "chromatic", "focus_breathing", "focus_metadata", "noise", "raw_pipeline",
                "sensor_tilt", "vignetting")


def timed(root: Path, model: Path, psf: Path | None, search: str, rounds: int, effects, out: Path) -> dict:
    from aat_deploy.diagnose.search import DiagnoseConfig
    from aat_deploy.diagnose.session import run

    cfg = DiagnoseConfig(search=search, max_effects=rounds, effects=list(effects) if effects else None)
    t = time.time()
    res = run(root, model, out, psf=psf, force=True, quiet=True, torch_free=True, cfg=cfg)
    return {"seconds": time.time() - t, "captures": len(res["captures"]), "renders": res["twin_renders"],
            "named": [e["effect"] for e in res["ranked_effects"] or res["image_effects"]], "verdict": res["verdict"],
            "evaluated": len(res["effects_evaluated"])}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("root", nargs="?", default=str(ROOT / "captures" / "sample_rf50"))
    ap.add_argument("--model", default=str(ROOT / "models" / "reproduce" / "dff_dfvnet_aat.onnx"))
    ap.add_argument("--psf", default=None)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--grid-rounds", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "cache" / "bench_diagnose_speed"))
    a = ap.parse_args()
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    out = Path(a.out)
    load0 = os.getloadavg()
    rows = [("fit (all effects)", timed(Path(a.root), Path(a.model), a.psf, "fit", a.rounds, None, out / "fit_all"),
             "all", a.rounds)]
    if a.grid_rounds:
        for search in ("fit", "grid"):
            rows.append((f"{search} (grid's effects)", timed(Path(a.root), Path(a.model), a.psf, search, a.grid_rounds,
                                                              GRID_EFFECTS, out / f"{search}_grid_effects"),
                         "grid's", a.grid_rounds))
    load1 = os.getloadavg()
    print(f"\n{a.root}, model {a.model}; load average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end "
          f"(2 cores)\n")
    print("| search | effects | rounds | wall time (s) | per capture (s) | full-resolution optical renders | "
          "effects evaluated | named | verdict |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, r, eff, rounds in rows:
        print(f"| {label} | {eff} | {rounds} | {r['seconds']:.0f} | {r['seconds'] / r['captures']:.0f} | "
              f"{r['renders']} | {r['evaluated']} | {', '.join(r['named']) or '—'} | {r['verdict']} |")
    if a.grid_rounds:
        fit, grid = rows[1][1]["seconds"], rows[2][1]["seconds"]
        print(f"\nspeed-up of the fitted search on the grid's effects, {a.grid_rounds} round(s): "
              f"{grid / fit:.1f}x ({grid:.0f} s -> {fit:.0f} s)")


if __name__ == "__main__":
    main()
