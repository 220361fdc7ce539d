"""Withheld-effect benchmark of `aat-diagnose` (issue: diagnose the sim-to-real gap).

Capture sets are made with the virtual camera (DNG frames, EXIF focus, ground truth) by a simulator that has
one effect more than the model's own (or two, or none). The effect is drawn at random per set, with random
settings, and is not passed to the diagnosis. Scored: is the named cause the withheld effect (when the withheld
effect opens no significant gap, nothing may be blamed: then the first effect the diagnosis sees in the images,
`image_effects`, must be the withheld one); for two: are both named, in order of their share; for none: is the
gap called not significant and nothing named. With --retrain-steps, the model is fine-tuned with the named
effects (`aat-train --init ... --effects ...`) and the gap re-measured (remaining = gap after / gap before).

Models: benchmarks/diagnose_setup.py (RF50 at 288x192, small DFVNets, AAT and thin-lens simulators). The full
frame at 125 um pixels is the default; `chromatic` is sub-pixel there and runs on the centre crop at 31.25 um;
`--variant shipped` takes the shipped full-sensor models at 960 x 640 (models/reproduce/dff_dfvnet_{aat,thin}.onnx, the
RF50's surrogate), or any model files given with --model-aat / --model-thin / --lens / --psf:

    python -m benchmarks.diagnose_setup [--variant crop4]
    python -m benchmarks.bench_diagnose [--sets-per-effect 3] [--captures 3] [--retrain-steps 0]
    python -m benchmarks.bench_diagnose --variant crop4 --effects chromatic
    python -m benchmarks.bench_diagnose --variant shipped [--model-aat M.onnx --model-thin T.onnx] --hidden

The v3 run at the shipped scale (BENCHMARKS.md): every effect once, every focus-error shape, the hidden sets, one
capture per set, torch-free twins as a runtime-only install has them; then (the same command again) the
retraining of the first 8 sets, in the run's order, with a named cause:

    python -m benchmarks.bench_diagnose --variant shipped --torch-free --hidden --sets-per-effect 1 --captures 1 \
        --rounds 1 --effects aberrations,chromatic,exposure,focus_breathing,focus_metadata,lens_tolerance,\
    misalignment,noise,raw_pipeline,sensor_tilt,vignetting --out results/diagnose_v3_shipped.jsonl \
        [--retrain-steps 150 --retrain-max 8]

v3 plan (this version): the effects real cameras add (exposure, misalignment, lens_tolerance), focus-metadata
errors of every shape the diagnosis fits (offset, distance scale, diopter quantisation, a monotone curve: one set
each per `--sets-per-effect` pair), and with --hidden one set per effect in HIDDEN whose withheld effect is also
hidden from the diagnosis's registry: the right answer there is "unexplained" (verdict), never a wrong name.
With --torch-free, a withheld effect the twins cannot render (chromatic without per-wavelength surrogates) is
skipped by the diagnosis, and its set is scored as a hidden one.

Results are appended to --out as JSON lines, one per set, and sets already there are skipped, so a stopped run
continues where it stopped (delete the file to start again); with --retrain-steps, sets diagnosed by an earlier run
are retrained then (up to --retrain-max in all). Capture sets are rendered once and kept;
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

from benchmarks.diagnose_setup import VARIANTS, setup_dir

ROOT = Path(__file__).resolve().parents[1]
FOCUS = (0.5, 10.0, 8)
# Capture sets and results of this version of the plan (v3: the new effects, focus-error shapes and hidden
# sets change the draws), inside the variant's setup folder; an older version's sets are not reused.
SETS, RESULTS = "sets_v3", "results_v3.jsonl"
FOCUS_SHAPES = ("offset", "scale", "quantisation", "monotone")
# effects hidden from the diagnosis in the --hidden sets (each opens a gap on these models when withheld)
HIDDEN = ("focus_metadata@scale", "sensor_tilt", "focus_breathing", "noise", "exposure", "misalignment",
          "lens_tolerance")


def draw_params(name: str, rng: np.random.Generator, width_px: int = 288) -> dict:
    """Random settings of a withheld effect (drawn per set; the diagnosis only sees the captures). name may carry
    a focus-error shape: 'focus_metadata@scale'."""
    name, _, shape = name.partition("@")
    if name == "noise":  # a dim scene or high ISO: weaker noise does not cost these models depth accuracy
        return {"full_well_e": float(np.exp(rng.uniform(np.log(250), np.log(1000))))}
    if name == "sensor_tilt":
        t = float(rng.choice([-1, 1]) * rng.uniform(0.6, 1.2))  # smaller tilts defocus the edges < 0.1 D here
        return {"tilt_x_deg": t, "tilt_y_deg": 0.0} if rng.random() < 0.5 else {"tilt_x_deg": 0.0, "tilt_y_deg": t}
    if name == "focus_metadata":
        sign = float(rng.choice([-1, 1]))
        if shape in ("", "offset"):
            return {"bias_d": sign * float(rng.uniform(0.05, 0.12))}
        if shape == "scale":  # the distance-encoder error: reported distance = scale x true
            return {"bias_d": 0.0, "scale": 1.0 + sign * float(rng.uniform(0.04, 0.1))}
        if shape == "quantisation":  # a camera storing focus in 0.1 D steps: up to 0.05 D off per frame
            return {"bias_d": 0.0, "quantise": "diopter", "step_d": 0.1}
        if shape == "monotone":  # an encoder curve: reported = true + a (t - 1)^2 - a/3, no offset nor scale
            a = sign * float(rng.uniform(0.06, 0.12))
            t = np.linspace(0.05, 2.2, 9)
            r = t + a * (t - 1.0) ** 2 - a / 3
            return {"bias_d": 0.0, "map_d": [round(float(v), 6) for pair in zip(r, t) for v in pair]}
        raise ValueError(f"unknown focus-error shape {shape!r}")
    if name == "exposure":  # auto exposure from frame to frame
        return {"sigma_log": float(rng.uniform(0.05, 0.12))}
    if name == "misalignment":  # shake between frames: a fraction of the frame width
        return {"sigma_px": float(rng.uniform(0.003, 0.008)) * width_px}
    if name == "lens_tolerance":  # one air gap off by 0.2-0.4 mm, or one element decentred by 0.15-0.35 mm
        if rng.random() < 0.5:
            return {"gap": float(rng.choice([1, 4, 5, 7, 9])), "gap_mm": float(rng.choice([-1, 1]) * rng.uniform(0.2, 0.4))}
        r, a = float(rng.uniform(0.15, 0.35)), float(rng.uniform(0, 2 * np.pi))
        return {"element": float(rng.integers(5)), "decentre_x_mm": r * np.cos(a), "decentre_y_mm": r * np.sin(a)}
    return {}


def scene(seed: int, h: int, w: int):
    from training.data.scenes import SceneConfig, procedural_scene

    rgb, depth = procedural_scene(SceneConfig(height=h, width=w, near_m=0.6, far_m=8.0), np.random.default_rng(seed))
    return np.ascontiguousarray(rgb.transpose(2, 0, 1)), depth  # (3, H, W) linear, (H, W) m


def make_set(folder: Path, lens, psf_src, base: list[str], withheld: list, scene_seeds: list[int], seed: int,
             key: str = "") -> None:
    """Render one capture set (one folder per scene) with the model's effects plus the withheld ones. A withheld
    `raw_pipeline` is the real thing: DNG frames (Bayer mosaic) that the runtime develops with LibRaw; otherwise
    frames are float TIFFs, exactly as rendered. The folder's set.json records the draws: a folder made by another
    plan (other arguments) is refused rather than mixed with this set's scenes."""
    from aat_deploy.capture.virtual import write_capture
    from aat_deploy.render import effects as fx
    from training.render.schedule import FocusSchedule
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF

    raw = any(w.split(":")[0] == "raw_pipeline" for w in withheld)
    rendered = [w for w in withheld if w.split(":")[0] != "raw_pipeline"]
    record = {"model": key, "base": base, "withheld": withheld, "scenes": scene_seeds, "seed": seed}
    stamp = folder / "set.json"
    scenes = {p.name for p in folder.iterdir() if p.is_dir()} if folder.exists() else set()
    # a folder from before the stamp holds this set if its scenes are this set's (seeded by the set's seed)
    same = (json.loads(stamp.read_text()) == record if stamp.exists()
            else scenes <= {f"scene{s}" for s in scene_seeds})
    if not same:
        raise SystemExit(f"{folder}: holds another set than this plan draws (other --effects, --captures, "
                         f"--sets-per-effect or --seed?); move it away or use the arguments it was made with")
    folder.mkdir(parents=True, exist_ok=True)
    stamp.write_text(json.dumps(record))
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
    ap.add_argument("--retrain-max", type=int, help="with --retrain-steps: at most this many retrainings in all "
                    "(results already in --out count), the first sets in the benchmark's order")
    ap.add_argument("--torch-free", action="store_true", help="diagnose with the torch-free twins, as a "
                    "runtime-only install does (effects it cannot render, e.g. chromatic without per-wavelength "
                    "surrogates, are skipped: a set withholding one is scored as hidden)")
    ap.add_argument("--rounds", type=int, default=2, help="greedy rounds for sets with one withheld effect "
                    "(the two-effect set always gets 3)")
    ap.add_argument("--effects", help="only these withheld effects (comma-separated; focus_metadata@SHAPE: one "
                    f"focus-error shape of {', '.join(FOCUS_SHAPES)})")
    ap.add_argument("--pairs", action="store_true", help="with --effects: also the two-effect and no-effect sets")
    ap.add_argument("--variant", choices=sorted(VARIANTS), default="full", help="models and sensor "
                    "(benchmarks/diagnose_setup.py; shipped = the models in models/ at 960 x 640)")
    ap.add_argument("--model-aat", help="the AAT model to diagnose (default: the variant's)")
    ap.add_argument("--model-thin", help="the thin-lens model (aberrations sets; default: the variant's)")
    ap.add_argument("--lens", help="their lens file (default: the variant's)")
    ap.add_argument("--psf", help="the lens's PSF surrogate (default: the variant's)")
    ap.add_argument("--hidden", action="store_true", help="also one set per HIDDEN effect with it hidden from the "
                    "diagnosis (the right answer: unexplained)")
    ap.add_argument("--out", help="results, one JSON line per set (resumable); default: the variant's "
                    f"{RESULTS}")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sets", default=SETS, help="folder of the capture sets inside the variant's setup folder: "
                    "another plan's sets (other --effects, --captures, ...) need their own")
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
            # the variant's cache folder, or its name in the file name (results/archive/diagnose_v2_crop4.jsonl)
            var = next((k for k, v in VARIANTS.items() if k != "full" and (v.folder == Path(f).resolve().parent.name
                                                                          or k in Path(f).stem)), "full")
            rows += [dict(json.loads(x), variant=var, source=f) for x in Path(f).read_text().splitlines()]
        table(rows, 0.0)
        return
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    torch.set_num_threads(2)
    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.search import DiagnoseConfig, diagnose
    from aat_deploy.render import effects as fx

    lens_path, psf_path, models = variant_files(args, setup)
    rng = np.random.default_rng(args.seed)
    names = args.effects.split(",") if args.effects else fx.names()
    unknown = {n.split("@")[0] for n in names} - set(fx.names())
    unknown |= {n for n in names if n.startswith("focus_metadata@") and n.split("@")[1] not in FOCUS_SHAPES}
    if unknown:
        raise SystemExit(f"--effects: unknown {', '.join(sorted(unknown))}; registered: {', '.join(fx.names())}")
    plan = make_plan(names, args.sets_per_effect, not args.effects or args.pairs, args.hidden)
    for p in {lens_path, psf_path, *(models[k] for k, _, _ in plan)}:
        if not p.exists():
            raise SystemExit(f"{p}: missing; run python -m benchmarks.diagnose_setup --variant {args.variant} first")
    if any(n.startswith("lens_tolerance") for _, w, _ in plan for n in w):
        tolerance_table(lens_path, psf_path)
    order = rng.permutation(len(plan))  # sets in random order; the diagnosis never sees the plan
    from aat_deploy.infer.model import DfFModel

    width = DfFModel(models["aat"]).sensor_px[0]  # misalignment is drawn as a fraction of the frame
    if args.verify_sets:
        return verify_sets(plan, order, rng, args.captures, setup, lens_path, psf_path, models, width, args.sets)
    ctx = {}
    out = Path(args.out)
    done = {r["set"]: r for r in map(json.loads, out.read_text().splitlines())} if out.exists() else {}
    rows, t0 = list(done.values()), time.time()
    retrained: set[str] = {kind_of(r) for r in rows if "remaining" in r}
    n_retrained = sum("remaining" in r for r in rows)

    def wants_retrain(row: dict, res: dict) -> bool:
        return bool(args.retrain_steps and res["shrink"] and row["withheld"] and not row["hidden"]
                    and (args.retrain == "all" or kind_of(row) not in retrained)
                    and (args.retrain_max is None or n_retrained < args.retrain_max))

    for i, key, withheld, hidden, set_seed, scene_seeds in drawn_sets(plan, order, rng, args.captures, width):
        folder = setup / args.sets / f"set{i:02d}"
        if i in done and not ("remaining" not in done[i] and (folder / "diagnosis.json").exists()
                              and wants_retrain(done[i], json.loads((folder / "diagnosis.json").read_text()))):
            continue
        if key not in ctx:
            ctx[key] = load_model(models[key], lens_path, psf_path, args.torch_free)
        m, lens, src, twins = ctx[key]
        base = [fx.spec(e) for e in twins.base]
        tr = time.time()
        make_set(folder, lens, src, base, withheld, scene_seeds, set_seed, key)
        caps = [load_capture_data(p, m) for p in sorted(folder.iterdir()) if p.is_dir()]
        if i in done:  # diagnosed by an earlier run without (or beyond the cap of) retraining: retrain now
            row, res = dict(done[i]), json.loads((folder / "diagnosis.json").read_text())
        else:
            truth = [w.split(":")[0] for w in withheld]
            # a hidden set's diagnosis does not know the withheld effect: it may only say "unexplained"
            effects = [n for n in fx.names() if n not in truth] if hidden else None
            cfg = DiagnoseConfig(max_effects=3 if len(withheld) > 1 else args.rounds, n_boot=300, effects=effects)
            ts = time.time()
            res, _, _ = diagnose(m, twins, caps, cfg)
            # the whole answer (every effect's fits and distances), to study other ranking rules without
            # re-rendering
            (folder / "diagnosis.json").write_text(json.dumps(res, indent=1, default=float))
            row = score(i, key, withheld, hidden, res)
            row["seconds"], row["render_seconds"] = round(time.time() - ts, 1), round(ts - tr, 1)
            row["torch_free"] = bool(args.torch_free)
        if wants_retrain(row, res):
            tt = time.time()
            row.update(retrain(m, lens_path, psf_path, res, caps, folder, args.retrain_steps, args.torch_free))
            row["retrain_seconds"] = round(time.time() - tt, 1)
            retrained.add(kind_of(row))
            n_retrained += 1
        rows = [r for r in rows if r["set"] != i] + [row]
        print(json.dumps(row), flush=True)
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
    table(rows, time.time() - t0)


def variant_files(args, setup: Path) -> tuple[Path, Path, dict]:
    """The lens, surrogate and models: the arguments, else the variant's (shipped: models/ and lenses/)."""
    if args.variant == "shipped":
        lens, psf = ROOT / "lenses" / "canon_rf50mm_f1.8.json", ROOT / "models" / "psf_rf50.onnx"
        models = {"aat": ROOT / "models" / "reproduce" / "dff_dfvnet_aat.onnx", "thin": ROOT / "models" / "reproduce" / "dff_dfvnet_thin.onnx"}
    else:
        lens, psf = setup / "rf50_288x192.json", setup / "psf.onnx"
        models = {"aat": setup / "diag_dfv_aat.onnx", "thin": setup / "diag_dfv_thin.onnx"}
    models = {"aat": Path(args.model_aat) if args.model_aat else models["aat"],
              "thin": Path(args.model_thin) if args.model_thin else models["thin"]}
    return Path(args.lens) if args.lens else lens, Path(args.psf) if args.psf else psf, models


def make_plan(names: list[str], per_effect: int, extras: bool, hidden: bool) -> list[tuple[str, list, bool]]:
    """(model key, withheld names, hidden) per set. focus_metadata: one set per shape per two `per_effect`."""
    plan = []
    for n in names:  # the AAT model's simulator has the aberrations: they are withheld from the thin-lens model
        if n == "focus_metadata":
            plan += [("aat", [f"{n}@{shape}"], False) for shape in FOCUS_SHAPES] * max(1, per_effect // 2)
        elif "@" in n:  # one focus-error shape: --effects focus_metadata@quantisation
            plan += [("aat", [n], False)] * per_effect
        else:
            plan += [("thin" if n == "aberrations" else "aat", [n], False)] * per_effect
    if extras:
        plan += [("aat", ["noise", "sensor_tilt"], False), ("aat", [], False)]
    if hidden:
        plan += [("aat", [n], True) for n in HIDDEN if n.split("@")[0] in names]
    return plan


def kind_of(row: dict) -> str:
    """A set's kind in the table: the withheld effects (with the focus-error shape), hidden or not."""
    k = " + ".join(row.get("labels") or [w.split(":")[0] for w in row["withheld"]]) or "(none)"
    if row.get("hidden"):
        return f"{k} (skipped by the twins)" if row.get("hidden_by") == "skipped" else f"{k} (hidden)"
    return k


def score(i: int, key: str, withheld: list[str], hidden: bool, res: dict) -> dict:
    """One set's row. Correct: nothing withheld -> no significant gap and nothing named; hidden -> no effect
    blamed (no cause named: verdict unexplained, or no gap); one withheld -> the first named effect is it (or,
    without a gap, the first seen in the images); two -> both named, in order of their share. `cause_ok`: the
    first effect that explains the gap (verdict) is the withheld one."""
    named = [e["effect"] for e in res["ranked_effects"]]
    seen = [e["effect"] for e in res["image_effects"]]
    causes = res.get("causes", [])
    shares = [round(e["share_of_gap"], 3) for e in res["ranked_effects"]]
    truth = [w.split(":")[0] for w in withheld]
    skipped = [e["effect"] for e in res.get("effects_skipped", [])]
    # a withheld effect the twins could not render (torch-free: chromatic) is hidden from the diagnosis as well
    hidden_by = "plan" if hidden else "skipped" if truth and set(truth) <= set(skipped) else None
    hidden = hidden_by is not None
    if not truth:
        ok = not res["gap_significant"] and not named
    elif hidden:
        ok = not causes
    elif len(truth) == 1:
        ok = (named or seen)[:1] == truth
    else:
        ok = set(named[:2]) == set(truth) and shares[0] >= shares[1]
    u = res.get("unexplained_share") or {}
    return {"set": int(i), "model": key, "withheld": withheld, "hidden": hidden, "hidden_by": hidden_by,
            "labels": labels(withheld), "skipped": skipped,
            "named": named, "seen": seen, "causes": causes, "shares": shares, "verdict": res.get("verdict"),
            "unexplained_share": u.get("share"), "gap_significant": res["gap_significant"],
            "gap_m": res["gap"]["gap_m"], "gap_ci_m": [res["gap"]["ci_low"], res["gap"]["ci_high"]],
            "gap_predicted_m": res["shrink"]["gap_predicted_m"] if res["shrink"] else None, "correct": ok,
            "cause_ok": bool(truth) and not hidden and len(truth) == 1 and causes[:1] == truth,
            "focus_family": (res.get("focus") or {}).get("family")}


def labels(withheld: list[str]) -> list[str]:
    """Effect names, focus_metadata with its error shape: 'focus_metadata (scale)'."""
    out = []
    for w in withheld:
        name, *kv = w.split(":")
        p = dict(x.split("=", 1) for x in kv)
        if name == "focus_metadata":
            shape = ("quantisation" if p.get("quantise", "none") != "none" else "monotone" if "map_d" in p
                     else "scale" if "scale" in p else "offset")
            name = f"{name} ({shape})"
        out.append(name)
    return out


def tolerance_table(lens_path: Path, psf_path: Path) -> None:
    """The lens's tolerance table next to its surrogate (the twins render lens_tolerance without torch): copied
    from models/ when one there fits the lens, else traced."""
    import shutil

    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import table_name

    name = table_name(load_lens(lens_path))
    target = psf_path.parent / name
    if target.exists():
        return
    if (ROOT / "models" / name).exists():
        shutil.copy(ROOT / "models" / name, target)
    else:
        subprocess.run([os.sys.executable, str(ROOT / "scripts" / "lens_tolerance_table.py"), str(lens_path),
                        "--psf", str(psf_path)], check=True, cwd=ROOT)


def drawn_sets(plan: list, order, rng: np.random.Generator, captures: int, width_px: int = 288):
    """Per set, in the benchmark's order: (index, model key, withheld effect specs, hidden, set seed, scene seeds).
    Every set's draws are made whether or not it is run, so a resumed run (or --verify-sets) sees the same draws."""
    from aat_deploy.render import effects as fx

    for i in order:
        key, withheld_names, hidden = plan[i]
        set_seed = int(rng.integers(1 << 30))
        wrng = np.random.default_rng(set_seed)
        withheld = [fx.spec(fx.make(n.split("@")[0], **draw_params(n, wrng, width_px))) for n in withheld_names]
        # v1 drew 3 of 8 scenes, so sets shared scenes (two aberration sets were identical)
        scene_seeds = [int(s) for s in wrng.choice(100_000, size=captures, replace=False)]
        yield int(i), key, withheld, hidden, set_seed, scene_seeds


def load_model(model_path: Path, lens_path: Path, psf_path: Path, torch_free: bool = False):
    """(model, lens, PSF surrogate source, twin renderer) as the diagnosis uses them (torch_free: as a runtime-only
    install does)."""
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.infer.model import DfFModel

    m = DfFModel(model_path, threads=2)
    lens, _ = find_lens(m, lens_path)
    src = find_surrogate(lens, psf_path)
    return m, lens, src, make_renderer(m, lens, src, torch_free)


def verify_sets(plan, order, rng, captures: int, setup: Path, lens_path: Path, psf_path: Path, models: dict,
                width: int = 288, sets: str = SETS) -> None:
    """Re-render the first scene of every stored set (same draws as `main`) and compare the frames, as the runtime
    reads them, with the stored ones: max |difference| in units of the white level."""
    import tempfile

    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.render import effects as fx

    ctx, worst, t0 = {}, 0.0, time.time()
    print("| set | withheld | scene | frames | max abs diff |\n|---|---|---|---|---|")
    for i, key, withheld, _, set_seed, scene_seeds in drawn_sets(plan, order, rng, captures, width):
        stored = setup / sets / f"set{i:02d}" / f"scene{scene_seeds[0]}"
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


def retrain(m, lens_path: Path, psf_path: Path, res: dict, caps, folder: Path, steps: int,
            torch_free: bool = False) -> dict:
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.diagnose.search import DiagnoseConfig
    from aat_deploy.diagnose.session import retrain_command, score_model

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
    after = score_model(new, lens, find_surrogate(lens, psf_path), caps, DiagnoseConfig(), 2, torch_free)
    return {"gap_after_m": after["gap_after_m"], "remaining": after["gap_after_m"] / res["gap"]["gap_m"]}


def table(rows: list[dict], seconds: float) -> None:
    """The results table (v2 rows, without verdicts, print as before) and the issue's three targets."""
    rows = list({(r.get("source"), r["set"]): r for r in rows}.values())  # the last result of each set
    print(f"\n{len(rows)} sets" + (f" in {seconds / 60:.1f} min (this run)" if seconds else "") + "\n")
    print("| withheld effect | sets | gap significant | named = withheld (gap) | explains = withheld (gap) | "
          "seen = withheld (no gap) | correct | share of gap (named) | verdicts | gap remaining after retraining |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    by: dict = {}
    for r in rows:
        by.setdefault((kind_of(r), r.get("variant") or "full"), []).append(r)
    for (k, var), rs in sorted(by.items()):
        truth = [w.split(":")[0] for w in rs[0]["withheld"]]
        label = k if var == "full" else f"{k} ({var})"
        sig = [r for r in rs if r["gap_significant"]]
        hidden = rs[0].get("hidden")
        if hidden:
            named_txt = cause_txt = "—"
        else:
            named_txt = f"{sum(r['named'][:len(truth)] == truth or set(r['named'][:2]) == set(truth) for r in sig)}/{len(sig)}"
            cause_txt = f"{sum(r.get('cause_ok', False) for r in sig)}/{len(sig)}" if len(truth) == 1 and \
                all("causes" in r for r in rs) else "—"
        seen = sum(r["seen"][:1] == truth[:1] for r in rs if not r["gap_significant"])
        seen_txt = "—" if not truth or hidden else f"{seen}/{len(rs) - len(sig)}"
        sh = [r["shares"][0] for r in sig if r["shares"]]
        rem = [r["remaining"] for r in rs if r.get("remaining") is not None]
        verdicts = ", ".join(f"{v} {n}" for v, n in sorted(_count(r.get("verdict") or "—" for r in rs).items()))
        print(f"| {label} | {len(rs)} | {len(sig)} | {named_txt} | {cause_txt} | {seen_txt} | "
              f"{sum(r['correct'] for r in rs)}/{len(rs)} | {f'{np.mean(sh):.2f}' if sh else '—'} | {verdicts} | "
              + (", ".join(f"{x:.2f}" for x in rem) if rem else "—") + " |")
    single = [r for r in rows if len(r["withheld"]) == 1 and not r.get("hidden")]
    sig = [r for r in single if r["gap_significant"]]
    print(f"\nsingle withheld effect: {sum(r['correct'] for r in single)}/{len(single)} correct "
          f"({len(sig)} with a significant gap)")
    if sig:
        print(f"target 1 (named cause right where the gap is significant, >= 90 %): "
              f"{sum(r['named'][:1] == [r['withheld'][0].split(':')[0]] for r in sig)}/{len(sig)}")
    hid = [r for r in rows if r.get("hidden")]
    if hid:
        hs = [r for r in hid if r["gap_significant"]]
        print(f"target 2 (hidden sets not blamed on a wrong effect, >= 80 %): {sum(r['correct'] for r in hid)}/"
              f"{len(hid)} ({sum(r['correct'] for r in hs)}/{len(hs)} of those with a significant gap; verdict "
              f"unexplained in {sum(r.get('verdict') == 'unexplained' for r in hs)})")
    for key, what in (("render_seconds", "rendering a set"), ("seconds", "diagnosing a set"),
                      ("retrain_seconds", "retraining and re-measuring")):
        t = [r[key] for r in rows if r.get(key) is not None]
        if t:
            print(f"{what}: {np.mean(t):.0f} s on average ({min(t):.0f}-{max(t):.0f} s, {len(t)} sets)")
    rem = [r["remaining"] for r in rows if r.get("remaining") is not None]
    if rem:
        # a gap that changes sign is not closed: |after| / before, so -0.9 (the twin now 0.9 gaps worse than the
        # captures) misses as +0.9 would
        print(f"target 3 (gap left after retraining with the named effect, |after| / before < 1/3): "
              f"{sum(abs(x) < 1 / 3 for x in rem)}/{len(rem)}")


def _count(items) -> dict:
    out: dict = {}
    for x in items:
        out[x] = out.get(x, 0) + 1
    return out


if __name__ == "__main__":
    main()
