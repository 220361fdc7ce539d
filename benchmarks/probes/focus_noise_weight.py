"""The families' parameter fits with and without each frame weighed by its noise share (`focusfit.signal_weight`,
`WEIGHT_BY_NOISE_SHARE`; issue 32), paired on the same stored `bench_diagnose_focus` rows: the whole choice redone
both ways from the rows' stored fits (`bench_diagnose_focus.rescored`, families on the estimates), the benchmark's
counts for both, and the largest error per set paired: sets better / worse by more than 0.0005 D, the mean change per
scene and a sign test over the scenes that changed (the sets of a scene are copies of the same images, so the scene is the unit).
Rows without noise shares (older runs) are the same both ways and counted in the totals only. A set given in several
rows (capture, kind) counts once, its last row, and the output says how many rows that dropped. Development rows
only: nothing held out enters it.

    python -m benchmarks.probes.focus_noise_weight RESULTS.jsonl ... --out results/focus_noise_weight.md   # and .json
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

CHANGED_D = 0.0005  # a set's largest error counts as changed beyond this (the rows' errors are rounded to 1e-4 D)
SCENE_TIE_D = 1e-4  # a scene's mean change within this is a tie, left out of the sign test


def counts(rows: list[dict]) -> dict:
    """The benchmark's targets over rescored rows: family right, sets within 0.02 D with every frame determined,
    claimed determined but over 0.02 D, with a frame undetermined, untouched copies blaming focus, frames whose 95 %
    interval holds the truth."""
    err = [r for r in rows if r["kind"] != "none"]
    cov = sum(int(np.sum(np.abs(np.asarray(r["corrected_err_d"])) <= 1.959964 * np.asarray(r["corrected_sd_d"])[0] + 1e-4))
              for r in rows)
    return {"sets": len(rows), "family_right": sum(r["family_ok"] for r in rows),
            "within_0.02_d": sum(r["corrected_max_err_d"] <= 0.02 and not r["frames_undetermined"] for r in err),
            "claimed_over_0.02_d": sum(r["corrected_max_err_d"] > 0.02 and not r["frames_undetermined"] for r in err),
            "undetermined": sum(bool(r["frames_undetermined"]) for r in err), "sets_with_an_error": len(err),
            "untouched_blaming_focus": sum(r["family"] != "none" for r in rows if r["kind"] == "none"),
            "frames_covered": cov, "frames": sum(len(r["corrected_err_d"]) for r in rows)}


def sign_test(k: int, n: int) -> float:
    """Two-sided binomial sign test: P(a count as far from n / 2 as k) under p = 1/2."""
    far = abs(k - n / 2)
    return min(1.0, sum(math.comb(n, i) for i in range(n + 1) if abs(i - n / 2) >= far - 1e-9) / 2 ** n)


def last_row_per_set(rows: list[dict]) -> list[dict]:
    """Each (capture, kind) set's last row, in first-seen order; a set in several rows (e.g. rerun in a later file)
    is said in one line on stdout, not silently dropped."""
    uniq = list({(r["capture"], r["kind"]): r for r in rows}.values())
    if len(rows) > len(uniq):
        print(f"{len(rows) - len(uniq)} of {len(rows)} rows repeat a set (capture, kind) given earlier: each set's "
              "last row is used\n")
    return uniq


def compare(rows: list[dict]) -> dict:
    from benchmarks import bench_diagnose_focus as bench

    given = len(rows)
    rows = last_row_per_set(rows)
    pairs = [(bench.rescored(r, "plain", on_estimates=True, noise_weight=False),
              bench.rescored(r, "weighed", on_estimates=True, noise_weight=True)) for r in rows]
    pairs = [(a, b) for a, b in pairs if a is not None]
    out = {"rows_repeating_a_set": given - len(rows), "plain": counts([a for a, _ in pairs]),
           "weighed": counts([b for _, b in pairs])}
    per_scene, better, worse = {}, 0, 0
    print("| set | plain: family, largest error (D), frames undetermined | weighed |\n|---|---|---|")
    for a, b in sorted(pairs, key=lambda x: (x[0]["capture"], x[0]["kind"])):
        if not a.get("frame_noise_share"):
            continue
        d = b["corrected_max_err_d"] - a["corrected_max_err_d"]
        per_scene.setdefault(a["capture"], []).append(d)
        better, worse = better + (d < -CHANGED_D), worse + (d > CHANGED_D)
        if abs(d) > CHANGED_D or (a["family"], a["frames_undetermined"]) != (b["family"], b["frames_undetermined"]):
            print(f"| {a['capture']} {a['kind']} | {a['family']}, {a['corrected_max_err_d']:.4f}, {a['frames_undetermined']} | "
                  f"{b['family']}, {b['corrected_max_err_d']:.4f}, {b['frames_undetermined']} |")
    means = {k: float(np.mean(v)) for k, v in sorted(per_scene.items())}
    down, up = sum(v < -SCENE_TIE_D for v in means.values()), sum(v > SCENE_TIE_D for v in means.values())
    out["paired"] = {"sets_with_noise_shares": sum(len(v) for v in per_scene.values()), "sets_better": int(better),
                     "sets_worse": int(worse), "scene_mean_change_d": {k: round(v, 5) for k, v in means.items()},
                     "scenes_better": int(down), "scenes_worse": int(up), "scenes": len(means),
                     "sign_test_p_scenes": round(sign_test(down, down + up), 4) if down + up else None}
    print("\n| counts | plain | weighed |\n|---|---|---|")
    for k in out["plain"]:
        print(f"| {k} | {out['plain'][k]} | {out['weighed'][k]} |")
    print("\n```json\n" + json.dumps(out, indent=1) + "\n```")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="bench_diagnose_focus results files (development rows)")
    ap.add_argument("--out", type=Path, required=True, help="the tables (.md), the summary beside it as .json; never "
                    "an existing file")
    a = ap.parse_args(argv)
    for f in a.results:  # one line before any work
        if not f.is_file():
            ap.error(f"{f}: no such results file")
    if a.out.suffix != ".md":
        ap.error(f"--out {a.out}: a .md file (the summary goes beside it as .json)")
    for f in (a.out, a.out.with_suffix(".json")):
        if f.exists():
            ap.error(f"{f}: exists (choose another --out)")
    from aat_deploy.io.atomic import write_text_atomic

    buf = io.StringIO()
    with redirect_stdout(buf):
        summary = compare([json.loads(x) for f in a.results for x in f.read_text().splitlines() if x.strip()])
    print(buf.getvalue())
    files = " ".join(str(f) for f in a.results)
    write_text_atomic(a.out.with_suffix(".json"), json.dumps({"files": files.split(), **summary}, indent=1) + "\n")
    write_text_atomic(a.out, f"# `python -m benchmarks.probes.focus_noise_weight {files} --out {a.out}`\n\n"
                      + buf.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
