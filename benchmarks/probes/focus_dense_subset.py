"""Should the binning correction be anchored densely around the estimates (`anchors.DENSE_ANCHORS`)? A declared,
stratified subset of the development sets (issue 32, 2026-11-27/28; docs/diagnosis.md, Limits, "Dense anchoring
measured"), rerun through the first-round focus fit with the setting on and judged against the stored rows rescored
by the code (`bench_diagnose_focus.rescored`), as `focus_start_invariance --mode dense` did on 28 sets.

The rule, fixed before any of its sets was rerun:
- The universe: the development sets of the scenes whose captures this lane has rendered (`CACHED_SCENES`: scene 2038
  and rounds 6-11, 25 scenes, 300 sets, their rows made with the code's estimator as it is now; the other development
  scenes, the tuning capture and rounds 1-5, would have to be rendered again and their rows are from older
  estimators). Never a scene of 3304 or later (the next held-out round's).
- Stratum A, every problem set: the family wrong, or a frame over 0.02 D, or claimed determined but over 0.02 D (the
  code, rescored). A1: the family wrong or claimed-wrong; A2: the rest (right family, a frame undetermined over 0.02 D).
- Stratum H, harm: a random sample (numpy seed 32) of the sets the code gets right (family right and, with an error,
  within 0.02 D with every frame determined): H0 8 untouched copies, H1 16 sets with an error.
- Sets already rerun by `focus_start_invariance --mode dense` (`DONE_FILES`) are not run again (their rows count, the
  runtime reproducing the probe's logic) and are left out of the sampling.
- Order: H0, then A1, then A2 and H1 shuffled together (seed 32): a run stopped by the session's clock covers the
  strata in proportion. Every set's outcome is its rerun against its stored row: better or worse in the family, in
  within 0.02 D with every frame determined, or in claimed-wrong (`focus_choice_nearest.scenes_moved`), per set and
  per scene, with a sign test over scenes.
- The trigger (`anchors.DENSE_MOVED_D`): dense anchoring only when some frame's first estimate lies T or more from
  its reported focus; for T in TRIGGERS_D a set below T keeps its stored outcome (its first estimates are the code's).

    python -m benchmarks.probes.focus_dense_subset --plan            # the subset, its order and the lane-B commands
    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 python -m benchmarks.probes.focus_dense_subset --run --until 01:14
        # the same commands in one process (the model, lens and PSF surrogate loaded once: about 100 s a command
        # otherwise), each holding /work/heavy2.lock for its sets only, niced; no command started after --until UTC
    python -m benchmarks.probes.focus_dense_subset --tally RERUN.jsonl ... [--out results/focus_dense_subset.md]
"""

from __future__ import annotations

import argparse
import datetime
import io
import json
import sys
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic

ROOT = Path(__file__).resolve().parents[2]
SEED = 32
N_UNTOUCHED, N_RIGHT = 8, 16
TRIGGERS_D = (0.0, 0.01, 0.02, 0.03, 0.05)
# the stored rows of each round (results/diagnose_focus_<name>.jsonl) and the benchmark's flag that renders its scenes
ROUNDS = {"dev_leftout_grid": None, "fresh7_fitonly": "--fresh7 4", "fresh8_fitonly": "--fresh8 4",
          "fresh9_fitonly": "--fresh9 4", "fresh10_fitonly": "--fresh10 4", "fresh11_fitonly": "--fresh11 4"}
FLAG_OF_SCENE = {"scene2038": "--fresh3 1", "scene2065": "--fresh6 4", "scene2073": "--fresh6 4",
                 "scene2141": "--fresh6 4", "scene2182": "--fresh6 4"}  # dev_leftout_grid's scenes
CACHED_SCENES = ("scene2038", "scene2065", "scene2073", "scene2141", "scene2182", "scene2222", "scene2304",
                 "scene2359", "scene2369", "scene2383", "scene2431", "scene2467", "scene2472", "scene2620",
                 "scene2628", "scene2655", "scene2722", "scene2817", "scene3045", "scene3076", "scene3239",
                 "scene3251", "scene3257", "scene3294", "scene3303")
DONE_FILES = ("focus_start_invariance_dense.jsonl", "focus_start_invariance_dense_dev8.jsonl",
              "focus_start_invariance_dense_dev9.jsonl", "focus_start_invariance_dense_dev10.jsonl",
              "focus_start_invariance_dense_dev11.jsonl")


def read(paths) -> list[dict]:
    return [json.loads(x) for p in paths for x in Path(p).read_text().splitlines() if x.strip()]


def stored() -> dict[tuple[str, str], dict]:
    """(capture, kind) -> the stored row, of every round in ROUNDS, the universe's scenes only."""
    rows = read(ROOT / "results" / f"diagnose_focus_{r}.jsonl" for r in ROUNDS)
    return {(r["capture"], r["kind"]): r for r in rows if r["capture"] in CACHED_SCENES}


def flag(capture: str, rows: dict) -> str:
    if capture in FLAG_OF_SCENE:
        return FLAG_OF_SCENE[capture]
    for name, f in ROUNDS.items():
        if f and any(c == capture for (c, _), r in rows.items() if r.get("_round") == name):
            return f
    raise KeyError(capture)


def marks(r: dict) -> tuple[bool, bool, bool]:
    """(family right, within 0.02 D with every frame determined, claimed determined but over 0.02 D)."""
    det = not r["frames_undetermined"]
    err = r["kind"] != "none"
    return r["family_ok"], err and det and r["corrected_max_err_d"] <= 0.02, err and det and r["corrected_max_err_d"] > 0.02


def plan() -> list[tuple[str, str, str]]:
    """[(stratum, capture, kind)] in the declared order."""
    from benchmarks import bench_diagnose_focus as bench

    rows = stored()
    done = {(r["capture"], r["kind"]) for r in read(ROOT / "results" / f for f in DONE_FILES)}
    a1, a2, h0, h1 = [], [], [], []
    for key in sorted(rows):
        if key in done:
            continue
        r = bench.rescored(rows[key], "code", on_estimates=True)
        fam, within, claimed = marks(r)
        over = r["kind"] != "none" and r["corrected_max_err_d"] > 0.02
        if not fam or claimed:
            a1.append(key)
        elif over:
            a2.append(key)
        elif r["kind"] == "none":
            h0.append(key)
        elif within:
            h1.append(key)
    rng = np.random.default_rng(SEED)
    h0 = [h0[i] for i in sorted(rng.choice(len(h0), N_UNTOUCHED, replace=False))]
    h1 = [h1[i] for i in sorted(rng.choice(len(h1), N_RIGHT, replace=False))]
    rest = [("A2", *k) for k in a2] + [("H1", *k) for k in h1]
    rest = [rest[i] for i in rng.permutation(len(rest))]
    return [("H0", *k) for k in h0] + [("A1", *k) for k in a1] + rest


def commands(order: list[tuple[str, str, str]], chunk: int = 5, mode: str = "dense",
             out_file: str = "results/focus_dense_subset.jsonl") -> list[str]:
    """The lane-B commands: consecutive sets of one round's flag, at most `chunk` to a command, each rerun with
    `focus_start_invariance --mode` `mode` into `out_file`."""
    rows = {}
    for name in ROUNDS:
        for r in read([ROOT / "results" / f"diagnose_focus_{name}.jsonl"]):
            rows[(r["capture"], r["kind"])] = {**r, "_round": name}
    groups: list[tuple[str, list[str]]] = []
    for _, c, k in order:
        f = f"{flag(c, rows)} --rows-file {rows[(c, k)]['_round']}"
        if groups and groups[-1][0] == f and len(groups[-1][1]) < chunk:
            groups[-1][1].append(f"{c}:{k}")
        else:
            groups.append((f, [f"{c}:{k}"]))
    lane = "OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 flock /work/heavy2.lock nice -n 10"
    out = []
    for f, s in groups:
        fl, name = f.split(" --rows-file ")
        out.append(f"{lane} python -m benchmarks.probes.focus_start_invariance --mode {mode} --rows results/diagnose_focus_"
                   f"{name}.jsonl --out {out_file} -- --fit-only --threads 1 {fl} --sets {','.join(s)}")
    return out


def hhmm(until: str) -> tuple[int, int]:
    """(hour, minute) of a cut-off HH:MM (UTC); ValueError with one line otherwise."""
    parts = until.split(":")
    if len(parts) != 2 or not all(x.isascii() and x.isdigit() for x in parts) \
            or not (int(parts[0]) < 24 and int(parts[1]) < 60):
        raise ValueError(f"--until {until}: not HH:MM")
    return int(parts[0]), int(parts[1])


def until_arg(text: str) -> str:
    """argparse type of --until: refused in one line at parse time, before any lock or command."""
    try:
        hhmm(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def cutoff(until: str, start: datetime.datetime) -> datetime.datetime:
    """The cut-off `until` (HH:MM UTC) as a moment: the one of that clock time nearest to `start` (a run started at
    23:30 with --until 01:14 stops at 01:14 the next day; one started at 10:25 with --until 10:20 starts nothing;
    any hour of the day, afternoon included)."""
    h, m = hhmm(until)
    t = start.replace(hour=h, minute=m, second=0, microsecond=0)
    day = datetime.timedelta(days=1)
    return min((t - day, t, t + day), key=lambda x: abs(x - start))


def utc_now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc)


def run(cmds: list[str], until: str, lock: Path, now=utc_now) -> None:
    """`commands` in this process, each under an exclusive lock on `lock` (released in between), from the first not
    yet done (the benchmark skips sets in its --out); none started at or after `until` (HH:MM UTC, `cutoff`; `now`
    the clock)."""
    import fcntl
    import os
    import shlex

    from aat_deploy.diagnose import lookup
    from aat_deploy.infer import model as model_mod
    from benchmarks.probes import focus_start_invariance as si

    def memo(f):
        seen = {}

        def g(*args, **kw):
            key = repr((args, sorted(kw.items())))
            if key not in seen:
                seen[key] = f(*args, **kw)
            return seen[key]
        return g

    model_mod.DfFModel = memo(model_mod.DfFModel)
    lookup.find_lens, lookup.find_surrogate = memo(lookup.find_lens), memo(lookup.find_surrogate)
    stop = cutoff(until, now())
    os.nice(10)
    for i, cmd in enumerate(cmds, 1):
        argv = shlex.split(cmd)
        argv = argv[argv.index("benchmarks.probes.focus_start_invariance") + 1:]
        if not remaining(argv):  # every set already in its --out: skipped without waiting for the lane's lock
            continue
        with lock.open("a") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX)
            if now() >= stop:  # checked with the lock held: a wait for the lane cannot start a command late
                print(f"=== stopped before command {i} of {len(cmds)} at {now():%H:%M:%S} UTC", flush=True)
                return
            print(f"=== {i}/{len(cmds)} {now():%H:%M:%S} {argv[-1]}", flush=True)
            si.main(argv)
            fcntl.flock(fh, fcntl.LOCK_UN)
    print(f"=== all {len(cmds)} commands done {now():%H:%M:%S} UTC", flush=True)


def remaining(argv: list[str]) -> list[str]:
    """A command's --sets (CAPTURE:KIND) not yet in its --out (the benchmark skips those, and appends the others)."""
    out = Path(argv[argv.index("--out") + 1])
    done = {f"{r['capture']}:{r['kind']}" for r in read([out])} if out.is_file() else set()
    return [x for x in argv[argv.index("--sets") + 1].split(",") if x not in done]


def moved_d(row: dict) -> float:
    """The largest distance of a row's first per-frame estimates from its reported focus (diopters): `robust.moved_d`
    where recorded, else from where it was re-anchored (below REANCHOR_D when it was not: 0)."""
    rob = row.get("robust", {})
    if "moved_d" in rob:
        return float(max(rob["moved_d"]))
    if "reanchored_d" not in rob:
        return 0.0
    return float(max(np.max(np.abs(np.asarray(a) - np.asarray(b))) for a, b in zip(rob["reanchored_d"], rob["anchors_d"])))


def tally(rerun: list[dict], strata: dict) -> str:
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes.focus_choice_nearest import scenes_moved

    rows = stored()
    out = io.StringIO()
    with redirect_stdout(out):
        rerun = list({(r["capture"], r["kind"]): r for r in rerun}.values())
        base = {k: bench.rescored(rows[k], "code", on_estimates=True) for k in ((r["capture"], r["kind"]) for r in rerun)}
        for r in rerun:
            if abs(r["reported_max_err_d"] - rows[(r["capture"], r["kind"])]["reported_max_err_d"]) > 1e-6:
                raise SystemExit(f"{r['capture']} {r['kind']}: its reported focus is not the stored row's")
        print("| stratum | set | moved (D) | the code (stored, rescored) | dense | per-frame max error (D), stored -> dense "
              "| s a fit | outcome |\n|---|---|---|---|---|---|---|---|")
        for r in sorted(rerun, key=lambda x: (strata.get((x["capture"], x["kind"]), "?"), x["capture"], x["kind"])):
            b = base[(r["capture"], r["kind"])]
            x, y = marks(b), marks(r)
            up, down = any(v > u for u, v in zip(x[:2], y[:2])) or (x[2] and not y[2]), \
                any(v < u for u, v in zip(x[:2], y[:2])) or (y[2] and not x[2])
            how = "better" if up and not down else "worse" if down and not up else "mixed" if up else ""
            desc = (lambda z: f"`{z['family']}` {z['corrected_max_err_d']:.4f} D"
                    f"{', ' + str(sum(np.asarray(z['frames_undetermined']).ravel())) + ' undetermined' if z['frames_undetermined'] else ''}"
                    f"{', claimed' if marks(z)[2] else ''}")
            pf = [np.nanmax(np.abs(np.asarray(z["frame_err_d"], np.float64))) for z in (rows[(r["capture"], r["kind"])], r)]
            print(f"| {strata.get((r['capture'], r['kind']), '?')} | {r['capture']} {r['kind']} | {moved_d(b):.3f} | "
                  f"{desc(b)} | {desc(r)} | {pf[0]:.4f} -> {pf[1]:.4f} | {r.get('seconds')} | {how} |")
        print()
        for t in TRIGGERS_D:
            var = [r if moved_d(base[(r["capture"], r["kind"])]) >= t else base[(r["capture"], r["kind"])] for r in rerun]
            m = scenes_moved(list(base.values()), var)
            sets = [s for v in m["scenes"].values() for s in v]
            n = lambda rs, i: sum(marks(z)[i] for z in rs)  # noqa: E731
            un = [z for z in var if z["kind"] == "none"]
            print(f"trigger {t:.2f} D: dense in {sum(z is not base[(z['capture'], z['kind'])] for z in var)}/{len(var)} "
                  f"sets; family right {n(base.values(), 0)} -> {n(var, 0)}, within 0.02 D {n(base.values(), 1)} -> "
                  f"{n(var, 1)}, claimed-wrong {n(base.values(), 2)} -> {n(var, 2)}, untouched blaming focus "
                  f"{sum(z['family'] != 'none' for z in (base[(u['capture'], 'none')] for u in un))} -> "
                  f"{sum(z['family'] != 'none' for z in un)} of {len(un)}; sets better {sum(s.endswith('better') for s in sets)}, "
                  f"worse {sum(s.endswith('worse') for s in sets)}, mixed {sum(s.endswith('mixed') for s in sets)}; "
                  f"scenes better {m['scenes_better']}, worse {m['scenes_worse']} (sign test p = {m['sign_test_p']}): "
                  f"{json.dumps(m['scenes'])}")
        d = np.array([r["corrected_max_err_d"] - base[(r["capture"], r["kind"])]["corrected_max_err_d"] for r in rerun])
        print(f"\nthe corrected focus's largest error per set: smaller in {int((d < -5e-4).sum())}, larger in "
              f"{int((d > 5e-4).sum())} (by more than 0.0005 D) of {len(d)}; median change {np.median(d):+.4f} D")
        secs = [r["seconds"] for r in rerun if r.get("seconds")]
        print(f"\nthe dense fit, wall clock: mean {np.mean(secs):.0f} s ({min(secs):.0f}-{max(secs):.0f} s, {len(secs)} sets)")
    return out.getvalue()


def subset_parser(doc: str, until: str, tally_help: str = "the reruns' rows") -> argparse.ArgumentParser:
    """The command line the subset probes share (this one, focus_ptc_subset, focus_exposure_subset): --plan, --run
    --until --lock, --tally --out; `until` is the declared cut-off (HH:MM UTC) after which no command starts."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--plan", action="store_true", help="print the sets in their order and the lane-B commands")
    ap.add_argument("--tally", nargs="+", type=Path, help=tally_help)
    ap.add_argument("--out", type=Path, help="with --tally: also write the table here (atomically)")
    ap.add_argument("--run", action="store_true", help="run the --plan commands in this process (lane B's lock each)")
    ap.add_argument("--until", default=until, type=until_arg,
                    help="with --run: start no command at or after this time (HH:MM UTC)")
    ap.add_argument("--lock", type=Path, default=Path("/work/heavy2.lock"), help="with --run: the lane's lock file")
    return ap


def tally_out(ap: argparse.ArgumentParser, a: argparse.Namespace, text_of) -> int:
    """The subset probes' --tally: refused in one line without it or with a results file missing; the table
    `text_of(rows)` of the files' rows printed, and written to --out atomically."""
    if not a.tally:
        ap.error("--plan or --tally")
    for f in a.tally:
        if not f.is_file():
            ap.error(f"--tally {f}: no such results file")
    text = text_of(read(a.tally))
    print(text)
    if a.out:
        write_text_atomic(a.out, text)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = subset_parser(__doc__, "01:14", "the reruns' rows (with the earlier probe's: DONE_FILES)")
    a = ap.parse_args(argv)
    order = plan()
    if a.run:
        run(commands(order), a.until, a.lock)
        return 0
    if a.plan:
        for s, c, k in order:
            print(s, c, k)
        print(f"\n{len(order)} sets: " + ", ".join(f"{s} {sum(x[0] == s for x in order)}" for s in ("H0", "A1", "A2", "H1")))
        print("\n".join(commands(order)))
        return 0
    strata = {(c, k): s for s, c, k in order}
    strata.update({(r["capture"], r["kind"]): "probe" for r in read(ROOT / "results" / f for f in DONE_FILES)})
    return tally_out(ap, a, lambda rows: tally(rows, strata))


if __name__ == "__main__":
    sys.exit(main())
