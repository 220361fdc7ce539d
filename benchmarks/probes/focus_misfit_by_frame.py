"""Which frames carry the part of the per-frame focus estimates' error that depends on the metadata? (issue 32, the
"shared twin misfit"; `focus_shared_misfit` part 2: every set carries its untouched copy's error pattern, amplified
where the metadata is further off.) On stored `bench_diagnose_focus` rows, development rows only (rounds 1-11; each
set's last row); nothing is fitted again and nothing held out enters it.

A set's *own part* at a frame is its estimate's error less its scene's untouched copy's at that frame (the images are
the same, only the metadata differs), over the frames fitted in both (`frame_err_d` finite). Its rms, diopters, by:
- the frame's expected noise share (`frame_noise_share`, the set's own, at its estimate; frames at or over
  `focusfit.NOISE_DOMINATED_SHARE` are left out, so they are not here);
- how far the frame's reported focus is from its truth (|reported - true|, diopters);
- the frame's rank among the fitted frames from the nearest (0: the nearest fitted, next to the frames left out);
and, per set kind, the share of the own part's sum of squares on the nearest fitted frame.

Then (bounds, not methods, as `focus_shared_misfit` part 6, `invariant`): every set's per-frame estimates replaced by
the truth plus its untouched copy's errors at the nearest fitted frame only (`nearest`), or at every fitted frame but
the nearest (`rest`), rescored against the code: how much of what the metadata's part costs sits on that frame.

With `--leave-out-share T ...`, a variant of the choice rescored from the same rows (`bench_diagnose_focus.rescored`,
on the estimates, as the code): every frame whose noise share at its estimate is T or more counts as left out (as
the noise rule's frames at `focusfit.NOISE_DOMINATED_SHARE`, 0.5, do: no estimate of its own, its family's value),
against the code rescored, per set and per scene (`focus_choice_nearest.scenes_moved`, sign test). **Declared before
any score of it was computed** (issue 32, 2026-11-28 ~03:00 UTC, T = 0.2, 0.3, 0.4): a rescoring cannot adopt it (the
runtime would prepare the sweep again without those frames, moving the others' estimates, and the frames' shares
would be taken at other estimates), so it only earns a whole rerun of the development sets if, against the code, more
scenes are better than worse with a sign test p < 0.05, no untouched copy blames focus and claimed-wrong does not
grow; otherwise it is recorded as measured and dropped. Rows without noise shares keep the code's outcome.

    python -m benchmarks.probes.focus_misfit_by_frame RESULTS.jsonl ... [--leave-out-share 0.2 0.3 0.4]
        [--out results/focus_misfit_by_frame.md]
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from collections import defaultdict
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

SHARE_BINS = (0.0, 0.05, 0.1, 0.2, 0.3, 0.5)
OFF_BINS_D = (0.0, 0.01, 0.03, 0.06, 0.1, 0.3)


def own_parts(rows: list[dict]) -> list[dict]:
    """Per fitted frame of every set with an error: its set, kind, own part (D), noise share, |reported - true| (D) and
    rank among the set's fitted frames from the nearest."""
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes.focus_shared_misfit import truth

    last = {(r["capture"], r["kind"]): r for r in rows}
    out = []
    for (cap, kind), r in sorted(last.items()):
        un = last.get((cap, "none"))
        if kind == "none" or un is None:
            continue
        e, u = (np.asarray(x["frame_err_d"], np.float64) for x in (r, un))
        share = np.asarray(r.get("frame_noise_share") or np.full(len(e), np.nan), np.float64)  # older rows: none
        t = truth(r)
        rep = bench.reported_d(kind, t, 0)  # a monotone curve bends either way by capture: |reported - true| alike
        fitted = np.flatnonzero(np.isfinite(e) & np.isfinite(u))
        order = np.argsort(-t[fitted])  # nearest (largest diopters) first
        rank = np.empty(len(fitted), int)
        rank[order] = np.arange(len(fitted))
        for j, i in enumerate(fitted):
            out.append({"set": f"{cap} {kind}", "kind": kind, "own_d": float(e[i] - u[i]), "share": float(share[i]),
                        "off_d": float(abs(rep[i] - t[i])), "toward_d": float(np.sign(rep[i] - t[i]) * (e[i] - u[i])),
                        "rank": int(rank[j])})
    return out


def rms(x) -> float:
    x = np.asarray(list(x), np.float64)
    return float(np.sqrt(np.mean(x ** 2))) if len(x) else float("nan")


def binned(parts: list[dict], key: str, edges) -> list[tuple[str, int, float, float, float]]:
    """Per bin of `key`: frames, rms own part, the own part's mean towards the reported focus (D; positive: the
    estimate moved from the untouched copy's towards the reported focus) and the fraction of frames moved that way
    (of those whose reported focus is not the truth)."""
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = [p for p in parts if lo <= p[key] < hi]
        tw = [p["toward_d"] for p in sel if p["off_d"] > 1e-9]
        out.append((f"{lo}-{hi}", len(sel), rms(p["own_d"] for p in sel), float(np.mean(tw)) if tw else float("nan"),
                    float(np.mean(np.asarray(tw) > 0)) if tw else float("nan")))
    return out


def report(rows: list[dict]) -> str:
    parts = own_parts(rows)
    buf = io.StringIO()
    with redirect_stdout(buf):
        print(f"{len(parts)} fitted frames of {len({p['set'] for p in parts})} sets with an error; rms own part "
              f"{rms(p['own_d'] for p in parts):.4f} D ({sum(np.isnan(p['share']) for p in parts)} frames of rows that "
              "record no noise share: in no noise-share bin)\n")
        for key, edges, name in (("share", SHARE_BINS, "noise share"), ("off_d", OFF_BINS_D, "|reported - true| (D)")):
            print(f"| {name} | frames | rms own part (D) | mean towards the reported focus (D) | fraction moved towards it "
                  "|\n|---|---|---|---|---|")
            for b, n, v, tw, fr in binned(parts, key, edges):
                print(f"| {b} | {n} | {v:.4f} | {tw:+.4f} | {fr:.2f} |")
            print()
        print("| rank from the nearest fitted frame | frames | rms own part (D) |\n|---|---|---|")
        for k in range(max(p["rank"] for p in parts) + 1):
            sel = [p["own_d"] for p in parts if p["rank"] == k]
            print(f"| {k} | {len(sel)} | {rms(sel):.4f} |")
        print()
        # the same split with the off-truth distance held in a band: is it the noise share or the metadata's size?
        print("| |reported - true| (D) | noise share < 0.1: frames, rms (D) | 0.1-0.2 | 0.2-0.5 |\n|---|---|---|---|")
        for lo, hi in zip(OFF_BINS_D[:-1], OFF_BINS_D[1:]):
            cells = []
            for a, b in ((0.0, 0.1), (0.1, 0.2), (0.2, 0.5)):
                sel = [p["own_d"] for p in parts if lo <= p["off_d"] < hi and a <= p["share"] < b]
                cells.append(f"{len(sel)}, {rms(sel):.4f}")
            print(f"| {lo}-{hi} | " + " | ".join(cells) + " |")
        print()
        by_kind: dict = defaultdict(list)
        for p in parts:
            by_kind[p["kind"]].append(p)
        print("| kind | frames | rms own part (D) | share of its sum of squares on the nearest fitted frame |\n"
              "|---|---|---|---|")
        for k, ps in sorted(by_kind.items()):
            ss = sum(p["own_d"] ** 2 for p in ps)
            near = sum(p["own_d"] ** 2 for p in ps if p["rank"] == 0)
            print(f"| {k} | {len(ps)} | {rms(p['own_d'] for p in ps):.4f} | {near / ss:.2f} |")
        print()
        worst = sorted(parts, key=lambda p: -abs(p["own_d"]))[:12]
        print("the largest own parts: " + "; ".join(
            f"{p['set']} rank {p['rank']} {p['own_d']:+.3f} D (share {p['share']:.2f}, off {p['off_d']:.3f} D)"
            for p in worst))
    return buf.getvalue()


def replaced(rows: list[dict], which: str) -> list[dict]:
    """The rows of scenes with an untouched copy, each set's `per_frame` estimates replaced by the truth plus the
    untouched copy's errors at its nearest fitted frame (`which` "nearest") or at its other fitted frames ("rest")."""
    from benchmarks.probes.focus_shared_misfit import truth

    un = {r["capture"]: r for r in rows if r["kind"] == "none"}
    out = []
    for r in rows:
        if r["capture"] not in un:
            continue
        u = np.asarray(un[r["capture"]]["frame_err_d"], np.float64)
        e = np.asarray(r["frame_err_d"], np.float64)
        t = truth(r)
        both = np.flatnonzero(np.isfinite(u) & np.isfinite(e))
        sel = np.zeros(len(u), bool)
        if len(both):
            near = both[np.argmax(t[both])]
            sel[both] = True
            sel = np.eye(len(u), dtype=bool)[near] if which == "nearest" else sel & ~np.eye(len(u), dtype=bool)[near]
        fams = [dict(f) for f in r["families"]]
        per = next(f for f in fams if f["family"] == "per_frame")
        est = np.asarray(per["true_d"], np.float64)[0]
        per["true_d"] = [np.where(sel, t + u, est).tolist()]
        out.append({**r, "families": fams})
    return out


def bounds(rows: list[dict]) -> str:
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes.focus_choice_nearest import scenes_moved

    last = list({(r["capture"], r["kind"]): r for r in rows}.values())
    buf = io.StringIO()
    with redirect_stdout(buf):
        base = {(r["capture"], r["kind"]): x for r in last if (x := bench.rescored(r, "code", on_estimates=True))}
        for which in ("nearest", "rest"):
            var = [x for r in replaced(last, which) if (x := bench.rescored(r, "code", on_estimates=True))]
            b = [base[(r["capture"], r["kind"])] for r in var]
            m = scenes_moved(b, var)
            n = lambda rs, f: sum(f(r) for r in rs)  # noqa: E731
            det = lambda r: not r["frames_undetermined"]  # noqa: E731
            print(f"\nthe untouched copy's errors at {'the nearest fitted frame only' if which == 'nearest' else 'every fitted frame but the nearest'} "
                  f"({len(var)} sets): family right {n(b, lambda r: r['family_ok'])} -> {n(var, lambda r: r['family_ok'])}, "
                  f"within 0.02 D {n(b, lambda r: r['kind'] != 'none' and det(r) and r['corrected_max_err_d'] <= 0.02)} -> "
                  f"{n(var, lambda r: r['kind'] != 'none' and det(r) and r['corrected_max_err_d'] <= 0.02)}, claimed-wrong "
                  f"{n(b, lambda r: r['kind'] != 'none' and det(r) and r['corrected_max_err_d'] > 0.02)} -> "
                  f"{n(var, lambda r: r['kind'] != 'none' and det(r) and r['corrected_max_err_d'] > 0.02)}; scenes better "
                  f"{m['scenes_better']}, worse {m['scenes_worse']} (sign test p = {m['sign_test_p']}): {json.dumps(m['scenes'])}")
    return buf.getvalue()


def left_out_at(row: dict, t: float) -> dict:
    """The row with every frame whose noise share is t or more counted as left out (`frames_noise_dominated`)."""
    share = row.get("frame_noise_share")
    if not share:
        return row
    dom = np.asarray(row.get("frames_noise_dominated") or np.zeros(len(share), bool), bool)
    return {**row, "frames_noise_dominated": (dom | (np.asarray(share, np.float64) >= t)).tolist()}


def variant(rows: list[dict], shares: list[float]) -> str:
    """The `--leave-out-share` variants against the code, both rescored (module docstring)."""
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes.focus_choice_nearest import scenes_moved

    last = list({(r["capture"], r["kind"]): r for r in rows}.values())
    base = [bench.rescored(r, "code", on_estimates=True) for r in last]
    keep = [i for i, b in enumerate(base) if b is not None]
    base = [base[i] for i in keep]

    def counts(rs):
        det = [not r["frames_undetermined"] for r in rs]
        err = [r["kind"] != "none" for r in rs]
        return {"family right": sum(r["family_ok"] for r in rs),
                "within 0.02 D": sum(e and d and r["corrected_max_err_d"] <= 0.02 for r, e, d in zip(rs, err, det)),
                "claimed-wrong": sum(e and d and r["corrected_max_err_d"] > 0.02 for r, e, d in zip(rs, err, det)),
                "untouched blaming focus": sum(r["kind"] == "none" and r["family"] != "none" for r in rs),
                "sets with a frame undetermined": sum(not d for d in det)}

    buf = io.StringIO()
    with redirect_stdout(buf):
        print(f"{len(base)} sets rescored; the code: {json.dumps(counts(base))}")
        for t in shares:
            var = [bench.rescored(left_out_at(last[i], t), "code", on_estimates=True) for i in keep]
            m = scenes_moved(base, var)
            n = sum(bool(r.get("frame_noise_share")) and np.any(np.asarray(r["frame_noise_share"]) >= t) and
                    not np.all(np.asarray(r.get("frames_noise_dominated") or [False]) |
                               (np.asarray(r["frame_noise_share"]) < t)) for r in (last[i] for i in keep))
            print(f"\nleave out at noise share >= {t}: {n} sets lose a fitted frame; {json.dumps(counts(var))}; scenes "
                  f"better {m['scenes_better']}, worse {m['scenes_worse']} (sign test p = {m['sign_test_p']}): "
                  f"{json.dumps(m['scenes'])}")
    return buf.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--leave-out-share", type=float, nargs="*", default=[], help="the declared variant (docstring)")
    a = ap.parse_args(argv)
    for f in a.results:
        if not f.is_file():
            ap.error(f"{f}: no such results file")
    rows = [json.loads(x) for f in a.results for x in f.read_text().splitlines() if x.strip()]
    text = report(rows) + bounds(rows) + (variant(rows, a.leave_out_share) if a.leave_out_share else "")
    print(text)
    if a.out:
        lo = f" --leave-out-share {' '.join(map(str, a.leave_out_share))}" if a.leave_out_share else ""
        a.out.write_text(f"# `python -m benchmarks.probes.focus_misfit_by_frame "
                         f"{' '.join(str(f) for f in a.results)}{lo}`\n\n{text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
