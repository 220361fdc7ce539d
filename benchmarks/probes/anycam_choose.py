"""Choose an any-camera run's checkpoint on one dozen RF50 validation stacks and judge it on another (exploratory).

    python -m benchmarks.probes.anycam_choose --select results/anycam_stack_curve_v9_select.json
        --judge results/anycam_stack_curve_v9.json [--first-run results/anycam_tiles_overlap_rf50_val.json]
        [--out OUT.json] [--png FIG.png]

The rule declared in docs/training.md ("The ninth run along its steps"): among the checkpoints `anycam_stack_curve`
scored on the choosing stacks (`--first 12`), the one with the lowest mean whole-frame MAE (m); it is then judged on
the judging stacks (the first 12, scored by the same probe), paired over those stacks with 95 % bootstrap intervals
(`aat_deploy.eval.stats.paired_ratio`) against the classical method with the lens map, in metres and in diopters,
and against the first run in 128 px tiles (`anycam_tiles` on the same stacks: its rows of those stacks, column 0).
Validation stacks only (training photographs): no held-out lens or test scene. A run scored in parts (a session's kept
checkpoints at a time) gives several files per role: their rows are pooled (`pool`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def pool(parts: list[dict], what: str) -> dict:
    """One anycam_stack_curve result from several of the same stacks (a run scored in parts): their rows pooled,
    each step once; the parts must agree on the stacks (first, n) and on the classical method's scores."""
    first = parts[0]
    for p in parts[1:]:
        if (p.get("first", 0), p["n"], p["classical_lens_map"]) != (first.get("first", 0), first["n"],
                                                                     first["classical_lens_map"]):
            raise SystemExit(f"{what}: the parts score different stacks")
    rows = {}
    for p in parts:
        for r in p["rows"]:
            if r["step"] in rows and rows[r["step"]]["mae_m"] != r["mae_m"]:
                raise SystemExit(f"{what}: step {r['step']} scored twice, differently")
            rows[r["step"]] = r
    return {**first, "rows": [rows[k] for k in sorted(rows)]}


def choose_window(select: dict, k: int) -> tuple[int, int, float]:
    """(first step, last step, score) of the k consecutive scored checkpoints whose mean of mean MAEs (m) is lowest
    (ties: the earlier window): the weights to average instead of one checkpoint (benchmarks.probes.anycam_swa)."""
    rows = sorted(select["rows"], key=lambda r: r["step"])
    if not 1 <= k <= len(rows):
        raise SystemExit(f"--window {k}: between 1 and the {len(rows)} checkpoints scored")
    means = [float(np.mean(r["mae_m"])) for r in rows]
    i = min(range(len(rows) - k + 1), key=lambda j: float(np.mean(means[j:j + k])))
    return rows[i]["step"], rows[i + k - 1]["step"], float(np.mean(means[i:i + k]))


def choose(select: dict) -> dict:
    """The row of `select` (an anycam_stack_curve result) with the lowest mean MAE (m); ties: the earlier step."""
    return min(sorted(select["rows"], key=lambda r: r["step"]), key=lambda r: float(np.mean(r["mae_m"])))


def judge(step: int, curve: dict, first_run_mae_m: list[float] | None) -> dict:
    """The judging stacks' scores of checkpoint `step` (in `curve`, an anycam_stack_curve result) against the
    classical method and the first run: means and paired ratios [point, low, high]."""
    from aat_deploy.eval.stats import paired_ratio

    rows = [r for r in curve["rows"] if r["step"] == step]
    if not rows:
        raise SystemExit(f"step {step}: not scored on the judging stacks")
    row, cl = rows[0], curve["classical_lens_map"]
    per = lambda v: [{"mae": float(x)} for x in v]  # noqa: E731
    out = {"step": step, "n": len(row["mae_m"]), "mae_m": float(np.mean(row["mae_m"])),
           "mae_d": float(np.mean(row["mae_d"])), "classical_mae_m": float(np.mean(cl["mae_m"])),
           "classical_mae_d": float(np.mean(cl["mae_d"])),
           "vs_classical_m": [float(v) for v in paired_ratio(per(row["mae_m"]), per(cl["mae_m"]))],
           "vs_classical_d": [float(v) for v in paired_ratio(per(row["mae_d"]), per(cl["mae_d"]))]}
    if first_run_mae_m is not None:
        first = first_run_mae_m[:len(row["mae_m"])]
        out["first_run_tiles_mae_m"] = float(np.mean(first))
        out["vs_first_run_tiles_m"] = [float(v) for v in paired_ratio(per(row["mae_m"]), per(first))]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--select", type=Path, nargs="+", required=True,
                    help="anycam_stack_curve results on the choosing stacks (one per part of the run)")
    ap.add_argument("--judge", type=Path, nargs="+", required=True,
                    help="anycam_stack_curve results on the judging stacks (one per part of the run)")
    ap.add_argument("--first-run", type=Path, default=ROOT / "results" / "anycam_tiles_overlap_rf50_val.json",
                    help="anycam_tiles result of the first run (column 0: 128 px tiles) on the judging stacks")
    ap.add_argument("--out", type=Path, help="JSON of the choice and the judgement")
    ap.add_argument("--png", type=Path, help="also draw the pooled choosing curve, the chosen step marked")
    ap.add_argument("--window", type=int, help="instead: only say which K consecutive checkpoints to average")
    a = ap.parse_args(argv)
    for p in (*a.select, *a.judge, a.first_run):
        if not p.is_file():
            ap.error(f"{p}: no such file")
    for out in (a.out, a.png):
        if out and out.exists():
            ap.error(f"{out}: exists (choose another)")
    sel = pool([json.loads(p.read_text()) for p in a.select], "--select")
    cur = pool([json.loads(p.read_text()) for p in a.judge], "--judge")
    (fs, ns), (fj, nj) = ((c.get("first", 0), len(c["classical_lens_map"]["mae_m"])) for c in (sel, cur))
    if fs < fj + nj and fj < fs + ns:  # overlapping ranges, not only equal starts: a stack in both would choose
        ap.error(f"--select (stacks {fs}-{fs + ns - 1}) and --judge ({fj}-{fj + nj - 1}) score the same stacks: "
                 "choose on one dozen, judge on another")
    if (sel.get("lens"), sel.get("split")) != (cur.get("lens"), cur.get("split")):
        ap.error(f"--select scores {sel.get('lens')} {sel.get('split')}, --judge {cur.get('lens')} {cur.get('split')}")
    # anycam_tiles scores stacks 0, 1, ...: its rows for the judging stacks start at the judge's first
    first = [r[0] for r in json.loads(a.first_run.read_text())["mae_m"]][fj:fj + nj]
    if len(first) < nj:
        ap.error(f"{a.first_run}: scores {len(first)} of the judging stacks {fj}-{fj + nj - 1}")
    if a.window is not None:
        lo, hi, score = choose_window(sel, a.window)
        print(f"window of {a.window}: steps {lo}-{hi} ({score:.3f} m on the choosing stacks, their mean; classical "
              f"{float(np.mean(sel['classical_lens_map']['mae_m'])):.3f})")
        return 0
    chosen = choose(sel)
    res = {"chosen_on": [str(p) for p in a.select], "chosen_mae_m": float(np.mean(chosen["mae_m"])),
           "chosen_classical_mae_m": float(np.mean(sel["classical_lens_map"]["mae_m"])),
           "judged_on": [str(p) for p in a.judge], **judge(chosen["step"], cur, first)}
    f = lambda v: f"{v[0]:.2f} [{v[1]:.2f}, {v[2]:.2f}]"  # noqa: E731
    print(f"chosen: step {res['step']} ({res['chosen_mae_m']:.3f} m on the choosing stacks, classical "
          f"{res['chosen_classical_mae_m']:.3f})")
    print(f"judged on {res['n']} other stacks: {res['mae_m']:.3f} m, {res['mae_d']:.3f} D; classical "
          f"{res['classical_mae_m']:.3f} m, {res['classical_mae_d']:.3f} D; the first run in tiles "
          f"{res['first_run_tiles_mae_m']:.3f} m")
    print(f"/ classical: {f(res['vs_classical_m'])} (m), {f(res['vs_classical_d'])} (D); / the first run in tiles: "
          f"{f(res['vs_first_run_tiles_m'])} (m)")
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(a.out, json.dumps(res, indent=1))
    if a.png:
        from benchmarks.probes.anycam_stack_curve import draw

        draw(sel["rows"], sel["classical_lens_map"], a.png, mark=res["step"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
