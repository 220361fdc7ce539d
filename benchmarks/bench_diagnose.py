"""Withheld-effect benchmark of `aat-diagnose` (issue: diagnose the sim-to-real gap).

Capture sets are made with the virtual camera (DNG frames, EXIF focus, ground truth) by a simulator that has
one effect more than the model's own (or two, or none). The effect is drawn at random per set, with random
settings, and is not passed to the diagnosis. Scored: is the named cause the withheld effect (when the withheld
effect opens no significant gap, nothing may be blamed: then the first effect the diagnosis sees in the images,
`image_effects`, must be the withheld one); for two: are both named, in order of their share; for none: is the
gap called not significant and nothing named. With --retrain-steps, the model is fine-tuned with the named
effects (`aat-train --init ... --effects ...`) and the gap re-measured (remaining = gap after / gap before).

Models: benchmarks/diagnose_setup.py (RF50 at 288x192, small DFVNets, AAT and thin-lens simulators). The full
frame at 125 um pixels is the default; `chromatic` is sub-pixel there and runs on the centre crop at 31.25 um:

    python benchmarks/diagnose_setup.py [--variant crop4]
    python benchmarks/bench_diagnose.py [--sets-per-effect 3] [--captures 3] [--retrain-steps 0]
    python benchmarks/bench_diagnose.py --variant crop4 --effects chromatic

Results are appended to --out as JSON lines, one per set, and sets already there are skipped, so a stopped run
continues where it stopped (delete the file to start again). Capture sets are rendered once and kept;
`--verify-sets` (with the run's own arguments) re-renders each set's first scene with the current code and
compares the frames.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import torch

from diagnose_setup import VARIANTS, setup_dir

ROOT = Path(__file__).resolve().parents[1]
FOCUS = (0.5, 10.0, 8)
# Capture sets and results of this version of the plan (v2: TIFF frames unless raw_pipeline is withheld), inside
# the variant's setup folder; an older version's sets are not reused.
SETS, RESULTS = "sets_v2", "results_v2.jsonl"


def draw_params(name: str, rng: np.random.Generator) -> dict:
    """Random settings of a withheld effect (drawn per set; the diagnosis only sees the captures)."""
    if name == "noise":  # a dim scene or high ISO: weaker noise does not cost these models depth accuracy
        return {"full_well_e": float(np.exp(rng.uniform(np.log(250), np.log(1000))))}
    if name == "sensor_tilt":
        t = float(rng.choice([-1, 1]) * rng.uniform(0.6, 1.2))  # smaller tilts defocus the edges < 0.1 D here
        return {"tilt_x_deg": t, "tilt_y_deg": 0.0} if rng.random() < 0.5 else {"tilt_x_deg": 0.0, "tilt_y_deg": t}
    if name == "focus_metadata":
        return {"bias_d": float(rng.choice([-1, 1]) * rng.uniform(0.05, 0.12))}
    return {}


def scene(seed: int, h: int, w: int):
    from training.data.scenes import SceneConfig, procedural_scene

    rgb, depth = procedural_scene(SceneConfig(height=h, width=w, near_m=0.6, far_m=8.0), np.random.default_rng(seed))
    return np.ascontiguousarray(rgb.transpose(2, 0, 1)), depth  # (3, H, W) linear, (H, W) m


def make_set(folder: Path, lens, psf_src, base: list[str], withheld: list, scene_seeds: list[int], seed: int) -> None:
    """Render one capture set (one folder per scene) with the model's effects plus the withheld ones. A withheld
    `raw_pipeline` is the real thing: DNG frames (Bayer mosaic) that the runtime develops with LibRaw; otherwise
    frames are float TIFFs, exactly as rendered."""
    from training.camera.virtual import write_capture
    from training.render import effects as fx
    from training.render.schedule import FocusSchedule
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF

    raw = any(w.split(":")[0] == "raw_pipeline" for w in withheld)
    rendered = [w for w in withheld if w.split(":")[0] != "raw_pipeline"]
    sim = Simulator(lens, OnnxPSF.from_source(psf_src), fx.parse(base + rendered))
    focus = FocusSchedule(*FOCUS).distances()
    h, w = lens.sensor.height_px, lens.sensor.width_px
    for k, s in enumerate(scene_seeds):
        out = folder / f"scene{s}"
        if out.exists():
            continue
        rgb, depth = scene(s, h, w)
        st = sim.render_stack(torch.from_numpy(rgb), torch.from_numpy(depth), focus, rng=np.random.default_rng(seed + k))
        write_capture(out, st.frames.numpy(), st.focus_reported_m, lens, depth, rgb,
                      {"benchmark": "bench_diagnose", "withheld": withheld}, frame_format="dng" if raw else "tiff")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sets-per-effect", type=int, default=3)
    ap.add_argument("--captures", type=int, default=3)
    ap.add_argument("--retrain-steps", type=int, default=0)
    ap.add_argument("--retrain", choices=["all", "first"], default="first",
                    help="with --retrain-steps: retrain on every set, or on the first set of each withheld kind")
    ap.add_argument("--rounds", type=int, default=2, help="greedy rounds for sets with one withheld effect "
                    "(the two-effect set always gets 3)")
    ap.add_argument("--effects", help="only these withheld effects (comma-separated)")
    ap.add_argument("--pairs", action="store_true", help="with --effects: also the two-effect and no-effect sets")
    ap.add_argument("--variant", choices=sorted(VARIANTS), default="full", help="models and sensor "
                    "(benchmarks/diagnose_setup.py)")
    ap.add_argument("--out", help="results, one JSON line per set (resumable); default: the variant's "
                    f"{RESULTS}")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--verify-sets", action="store_true", help="re-render each stored set's first scene with this "
                    "code into a temporary folder and compare its frames with the stored ones (the sets are "
                    "rendered once and kept; this shows the code still makes them), then exit")
    ap.add_argument("--table", nargs="*", metavar="RESULTS", help="only print the table of these results files "
                    "(default: --out); sets of a variant other than `full` are labelled with it")
    args = ap.parse_args()
    setup = setup_dir(args.variant)
    args.out = args.out or str(setup / RESULTS)
    if args.table is not None:
        rows = []
        for f in args.table or [args.out]:
            # the variant's cache folder, or its name in the file name (benchmarks/results/diagnose_v2_crop4.jsonl)
            var = next((k for k, v in VARIANTS.items() if k != "full" and (v.folder == Path(f).resolve().parent.name
                                                                          or k in Path(f).stem)), "full")
            rows += [dict(json.loads(x), variant=var, source=f) for x in Path(f).read_text().splitlines()]
        table(rows, 0.0)
        return
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    torch.set_num_threads(2)
    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.search import DiagnoseConfig, diagnose
    from training.render import effects as fx

    lens_path, psf_path = setup / "rf50_288x192.json", setup / "psf.onnx"
    models = {"aat": setup / "diag_dfv_aat.onnx", "thin": setup / "diag_dfv_thin.onnx"}
    rng = np.random.default_rng(args.seed)
    names = args.effects.split(",") if args.effects else fx.names()
    unknown = set(names) - set(fx.names())
    if unknown:
        raise SystemExit(f"--effects: unknown {', '.join(sorted(unknown))}; registered: {', '.join(fx.names())}")
    plan = []  # (model key, withheld list)
    for n in names:  # the AAT model's simulator has the aberrations: they are withheld from the thin-lens model
        plan += [("thin" if n == "aberrations" else "aat", [n])] * args.sets_per_effect
    if not args.effects or args.pairs:
        plan += [("aat", ["noise", "sensor_tilt"]), ("aat", [])]
    for p in {lens_path, psf_path, *(models[k] for k, _ in plan)}:
        if not p.exists():
            raise SystemExit(f"{p}: missing; run python benchmarks/diagnose_setup.py --variant {args.variant} first")
    order = rng.permutation(len(plan))  # sets in random order; the diagnosis never sees the plan
    if args.verify_sets:
        return verify_sets(plan, order, rng, args.captures, setup, lens_path, psf_path, models)
    ctx = {}
    out = Path(args.out)
    done = {r["set"]: r for r in map(json.loads, out.read_text().splitlines())} if out.exists() else {}
    rows, t0 = list(done.values()), time.time()
    retrained: set[str] = {" + ".join(w.split(":")[0] for w in r["withheld"]) for r in rows if "remaining" in r}
    for i, key, withheld, set_seed, scene_seeds in drawn_sets(plan, order, rng, args.captures):
        if i in done:
            continue
        if key not in ctx:
            ctx[key] = load_model(models[key], lens_path, psf_path)
        m, lens, src, twins = ctx[key]
        base = [fx.spec(e) for e in twins.base]
        folder = setup / SETS / f"set{i:02d}"
        make_set(folder, lens, src, base, withheld, scene_seeds, set_seed)
        caps = [load_capture_data(p, m) for p in sorted(folder.iterdir()) if p.is_dir()]
        cfg = DiagnoseConfig(max_effects=3 if len(withheld) > 1 else args.rounds, n_boot=300)
        ts = time.time()
        res, _, _ = diagnose(m, twins, caps, cfg)
        # the whole answer (every effect's fits and distances), to study other ranking rules without re-rendering
        (folder / "diagnosis.json").write_text(json.dumps(res, indent=1, default=float))
        named = [e["effect"] for e in res["ranked_effects"]]
        seen = [e["effect"] for e in res["image_effects"]]
        shares = [round(e["share_of_gap"], 3) for e in res["ranked_effects"]]
        truth = [w.split(":")[0] for w in withheld]
        if not truth:  # nothing withheld: no gap, nothing blamed
            ok = not res["gap_significant"] and not named
        elif len(truth) == 1:  # the named cause (or, without a gap, the effect seen first in the images)
            ok = (named or seen)[:1] == truth
        else:  # both named, in order of their share
            ok = set(named[:2]) == set(truth) and shares[0] >= shares[1]
        row = {"set": int(i), "model": key, "withheld": withheld, "named": named, "seen": seen, "shares": shares,
               "gap_significant": res["gap_significant"], "gap_m": res["gap"]["gap_m"],
               "gap_ci_m": [res["gap"]["ci_low"], res["gap"]["ci_high"]],
               "gap_predicted_m": res["shrink"]["gap_predicted_m"] if res["shrink"] else None,
               "correct": ok, "seconds": round(time.time() - ts, 1)}
        kind = " + ".join(truth)
        if args.retrain_steps and res["shrink"] and truth and (args.retrain == "all" or kind not in retrained):
            row.update(retrain(m, lens_path, psf_path, res, caps, folder, args.retrain_steps))
            retrained.add(kind)
        rows.append(row)
        print(json.dumps(row), flush=True)
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
    table(rows, time.time() - t0)


def drawn_sets(plan: list, order, rng: np.random.Generator, captures: int):
    """Per set, in the benchmark's order: (index, model key, withheld effect specs, set seed, scene seeds). Every
    set's draws are made whether or not it is run, so a resumed run (or --verify-sets) sees the same draws."""
    from training.render import effects as fx

    for i in order:
        key, withheld_names = plan[i]
        set_seed = int(rng.integers(1 << 30))
        wrng = np.random.default_rng(set_seed)
        withheld = [fx.spec(fx.make(n, **draw_params(n, wrng))) for n in withheld_names]
        # v1 drew 3 of 8 scenes, so sets shared scenes (two aberration sets were identical)
        scene_seeds = [int(s) for s in wrng.choice(100_000, size=captures, replace=False)]
        yield int(i), key, withheld, set_seed, scene_seeds


def load_model(model_path: Path, lens_path: Path, psf_path: Path):
    """(model, lens, PSF surrogate source, twin renderer) as the diagnosis uses them."""
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.model import DfFModel
    from aat_deploy.twin.lookup import find_lens, find_surrogate

    m = DfFModel(model_path, threads=2)
    lens, _ = find_lens(m, lens_path)
    src = find_surrogate(lens, psf_path)
    return m, lens, src, make_renderer(m, lens, src)


def verify_sets(plan, order, rng, captures: int, setup: Path, lens_path: Path, psf_path: Path, models: dict) -> None:
    """Re-render the first scene of every stored set (same draws as `main`) and compare the frames, as the runtime
    reads them, with the stored ones: max |difference| in units of the white level."""
    import tempfile

    from aat_deploy.diagnose.inputs import load_capture_data
    from training.render import effects as fx

    ctx, worst, t0 = {}, 0.0, time.time()
    print("| set | withheld | scene | frames | max abs diff |\n|---|---|---|---|---|")
    for i, key, withheld, set_seed, scene_seeds in drawn_sets(plan, order, rng, captures):
        stored = setup / SETS / f"set{i:02d}" / f"scene{scene_seeds[0]}"
        if not stored.is_dir():
            print(f"| {i} | {' + '.join(withheld) or '(none)'} | {stored.name} | not rendered yet | — |")
            continue
        if key not in ctx:
            ctx[key] = load_model(models[key], lens_path, psf_path)
        m, lens, src, twins = ctx[key]
        with tempfile.TemporaryDirectory() as tmp:
            make_set(Path(tmp), lens, src, [fx.spec(e) for e in twins.base], withheld, scene_seeds[:1], set_seed)
            a = load_capture_data(stored, m, use_exiftool=False).frames
            b = load_capture_data(Path(tmp) / stored.name, m, use_exiftool=False).frames
        d = float(np.abs(a.astype(np.float64) - b).max()) if a.shape == b.shape else float("inf")
        worst = max(worst, d)
        print(f"| {i} | {' + '.join(withheld) or '(none)'} | {stored.name} | {len(a)} | {d:.3g} |", flush=True)
    print(f"\nlargest difference: {worst:.3g} ({time.time() - t0:.0f} s)")


def retrain(m, lens_path: Path, psf_path: Path, res: dict, caps, folder: Path, steps: int) -> dict:
    from aat_deploy.diagnose.search import DiagnoseConfig
    from aat_deploy.diagnose.session import retrain_command, score_model
    from aat_deploy.twin.lookup import find_lens, find_surrogate

    out = folder.parent / f"{folder.name}_retrain"
    cmd = retrain_command(m.path, lens_path, psf_path, res["shrink"]["effects"], steps, out,
                          m.meta["aat.sensor_mm"], m.sensor_px)
    stamp = out.with_suffix(".command")  # a folder made by another command (other effect settings) is redone
    if out.exists() and (not stamp.exists() or stamp.read_text() != " ".join(cmd)):
        shutil.rmtree(out)
    if not list(out.glob("dff_*_aat.onnx")):  # aat-train resumes a stopped run in the same folder
        print("+", " ".join(cmd), flush=True)
        stamp.write_text(" ".join(cmd))
        subprocess.run(cmd, check=True, cwd=ROOT)
    new = sorted(out.glob("dff_*_aat.onnx"))[0]
    lens, _ = find_lens(m, lens_path)
    after = score_model(new, lens, find_surrogate(lens, psf_path), caps, DiagnoseConfig(), 2)
    return {"gap_after_m": after["gap_after_m"], "remaining": after["gap_after_m"] / res["gap"]["gap_m"]}


def table(rows: list[dict], seconds: float) -> None:
    rows = list({(r.get("source"), r["set"]): r for r in rows}.values())  # the last result of each set
    print(f"\n{len(rows)} sets" + (f" in {seconds / 60:.1f} min (this run)" if seconds else "") + "\n")
    print("| withheld effect | sets | gap significant | named = withheld (gap) | seen = withheld (no gap) | "
          "correct | share of gap (named) | gap remaining after retraining |")
    print("|---|---|---|---|---|---|---|---|")
    by: dict = {}
    for r in rows:
        k = " + ".join(w.split(":")[0] for w in r["withheld"]) or "(none)"
        by.setdefault((k, r.get("variant") or "full"), []).append(r)
    for (k, var), rs in sorted(by.items()):
        truth = k.split(" + ")
        label = k if var == "full" else f"{k} ({var})"
        sig = [r for r in rs if r["gap_significant"]]
        named = sum(r["named"][:len(truth)] == truth or set(r["named"][:2]) == set(truth) for r in sig)
        seen = sum(r["seen"][:1] == truth[:1] for r in rs if not r["gap_significant"])
        seen_txt = "—" if k == "(none)" else f"{seen}/{len(rs) - len(sig)}"  # nothing to see
        sh = [r["shares"][0] for r in sig if r["shares"]]
        rem = [r["remaining"] for r in rs if r.get("remaining") is not None]
        print(f"| {label} | {len(rs)} | {len(sig)} | {named}/{len(sig)} | {seen_txt} | "
              f"{sum(r['correct'] for r in rs)}/{len(rs)} | {np.mean(sh):.2f} | " if sh else
              f"| {label} | {len(rs)} | {len(sig)} | {named}/{len(sig)} | {seen_txt} | "
              f"{sum(r['correct'] for r in rs)}/{len(rs)} | — | ", end="")
        print(", ".join(f"{x:.2f}" for x in rem) + " |" if rem else "— |")
    single = [r for r in rows if len(r["withheld"]) == 1]
    print(f"\nsingle withheld effect: {sum(r['correct'] for r in single)}/{len(single)} correct "
          f"({sum(r['gap_significant'] for r in single)} with a significant gap)")


if __name__ == "__main__":
    main()
