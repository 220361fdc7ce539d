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

    python -m benchmarks.bench_diagnose_speed --against COMMIT [--after COMMIT] [ROOT] [--model M.onnx] [--repeat 2]
    python -m benchmarks.bench_diagnose_speed --profile [ROOT] [--model M.onnx]

Before/after (issue 32's speed work): the whole `aat-diagnose ROOT --model M --torch-free` (every effect, 3 rounds) as
it ran at COMMIT (its `aat_deploy/` exported with `git archive` into cache/bench_ref/<commit>/,
`bench_big_capture.reference_tree`) and as this checkout runs it, each in a fresh process exactly as a user runs
it, `--repeat` times interleaved (before, after, before, ...). The table gives each run's wall time, CPU time
(user + system, all threads: less sensitive to other jobs) and the load average at its start and end, and the
ratios of the best runs; then whether the two diagnoses agree (verdict, named effects and their settings, the focus
family, every evaluated effect's settings, closeness and share).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
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


# `python -m aat_deploy.cli.diagnose ARGS` as a user runs it
DIAGNOSE = """import runpy, sys
sys.argv[0] = "aat-diagnose"
runpy.run_module("aat_deploy.cli.diagnose", run_name="__main__", alter_sys=True)
"""


def diagnose_process(code_root: Path, root: Path, model: Path, lens: Path, psf: Path, out: Path) -> dict:
    """One `aat-diagnose` process running the code under code_root: wall and CPU seconds (the process's, all its
    threads), the load average at its start and end, and its diagnosis.json."""
    from benchmarks.timing import timed_process

    env = {**os.environ, "PYTHONPATH": str(code_root), "OMP_WAIT_POLICY": "PASSIVE"}
    cmd = [sys.executable, "-c", DIAGNOSE, str(root), "--model", str(model), "--lens", str(lens), "--psf", str(psf),
           "--out", str(out), "--torch-free", "--force"]
    return {**timed_process(cmd, code_root, env), "result": json.loads((out / "diagnosis.json").read_text())}


def _round(x, digits: int = 6):
    """Numbers to `digits` significant digits inside nested lists and dicts (float32-rounding differences of the
    renderer's FFTs must not count as a different diagnosis)."""
    if isinstance(x, float):
        return float(f"{x:.{digits}g}") if math.isfinite(x) else x
    if isinstance(x, dict):
        return {k: _round(v, digits) for k, v in x.items()}
    if isinstance(x, list):
        return [_round(v, digits) for v in x]
    return x


def compare(a: dict, b: dict) -> list[tuple[str, str]]:
    """(what, "same" or the two values) of the parts of two diagnoses a user reads."""
    def named(r):
        return [(e["effect"], e["params"]) for e in r["ranked_effects"] or r["image_effects"]]

    def evaluated(r, key):
        return [(e["effect"], e["round"], _round(e.get(key), 3)) for e in r["effects_evaluated"]]

    focus = (lambda r: (r["focus"] or {}).get("family"), lambda r: _round((r["focus"] or {}).get("params"), 4))
    rows = [("verdict", lambda r: r["verdict"]), ("causes", lambda r: r["causes"]), ("named effects and settings", named),
            ("focus family", focus[0]), ("focus settings", focus[1]),
            ("evaluated effects' settings", lambda r: evaluated(r, "params")),
            ("evaluated effects' closeness (3 digits)", lambda r: evaluated(r, "closeness")),
            ("evaluated effects' share of the gap (3 digits)", lambda r: evaluated(r, "share_of_gap")),
            ("gap (m, 3 digits)", lambda r: _round(r["gap"]["gap_m"], 3))]
    return [(what, "same" if f(a) == f(b) else f"{f(a)} -> {f(b)}") for what, f in rows]


def against(a) -> None:
    """Before (a.against's code) and after (this checkout), interleaved, `a.repeat` times each."""
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.infer.model import DfFModel
    from benchmarks.bench_big_capture import reference_tree

    model = Path(a.model).resolve()
    lens_obj, lens = find_lens(DfFModel(model), None)
    psf = Path(a.psf) if a.psf else find_surrogate(lens_obj, None).path
    ref = reference_tree(a.against)
    after = reference_tree(a.after) if a.after else ROOT
    out = Path(a.out) / "against"
    runs: dict[str, list] = {"before": [], "after": []}
    for k in range(a.repeat):
        for name, code in (("before", ref), ("after", after)):
            r = diagnose_process(code, Path(a.root).resolve(), model, lens.resolve(), Path(psf).resolve(),
                                 out / f"{name}_{k}")
            runs[name].append(r)
            print(f"{name} #{k + 1}: {r['wall_s']:.0f} s wall, {r['cpu_s']:.0f} s CPU, load {r['load']:.1f} -> "
                  f"{r['load_end']:.1f}", flush=True)
    best = {k: min(v, key=lambda r: r["wall_s"]) for k, v in runs.items()}
    print(f"\n{a.root}, model {model.name}, torch-free, every effect, 3 rounds; before = {ref.name[:7]}, after = "
          f"{after.name[:7] if a.after else 'this checkout'}; 2 cores\n")
    print("| code | run | wall time (s) | CPU time (s) | load average at start -> end |")
    print("|---|---|---|---|---|")
    for name, rs in runs.items():
        for k, r in enumerate(rs):
            print(f"| {name} | {k + 1} | {r['wall_s']:.0f} | {r['cpu_s']:.0f} | {r['load']:.1f} -> "
                  f"{r['load_end']:.1f} |")
    b, f = best["before"], best["after"]
    print(f"\nbest runs: wall {b['wall_s']:.0f} s -> {f['wall_s']:.0f} s ({b['wall_s'] / f['wall_s']:.2f}x faster), "
          f"CPU {b['cpu_s']:.0f} s -> {f['cpu_s']:.0f} s ({b['cpu_s'] / f['cpu_s']:.2f}x less)\n")
    print("| part of the diagnosis (last runs) | before -> after |")
    print("|---|---|")
    for what, verdict in compare(runs["before"][-1]["result"], runs["after"][-1]["result"]):
        print(f"| {what} | {verdict} |")


# (label, pstats pattern: file suffix and function name) of the stages `--profile` reports; they nest and overlap
STAGES = (
    ("the whole run (session.run)", "diagnose/session.py", "run"),
    ("optical renders, full resolution and binned (TwinRenderer.optical)", "diagnose/twin.py", "optical"),
    ("twins scored at full resolution (render, model, distances: score_twin)", "diagnose/gap.py", "score_twin"),
    ("model inference (DfFModel.infer)", "infer/model.py", "infer"),
    ("focus_metadata's fit (fit_focus_metadata)", "diagnose/fitters.py", "fit_focus_metadata"),
    ("... its binning correction re-anchored (anchors.reanchored_sweep)", "diagnose/anchors.py", "reanchored_sweep"),
    ("... its family fits and bootstrap (focusfit.fit_metadata)", "diagnose/focusfit.py", "fit_metadata"),
    ("lens_tolerance's fit (fit_lens_tolerance)", "diagnose/fitters.py", "fit_lens_tolerance"),
    ("sensor_tilt's fit (fit_sensor_tilt)", "diagnose/fitters.py", "fit_sensor_tilt"),
    ("... their amounts refitted on binned twins (refine_amount)", "diagnose/fitters.py", "refine_amount"),
    ("misalignment's fit (fit_misalignment)", "diagnose/fitters.py", "fit_misalignment"),
    ("noise's fit (fit_noise)", "diagnose/fitters.py", "fit_noise"),
    ("screening at reduced resolution (_screen)", "diagnose/search.py", "_screen"),
    ("noise draws (poisson_gaussian)", "effects/noise.py", "poisson_gaussian"),
    ("report, figures, recording (report.*)", "diagnose/report.py", None),
)


def profile(a) -> None:
    """Where one whole diagnosis (this checkout, every effect, `--rounds` rounds) spends its time: cProfile of the
    main thread (frames render in 2 worker threads: a render counts in full where it is waited for), cumulative
    seconds of each stage; then one full-resolution optical stack rendered single-threaded, by function."""
    import cProfile
    import pstats

    from aat_deploy.diagnose.search import DiagnoseConfig
    from aat_deploy.diagnose.session import run

    out = Path(a.out) / "profile"
    prof = cProfile.Profile()
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    prof.enable()
    res = run(Path(a.root), Path(a.model), out, psf=a.psf, force=True, quiet=True, torch_free=True,
              cfg=DiagnoseConfig(max_effects=a.rounds))
    prof.disable()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    st = pstats.Stats(prof).stats  # {(file, line, name): (cc, nc, tt, ct, callers)}
    print(f"\n{a.root}, model {Path(a.model).name}, torch-free, {a.rounds} rounds: {wall:.0f} s wall, {cpu:.0f} s CPU "
          f"(process), load {load0:.1f} -> {os.getloadavg()[0]:.1f}; named {[e['effect'] for e in res['ranked_effects']]}, "
          f"{res['twin_renders']} full-resolution optical renders\n")
    print("| stage | calls | cumulative wall time (s) | share of the run |")
    print("|---|---|---|---|")
    for label, path, name in STAGES:
        hits = [(v[1], v[3]) for (f, _, n), v in st.items() if f.endswith(path) and (n == name or name is None)]
        if name is None:  # a module: its top-level calls from elsewhere only
            hits = [(v[1], v[3]) for (f, _, n), v in st.items() if f.endswith(path)
                    and not any(c[0].endswith(path) for c in v[4])]
        calls, cum = sum(h[0] for h in hits), sum(h[1] for h in hits)
        print(f"| {label} | {calls} | {cum:.1f} | {100 * cum / wall:.0f} % |")
    render_profile(a)


def render_profile(a) -> None:
    """One full-resolution optical stack of the capture (the base twin), rendered in one thread: its time by
    function (the FFTs' share)."""
    import cProfile
    import pstats

    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.infer.model import DfFModel

    model = DfFModel(a.model, threads=2)
    lens, _ = find_lens(model, None)
    twins = make_renderer(model, lens, find_surrogate(lens, a.psf), torch_free=True)
    twins.workers = 1
    cap = load_capture_data(Path(a.root), model)
    prof = cProfile.Profile()
    t0 = time.process_time()
    prof.enable()
    twins.linear(cap, cap.aif_linear, [])
    prof.disable()
    total = time.process_time() - t0
    st = pstats.Stats(prof).stats
    groups = {"FFTs (pocketfft)": ("pocketfft", "_pocketfft", "scipy/fft", "numpy/fft"),
              "PSF surrogate (onnxruntime)": ("onnxruntime",)}
    print(f"\none full-resolution optical stack ({cap.frames.shape[0]} frames), one thread: {total:.1f} s CPU")
    print("| part | self time (s) | share |")
    print("|---|---|---|")
    for label, keys in groups.items():
        t = sum(v[2] for (f, _, n), v in st.items() if any(k in f or k in n for k in keys))
        print(f"| {label} | {t:.1f} | {100 * t / total:.0f} % |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("root", nargs="?", default=str(ROOT / "captures" / "sample_rf50"))
    ap.add_argument("--model", default=str(ROOT / "models" / "reproduce" / "dff_dfvnet_aat.onnx"))
    ap.add_argument("--psf", default=None)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--grid-rounds", type=int, default=1)
    ap.add_argument("--against", metavar="COMMIT", help="before/after: the whole diagnosis at COMMIT and here")
    ap.add_argument("--repeat", type=int, default=2, help="with --against: runs of each, interleaved")
    ap.add_argument("--after", metavar="COMMIT", help="with --against: 'after' is COMMIT's code (exported as "
                    "'before' is), not this checkout's (which may change while the benchmark runs)")
    ap.add_argument("--out", default=str(ROOT / "cache" / "bench_diagnose_speed"))
    ap.add_argument("--profile", action="store_true", help="where one whole diagnosis spends its time (cProfile)")
    a = ap.parse_args()
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    if a.profile:
        profile(a)
        return
    if a.against:
        against(a)
        return
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
