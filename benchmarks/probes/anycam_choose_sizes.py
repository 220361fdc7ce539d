"""Choose an any-camera checkpoint on RF50 validation stacks swept with several frame counts (exploratory).

    python -m benchmarks.probes.anycam_choose_sizes --select S3.json S5.json S8.json [--out OUT.json]
        [--route SMALL LARGE]

The rule declared in docs/training.md ("The tenth run with few frames"): every input is an `anycam_stack_curve` result
on the same choosing stacks (`--first 12 --n 12`), swept with its own frame count (`--stack-size`, recorded as
"stack_size"). A checkpoint's score is the mean over the frame counts of its mean whole-frame MAE (m) over the
classical method's mean MAE (m) at that count, so each count weighs alike although 3-frame MAEs are several times
8-frame ones. The lowest score is chosen; ties go to the checkpoint given first. Checkpoints are matched by the path
each result names, so score every candidate under one path at every count. Several files of one count (a run scored
in parts) are pooled. Validation stacks only (training photographs): no held-out lens or test scene.

--route SMALL LARGE applies the routing rule declared in docs/training.md ("one file for few and many frames") to two
of the checkpoints instead: at each frame count the one with the lower MAE over the classical method's is the better,
and the threshold T is the largest count up to which SMALL is the better at every scored count (`training.train.route`
then runs SMALL on stacks of at most T frames).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def by_size(results: list[dict]) -> dict[int, dict]:
    """{frames: {"classical": mean MAE (m), "rows": {checkpoint: mean MAE (m)}}} from anycam_stack_curve results;
    files of one frame count must score the same stacks alike (a run scored in parts)."""
    out: dict[int, dict] = {}
    for r in results:
        s = r.get("stack_size")
        if s is None:
            raise SystemExit("a --select result has no stack_size (score it again with anycam_stack_curve "
                             "--stack-size)")
        key = (r.get("first", 0), r["n"])
        cl = float(np.mean(r["classical_lens_map"]["mae_m"]))
        got = out.setdefault(int(s), {"stacks": key, "classical": cl, "rows": {}})
        if (got["stacks"], got["classical"]) != (key, cl):
            raise SystemExit(f"the {s}-frame results score different stacks")
        for row in r["rows"]:
            v = float(np.mean(row["mae_m"]))
            if got["rows"].get(row["checkpoint"], v) != v:
                raise SystemExit(f"{row['checkpoint']}: scored twice with {s} frames, differently")
            got["rows"][row["checkpoint"]] = v
    if len({v["stacks"] for v in out.values()}) > 1:
        raise SystemExit("the frame counts score different stacks: " + ", ".join(
            f"{s} frames {v['stacks']}" for s, v in sorted(out.items())))
    return out


def scores(sizes: dict[int, dict]) -> dict[str, dict]:
    """{checkpoint: {"score": mean over frame counts of MAE / classical MAE, "ratios": {frames: ratio}}} for the
    checkpoints scored at every frame count, in the order the first count lists them."""
    first = next(iter(sizes.values()))["rows"]
    out = {}
    for ck in first:
        if all(ck in v["rows"] for v in sizes.values()):
            ratios = {s: v["rows"][ck] / v["classical"] for s, v in sorted(sizes.items())}
            out[ck] = {"score": float(np.mean(list(ratios.values()))), "ratios": ratios}
    return out


def route_threshold(sizes: dict[int, dict], small: str, large: str) -> int | None:
    """The largest frame count T such that `small` has the lower MAE at every scored count <= T (ties go to
    `large`, the net already shipped for many frames); None when `large` is the better already at the fewest."""
    t = None
    for s in sorted(sizes):
        rows = sizes[s]["rows"]
        for ck in (small, large):
            if ck not in rows:
                raise SystemExit(f"{ck}: not scored with {s} frames")
        if rows[small] >= rows[large]:
            break
        t = s
    return t


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--select", type=Path, nargs="+", required=True,
                    help="anycam_stack_curve results on the choosing stacks, one or more per frame count")
    ap.add_argument("--out", type=Path, help="JSON of every candidate's score and the choice")
    ap.add_argument("--route", nargs=2, metavar=("SMALL", "LARGE"),
                    help="two checkpoints as the results name them: print the routing threshold T instead")
    a = ap.parse_args(argv)
    for p in a.select:
        if not p.is_file():
            ap.error(f"{p}: no such file")
    if a.out and a.out.exists():
        ap.error(f"{a.out}: exists (choose another)")
    sizes = by_size([json.loads(p.read_text()) for p in a.select])
    if len(sizes) < 2:
        ap.error(f"--select: results of at least two frame counts, got {sorted(sizes)}")
    if a.route:
        return _route(sizes, *a.route, a.out)
    sc = scores(sizes)
    if not sc:
        ap.error("no checkpoint is scored at every frame count")
    left = sorted(set().union(*(v["rows"] for v in sizes.values())) - set(sc))
    chosen = min(sc, key=lambda k: sc[k]["score"])  # min keeps the first of equal scores
    counts = sorted(sizes)
    print("| checkpoint | " + " | ".join(f"{s} frames / classical" for s in counts) + " | score |")
    print("|---|" + "---|" * (len(counts) + 1))
    for ck, v in sc.items():
        mark = " (chosen)" if ck == chosen else ""
        print(f"| {ck}{mark} | " + " | ".join(f"{v['ratios'][s]:.3f}" for s in counts) + f" | {v['score']:.3f} |")
    print("classical mean MAE (m): " + ", ".join(f"{s} frames {sizes[s]['classical']:.3f}" for s in counts))
    if left:
        print(f"left out, not scored at every frame count: {len(left)}", file=sys.stderr)
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(a.out, json.dumps({
            "chosen": chosen, "chosen_score": sc[chosen]["score"], "select": [str(p) for p in a.select],
            "classical_mae_m": {str(s): sizes[s]["classical"] for s in counts},
            "candidates": {ck: {"score": v["score"], "ratios": {str(s): r for s, r in v["ratios"].items()}}
                           for ck, v in sc.items()},
            "left_out": left}, indent=1))
    return 0


def _route(sizes: dict[int, dict], small: str, large: str, out: Path | None) -> int:
    t = route_threshold(sizes, small, large)
    print(f"| frames | {small} / classical | {large} / classical | better |")
    print("|---|---|---|---|")
    for s in sorted(sizes):
        r = {ck: sizes[s]["rows"][ck] / sizes[s]["classical"] for ck in (small, large)}
        print(f"| {s} | {r[small]:.3f} | {r[large]:.3f} | {'small' if r[small] < r[large] else 'large'} |")
    print(f"threshold T = {t}: stacks of at most T frames run {small}" if t is not None
          else f"{large} is the better at every count: nothing to route")
    if out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(out, json.dumps({
            "small": small, "large": large, "max_small_frames": t,
            "ratios": {str(s): {ck: sizes[s]["rows"][ck] / sizes[s]["classical"] for ck in (small, large)}
                       for s in sorted(sizes)},
            "classical_mae_m": {str(s): sizes[s]["classical"] for s in sorted(sizes)}}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
