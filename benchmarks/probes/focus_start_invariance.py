"""Where does the part of the per-frame focus estimates' error that depends on the metadata come from? (issue 32, after
the eleventh round; `focus_shared_misfit` part 2: every set carries its untouched copy's error pattern, amplified
where the metadata is further off, e.g. scene 3303's scale 1.1 set 1.9 times.) Development sets only (the spent
eleventh round's scene 3303 and its like), rerun through the first-round focus fit (`bench_diagnose_focus
--fit-only`) in one of five ways, nothing else changed:

- `reanchor`: the binning correction anchored again at the new estimates until every estimate lies within
  `anchors.REANCHOR_AGAIN_D` of a focus it is anchored at (at most `anchors.REANCHOR_ROUNDS` anchor sets after the
  first; the code anchors once unless `anchors.DENSE_ANCHORS`): the runtime's `anchors.densely_anchored` with
  `DENSE_STEPS` 0. Is it the correction interpolated between anchors off the truth?
- `start`: the set's copy reports its own stored first-pass estimates as its focus (`per_frame`; the frames it left
  out: its chosen family's value), so every step that starts from the reported focus (the sweep's range, the anchors,
  the robust preparation's floors, the full well) starts near the truth, as the untouched copy's do: are its errors
  then the untouched copy's?
- `refit`: the full well fitted again on the sweep whose binning correction is anchored at the estimates too
  (`fitters.FULL_WELL_ON_FINAL_SWEEP`; the code fits it once, on the first sweep, anchored at the reported focus):
  is it the full well, fitted where the correction is exact only at the reported focus?
- `dense`: as `reanchor`, with anchor sets at the code's estimates +- 1 to `--dense-steps` (2) steps of `--dense-d`
  (0.01 D) first (the runtime's `anchors.DENSE_ANCHORS`, with `--dense-moved-d` its `DENSE_MOVED_D`, 0: always):
  is the correction, which changes fastest near focus, sampled too coarsely around the truth?
- `near`: the set's copy reports the true focus plus NEAR_D diopters (`--near-d`, e.g. 0.002 D): is the untouched
  copy's pattern the fit's error at any reported focus near the truth, or only where the reported focus is the truth
  itself, bit for bit (the renderer that made the capture and the twin's then render the same optics)?
- `step`: the focus sweep rendered every `--step-d` diopters (e.g. 0.03) instead of `fitters.SWEEP_STEP_D` (0.06), the
  twin's curves Catmull-Rom interpolated between: is the pattern every set of a scene shares, its untouched copy's
  included, the interpolation between the sweep's focus distances? (The sweep's range, hence its grid, is the same
  for every set of a scene whose nearest and furthest reported focus lie within `SWEEP_MARGIN_D` of the model's focus
  range: so an interpolation error is shared, not a part that depends on the metadata.)
- `fullwell`: the focus twin's full well fixed at `--full-well-e` electrons (an oracle: the noise the captures were
  rendered with, 8000 e- by `aat-render`'s default) instead of fitted against the expected floor
  (`fitters.full_well_on_floor`): is the shared pattern the noise floor at a misfitted full well?
- `ptc`: the focus twin's full well measured on the captures' RAW mosaics by photon transfer before the focus fit
  (`fitters.FULL_WELL_BY_PHOTON_TRANSFER`, `aat_deploy/diagnose/photon.py`), the capture alone, no truth: the
  declared change of `focus_ptc_subset`.
- `ptc_exposure`: `ptc` with the floor put at the capture's exposure (`fitters.FLOOR_AT_CAPTURE_EXPOSURE`: the measured
  full well times the capture's brightness over the twin's, `fitters.capture_exposure`): the declared change of
  `focus_exposure_subset`.
- `code`: nothing changed (the code as it is, rerun: on another machine the captures are rendered again, so a
  comparison needs the code's rows from the same machine).
- `channel`: the binning correction each channel's own under its floor (`anchors.PER_CHANNEL`); `ptc_exposure_channel`:
  that with `ptc_exposure` (`focus_channel_correction`).

Then `--summary` prints, per rerun set, its errors against the stored row's and the untouched copy's (the
coefficient on the untouched errors: 1 is the untouched pattern, the stored rows' coefficient beside it), and what
the stored row's family choice becomes with the rerun's estimates (`bench_diagnose_focus.rescored`, the families
refitted to them against the set's own reported focus; only meaningful for `start`, whose fitted families are against
the estimates it was told).

    python -m benchmarks.probes.focus_start_invariance --mode start --rows results/diagnose_focus_fresh11_fitonly.jsonl \\
        --out results/focus_start_invariance_start.jsonl -- --fit-only --threads 1 --fresh11 4 --sets scene3303:scale_1.1
    python -m benchmarks.probes.focus_start_invariance --summary results/focus_start_invariance_start.jsonl \\
        --rows results/diagnose_focus_fresh11_fitonly.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

# the modes that set runtime switches: (FULL_WELL_BY_PHOTON_TRANSFER, FLOOR_AT_CAPTURE_EXPOSURE, anchors.PER_CHANNEL)
# on, or left at the code's value (CODE_SWITCHES, read when this module is imported, before any mode set them)
SWITCHES = {"code": (False, False, False), "ptc": (True, False, False), "ptc_exposure": (True, True, False),
            "channel": (False, False, True), "ptc_exposure_channel": (True, True, True)}


def _code_switches() -> dict:
    from aat_deploy.diagnose import anchors, fitters

    return {"FULL_WELL_BY_PHOTON_TRANSFER": fitters.FULL_WELL_BY_PHOTON_TRANSFER,
            "FLOOR_AT_CAPTURE_EXPOSURE": fitters.FLOOR_AT_CAPTURE_EXPOSURE, "PER_CHANNEL": anchors.PER_CHANNEL}


CODE_SWITCHES = _code_switches()


def first_pass(row: dict) -> np.ndarray:
    """(S,) a stored row's per-frame estimates, its chosen family's value at the frames it left out (diopters)."""
    fams = {f["family"]: f for f in row["families"]}
    est = np.asarray(fams["per_frame"]["true_d"], np.float64)[0]
    gone = np.asarray(row.get("frames_noise_dominated") or np.zeros(len(est), bool), bool)
    if row.get("frames_left_out_on_bound"):
        gone = gone | np.asarray(row["frames_left_out_on_bound"], bool)
    return np.where(gone, np.asarray(fams[row["family"]]["true_d"], np.float64)[0], est)


def use_runtime(dense_d: float = 0.0, dense_steps: int = 2, moved_d: float = 0.0) -> None:
    """Modes `reanchor` (dense_d 0) and `dense`: the runtime's `anchors.DENSE_ANCHORS` on, with these settings (this
    probe kept its own copy of that logic until it moved into the runtime)."""
    from aat_deploy.diagnose import anchors

    anchors.DENSE_ANCHORS = True
    anchors.DENSE_STEP_D, anchors.DENSE_STEPS = (dense_d, dense_steps) if dense_d else (0.0, 0)
    anchors.DENSE_MOVED_D = moved_d


def summary(rerun: list[dict], stored: list[dict]) -> list[dict]:
    """Per rerun set: its errors, the stored row's, the untouched copy's, each set's coefficient on the untouched
    errors, and the stored row's choice with the rerun's estimates (rescored)."""
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes.focus_shared_misfit import truth as true_focus_d

    rows = {(r["capture"], r["kind"]): r for r in stored}
    out = []
    for r in rerun:
        old, un = rows[(r["capture"], r["kind"])], rows[(r["capture"], "none")]
        u = np.asarray(un["frame_err_d"], np.float64)

        def coef(e):
            e = np.asarray(e, np.float64)
            m = np.isfinite(e) & np.isfinite(u)
            return round(float(e[m] @ u[m] / (u[m] @ u[m])), 2)

        fams = [dict(f) for f in old["families"]]
        per = next(f for f in fams if f["family"] == "per_frame")
        truth = true_focus_d(old)
        new_e = np.asarray(r["frame_err_d"], np.float64)
        per["true_d"] = [np.where(np.isfinite(new_e), truth + new_e, np.asarray(per["true_d"][0], np.float64)).tolist()]
        re = bench.rescored({**old, "families": fams}, "probe", on_estimates=True)
        base = bench.rescored(old, "probe", on_estimates=True)
        out.append({"set": f"{r['capture']} {r['kind']}", "err_d": np.round(new_e, 3).tolist(),
                    "stored_err_d": np.round(np.asarray(old["frame_err_d"], np.float64), 3).tolist(),
                    "untouched_err_d": np.round(u, 3).tolist(), "coef": coef(new_e), "stored_coef": coef(old["frame_err_d"]),
                    "choice_stored": f"{base['family']} {base['corrected_max_err_d']:.4f}",
                    "choice_with_rerun_estimates": f"{re['family']} {re['corrected_max_err_d']:.4f}",
                    # the rerun's own fit (its reported focus the set's: not for `start` or `near`)
                    "rerun_fit": f"{r['family']} {r['corrected_max_err_d']:.4f} undetermined {r.get('frames_undetermined')}",
                    "seconds": r.get("seconds"),
                    "robust_anchors": sorted(k for k in r.get("robust", {}) if "anchor" in k)})
    return out


def tally(rerun: list[dict], stored: list[dict]) -> dict:
    """The reruns' own fits against their stored rows rescored by the code (`bench_diagnose_focus.rescored`), set by
    set and scene by scene (`focus_choice_nearest.scenes_moved`); only meaningful for modes that keep the set's
    reported focus (`reanchor`, `refit`, `dense`)."""
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes.focus_choice_nearest import scenes_moved

    rows = {(r["capture"], r["kind"]): r for r in stored}
    base = [bench.rescored(rows[(r["capture"], r["kind"])], "code", on_estimates=True) for r in rerun]
    m = scenes_moved(base, rerun)
    sets = [s for v in m["scenes"].values() for s in v]
    return {**m, "sets_better": sum(s.endswith("better") for s in sets), "sets_worse": sum(s.endswith("worse") for s in sets)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", choices=("start", "reanchor", "near", "refit", "dense", "step", "fullwell",
                                                        "ptc", "ptc_exposure", "code", "channel",
                                                        "ptc_exposure_channel"))
    ap.add_argument("--dense-d", type=float, default=0.01, help="with --mode dense: the anchors' step (D)")
    ap.add_argument("--dense-steps", type=int, default=2, help="with --mode dense: steps either side")
    ap.add_argument("--dense-moved-d", type=float, default=0.0, help="with --mode dense: only where some frame's "
                    "first estimate lies this far (D) from its reported focus (anchors.DENSE_MOVED_D)")
    ap.add_argument("--step-d", type=float, default=0.03, help="with --mode step: the sweep's spacing (D)")
    ap.add_argument("--full-well-e", type=float, default=8000.0, help="with --mode fullwell: the full well (e-)")
    ap.add_argument("--near-d", type=float, default=0.002, help="with --mode near: the reported focus's offset (D)")
    ap.add_argument("--rows", type=Path, nargs="+", required=True, help="the stored rows of the sets (and their "
                    "untouched copies; several files: a set's last row)")
    ap.add_argument("--out", type=Path, help="with --mode: the rerun's rows (bench_diagnose_focus --out)")
    ap.add_argument("--summary", type=Path, nargs="+", help="only summarise these rerun rows against --rows")
    a, rest = ap.parse_known_args(argv)
    rest = [x for x in rest if x != "--"]
    for f in a.rows:
        if not f.is_file():
            ap.error(f"--rows {f}: no such results file")
    stored = [json.loads(x) for f in a.rows for x in f.read_text().splitlines() if x.strip()]
    if a.summary:
        rerun = [json.loads(y) for f in a.summary for y in f.read_text().splitlines() if y.strip()]
        have = {(r["capture"], r["kind"]) for r in stored}
        gone = sorted({f"{c} {k}" for r in rerun for c, k in ((r["capture"], r["kind"]), (r["capture"], "none"))
                       if (c, k) not in have})
        if gone:
            ap.error(f"--rows {' '.join(str(f) for f in a.rows)} has no row of {', '.join(gone)} (give the rerun "
                     "sets' own round)")
        for x in summary(rerun, stored):
            print(json.dumps(x))
        m = tally(rerun, stored)
        print(f"{len(rerun)} sets: {m['sets_better']} better, {m['sets_worse']} worse (family right, within 0.02 D with "
              f"every frame determined, or not claimed over 0.02 D); by scene {m['scenes_better']} better, "
              f"{m['scenes_worse']} worse (sign test p = {m['sign_test_p']})")
        return 0
    if a.mode is None or a.out is None:
        ap.error("--mode and --out (or --summary)")
    from benchmarks import bench_diagnose_focus as bench

    if a.mode == "start":
        rows = {(r["capture"], r["kind"]): r for r in stored}
        if "--sets" not in rest[:-1]:
            ap.error("--mode start: name the sets after --, as --sets CAPTURE:KIND,... (their first pass is the focus)")
        pairs = [x.split(":") for x in rest[rest.index("--sets") + 1].split(",")]
        cap_of = {kd: c for c, kd in pairs}
        if len(cap_of) < len(pairs):
            ap.error("--mode start: one capture per kind in --sets (the benchmark asks for the reported focus by kind)")

        def reported(kind, true_d, k):
            return first_pass(rows[(cap_of[kind], kind)])

        bench.reported_d = reported
    elif a.mode == "refit":
        from aat_deploy.diagnose import fitters

        fitters.FULL_WELL_ON_FINAL_SWEEP = True
    elif a.mode == "step":
        from aat_deploy.diagnose import fitters

        d = fitters.focus_sweep.__defaults__
        fitters.focus_sweep.__defaults__ = (a.step_d, *d[1:])  # its step is a default argument, bound at import
    elif a.mode == "fullwell":
        from aat_deploy.diagnose import fitters

        fitters.full_well_on_floor = lambda d, fw0: (a.full_well_e, {"oracle_full_well_e": a.full_well_e})
    elif a.mode in SWITCHES:  # every switch set, to the code's value where the mode leaves it: modes run one
        # after another in one process (`focus_dense_subset.run`) must not inherit each other's
        from aat_deploy.diagnose import anchors, fitters

        for (mod, name), on in zip(((fitters, "FULL_WELL_BY_PHOTON_TRANSFER"), (fitters, "FLOOR_AT_CAPTURE_EXPOSURE"),
                                    (anchors, "PER_CHANNEL")), SWITCHES[a.mode]):
            setattr(mod, name, True if on else CODE_SWITCHES[name])
    elif a.mode == "near":
        bench.reported_d = lambda kind, true_d, k: np.asarray(true_d, np.float64) + a.near_d
    else:
        use_runtime(a.dense_d if a.mode == "dense" else 0.0, a.dense_steps, a.dense_moved_d)
    sys.argv = ["bench_diagnose_focus", *rest, "--out", str(a.out)]
    bench.main()
    return 0


if __name__ == "__main__":
    sys.exit(main())
