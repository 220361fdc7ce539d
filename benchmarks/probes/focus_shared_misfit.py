"""The twin misfit shared by every set of a scene (issue 32, after the eleventh round; scenes 3303 and 2359): how much
of the per-frame focus estimates' error is common to a scene's sets, how it is read as a focus family, and whether
the choice can separate it with what a user has (one capture and its ground-truth depth). On stored
`bench_diagnose_focus` rows, development rows only (rounds 1-11: the eleventh round is spent, development material
since it was reported); nothing is fitted again and nothing held out enters it.

1. Per scene (its sets are copies of the same images with different focus metadata): the share of the estimates'
   sum of squared errors (`frame_err_d`, fitted frames) that the scene's mean error pattern explains, the rms error
   and the rms of that pattern, and the correlation of the untouched copy's errors with the other sets' mean.
2. Per set kind: the median coefficient of each set's errors on its scene's untouched copy's (1: the same misfit)
   and the median rms of the set's own part (errors less the untouched copy's).
3. Per scene: the untouched copy's errors c fitted as a + b t over its fitted frames (t the true focus, diopters;
   weights 1 / the row's modelled variance): b is the slope a misfit adds to e - reported against t, where a
   distance scale s adds 1 - 1/s (0.048 for 1.05), an offset nothing. A b near -(1 - 1/s) makes that scale look
   like an offset on the fitted frames. Listed with what each scale set was read as (the code, rescored).
4. The frames left out for noise: their robust preparation's estimates (`robust.noise_dominated_at_d`) against the
   truth (why they cannot tell the families apart where the others do not).
5. Variants of the choice, rescored from the rows' fits (`bench_diagnose_focus.rescored(on_estimates=True)`, the
   code as it is, and with the change): `glsL` the choice's chi2, its Laplace determinant and the error scale with
   the frames' errors correlated as the standard errors already assume (`focusfit.error_correlation`, length L
   diopters; L = 0 is the code), and `runnerD` every frame undetermined where a family within D of the chosen one's
   score (-2 log evidence: D = 2 is Kass and Raftery's "not worth more than a bare mention") puts it more than 0.02 D
   away (`focusfit.UNDETERMINED_SD_D`). The benchmark's counts for each, every set that moved, and the per-scene sign
   test against the code (`focus_choice_nearest.scenes_moved`).
6. The bound on making the estimates independent of the metadata (`invariant`): every set's per-frame estimates
   replaced by the truth plus its scene's untouched copy's errors (what the images alone give when the metadata is
   right; the set's own spreads, systematic errors and noise shares kept), rescored: what the part of the misfit that
   depends on the metadata costs, the shared part left as it is.

    python -m benchmarks.probes.focus_shared_misfit RESULTS.jsonl ... --out results/focus_shared_misfit.md
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
from collections import defaultdict
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

GLS_LENGTHS_D = (0.135, 0.3, 0.6)  # 0.135: focusfit.ERROR_CORRELATION_D; longer: the scenes' misfits err alike further
RUNNER_UP_GAPS = (2.0, 4.0, 6.0)  # -2 log evidence; 2: "not worth more than a bare mention" (Kass & Raftery 1995)


def sigma(row: dict) -> np.ndarray:
    """(S,) the row's modelled error of every frame's estimate (bootstrap spread and systematic error), diopters."""
    sd = np.asarray([np.nan if x is None else x for x in row["frame_focus_sd_d"][0]], np.float64)
    return np.hypot(sd, np.asarray(row["frame_systematic_d"], np.float64)[0])


def truth(row: dict) -> np.ndarray:
    """(S,) the row's true focus (diopters, to 1e-4 D): its chosen family's focus less its error."""
    fams = {f["family"]: f for f in row["families"]}
    return np.asarray(fams[row["family"]]["true_d"], np.float64)[0] - np.asarray(row["corrected_err_d"], np.float64)


def by_scene(rows: list[dict]) -> dict[str, dict[str, dict]]:
    out: dict = defaultdict(dict)
    for r in rows:
        out[r["capture"]][r["kind"]] = r
    return out


def shared(rows: list[dict]) -> tuple[list[dict], float]:
    """Part 1 per scene, and the share over every scene."""
    out, tot, com = [], 0.0, 0.0
    for sc, sets in by_scene(rows).items():
        e = np.array([np.asarray(r["frame_err_d"], np.float64) for r in sets.values()])
        e = e[:, np.isfinite(e).all(0)]  # the frames fitted in every set
        c = e.mean(0)
        ss, ssr = float(np.sum(e ** 2)), float(np.sum((e - c) ** 2))
        tot, com = tot + ss, com + ss - ssr
        corr = None
        if "none" in sets and len(sets) > 2:
            keep = np.isfinite(np.asarray(sets["none"]["frame_err_d"], np.float64))
            u = np.asarray(sets["none"]["frame_err_d"], np.float64)
            ok = keep & np.isfinite(np.array([np.asarray(r["frame_err_d"], np.float64) for r in sets.values()])).all(0)
            others = np.array([np.asarray(r["frame_err_d"], np.float64)[ok] for k, r in sets.items() if k != "none"])
            corr = round(float(np.corrcoef(u[ok], others.mean(0))[0, 1]), 2)
        out.append({"scene": sc, "sets": len(sets), "common_share": round(1 - ssr / ss, 2) if ss else None,
                    "rms_err_d": round(float(np.sqrt(np.mean(e ** 2))), 4),
                    "rms_common_d": round(float(np.sqrt(np.mean(c ** 2))), 4), "untouched_corr": corr})
    return out, round(com / tot, 3)


def per_kind(rows: list[dict]) -> list[dict]:
    """Part 2."""
    acc: dict = defaultdict(list)
    for sets in by_scene(rows).values():
        if "none" not in sets:
            continue
        u = np.asarray(sets["none"]["frame_err_d"], np.float64)
        for k, r in sets.items():
            e = np.asarray(r["frame_err_d"], np.float64)
            m = np.isfinite(u) & np.isfinite(e)
            if k == "none" or not m.any() or not np.any(u[m]):
                continue
            acc[k].append((float(e[m] @ u[m] / (u[m] @ u[m])), float(np.sqrt(np.mean((e[m] - u[m]) ** 2))),
                           float(np.sqrt(np.mean(u[m] ** 2)))))
    return [{"kind": k, "sets": len(v), "coef_on_untouched": round(float(np.median([x[0] for x in v])), 2),
             "rms_own_part_d": round(float(np.median([x[1] for x in v])), 4),
             "rms_untouched_d": round(float(np.median([x[2] for x in v])), 4)} for k, v in sorted(acc.items())]


def apparent_slope(rows: list[dict], code: list[dict]) -> list[dict]:
    """Part 3: per scene with an untouched copy, b of its errors c = a + b t (weighted), and what its scale sets
    were read as by the code (rescored rows `code`)."""
    read = {(r["capture"], r["kind"]): r for r in code}
    out = []
    for sc, sets in by_scene(rows).items():
        if "none" not in sets:
            continue
        u = sets["none"]
        c, t, s = np.asarray(u["frame_err_d"], np.float64), truth(u), sigma(u)
        m = np.isfinite(c) & np.isfinite(s) & (s > 0)
        if m.sum() < 3:
            continue
        w = 1 / s[m] ** 2
        x = np.stack([np.ones(m.sum()), t[m]], 1)
        a, b = np.linalg.solve(x.T @ (x * w[:, None]), x.T @ (w * c[m]))
        scales = {k: read[(sc, k)] for k in sets if k.startswith("scale_") and (sc, k) in read}
        out.append({"scene": sc, "slope": round(float(b), 4), "offset_d": round(float(a), 4),
                    "scales_read": {k[6:]: f"{r['family']} {r['corrected_max_err_d']:.3f}" for k, r in scales.items()}})
    return out


def left_out(rows: list[dict]) -> dict:
    """Part 4: the left-out frames' robust estimates against the truth, pooled and by rank among the left-out frames
    (0 the nearest)."""
    errs: dict = defaultdict(list)
    for r in rows:
        nd, exc = (r.get("robust") or {}).get("noise_dominated_at_d"), r.get("frames_noise_dominated")
        if not nd or not exc or not any(exc):
            continue
        e = np.asarray(nd[0], np.float64) - truth(r)
        for rank, i in enumerate(np.where(np.asarray(exc, bool))[0]):
            if np.isfinite(e[i]):
                errs[rank].append(abs(float(e[i])))
    pooled = np.concatenate([np.asarray(v) for v in errs.values()]) if errs else np.zeros(0)
    q = (lambda a: [round(float(x), 3) for x in np.quantile(a, [0.5, 0.9])]) if len(pooled) else (lambda a: None)
    return {"frames": len(pooled), "rms_d": round(float(np.sqrt(np.mean(pooled ** 2))), 3) if len(pooled) else None,
            "median_p90_abs_d": q(pooled),
            "by_rank": {k: {"frames": len(v), "rms_d": round(float(np.sqrt(np.mean(np.square(v)))), 3),
                            "median_p90_abs_d": q(np.asarray(v))} for k, v in sorted(errs.items())}}


def gls(length_d: float):
    """score_families and error_scale with the frames' errors correlated (`focusfit.error_correlation` of the
    per-frame estimates, length_d): chi2 = r' C^-1 r, the Laplace determinant of J' C^-1 J."""
    from aat_deploy.diagnose import focusfit as ff

    def blocks(fits, frame_sd, frames, systematic_d):
        e = fits["per_frame"].true_d
        sig = np.sqrt(np.asarray(frame_sd, np.float64) ** 2 + np.asarray(systematic_d) ** 2) * np.ones(e.shape)
        corr = ff.error_correlation(e, frames, length_d)
        out = []
        for n in range(e.shape[0]):
            u = np.asarray(frames[n]) > 0
            out.append((u, np.linalg.inv(sig[n][u][:, None] * corr[n][np.ix_(u, u)] * sig[n][u][None, :])))
        return out

    def chi2(f, e, bl):
        return sum(float((f.true_d[n][u] - e[n][u]) @ p @ (f.true_d[n][u] - e[n][u])) for n, (u, p) in enumerate(bl))

    def score(fits, frame_sd, frames, systematic_d=ff.SYSTEMATIC_D):
        bl = blocks(fits, frame_sd, frames, systematic_d)
        e, rep = fits["per_frame"].true_d, fits["none"].true_d
        for f in fits.values():
            jac, widths = ff.family_design(f.name, rep, f.true_d, frames, ff.fit_quantiser(f))
            k = jac.shape[-1]
            logdet = float(np.linalg.slogdet(sum(jac[n][u].T @ p @ jac[n][u] for n, (u, p) in enumerate(bl)))[1]) if k else 0.0
            f.score = chi2(f, e, bl) + logdet - k * math.log(2 * math.pi) + 2 * sum(math.log(w) for w in widths)

    def scale(fits, frame_sd, frames, systematic_d=ff.SYSTEMATIC_D):
        f = fits.get("monotone")
        dof = int((np.asarray(frames) > 0).sum()) - (f.k if f else 0)
        if f is None or "per_frame" not in fits or dof <= 0:
            return 1.0
        return math.sqrt(max(1.0, chi2(f, fits["per_frame"].true_d, blocks(fits, frame_sd, frames, systematic_d)) / dof))

    return score, scale


def runner_up(r: dict, gap: float) -> dict:
    """The rescored row r with every frame undetermined where a family scoring within gap of the chosen one puts it
    more than UNDETERMINED_SD_D away (the frames' errors and the family unchanged)."""
    from aat_deploy.diagnose import focusfit as ff

    fams = {x["family"]: x for x in r["families"]}
    best = np.asarray(fams[r["family"]]["true_d"], np.float64)[0]
    far = np.zeros(best.shape, bool)
    for k, f in fams.items():
        if k not in (r["family"], "per_frame") and f["score"] - fams[r["family"]]["score"] <= gap:
            far |= np.abs(np.asarray(f["true_d"], np.float64)[0] - best) > ff.UNDETERMINED_SD_D
    und = far | (np.asarray(r["corrected_sd_d"], np.float64)[0] >= ff.UNDETERMINED_SD_D)
    return {**r, "frames_undetermined": int(und.sum())}


def runner_gap(r: dict) -> float | None:
    """How far (-2 log evidence) the best family that puts some frame more than UNDETERMINED_SD_D from the chosen
    family's focus scores above it (None: no such family); `per_frame` is not counted."""
    from aat_deploy.diagnose import focusfit as ff

    fams = {x["family"]: x for x in r["families"]}
    best = np.asarray(fams[r["family"]]["true_d"], np.float64)[0]
    gaps = [f["score"] - fams[r["family"]]["score"] for k, f in fams.items() if k not in (r["family"], "per_frame")
            and np.nanmax(np.abs(np.asarray(f["true_d"], np.float64)[0] - best)) > ff.UNDETERMINED_SD_D]
    return min(gaps) if gaps else None


def gap_by_outcome(code: list[dict]) -> dict:
    """`runner_gap` over the code's sets with an error, by outcome: claimed determined but over 0.02 D, within 0.02 D
    with every frame determined, with a frame undetermined: sets, min, 5th percentile, median."""
    out: dict = defaultdict(list)
    for r in code:
        if r["kind"] == "none" or (g := runner_gap(r)) is None:
            continue
        det = not r["frames_undetermined"]
        out["claimed_over" if det and r["corrected_max_err_d"] > 0.02 else "within" if det else "undetermined"].append(g)
    return {k: {"sets": len(v), "min": round(min(v), 2), "p5": round(float(np.quantile(v, 0.05)), 2),
                "median": round(float(np.median(v)), 2), "max": round(max(v), 2)} for k, v in out.items()}


def variants(rows: list[dict]) -> dict[str, list[dict]]:
    """{variant: rescored rows}; '' is the code as it is."""
    from aat_deploy.diagnose import focusfit as ff
    from benchmarks import bench_diagnose_focus as bench

    def run():
        return [x for x in (bench.rescored(r, "probe", on_estimates=True) for r in rows) if x is not None]

    out = {"": run()}
    orig = ff.score_families, ff.error_scale
    try:
        for length in GLS_LENGTHS_D:
            ff.score_families, ff.error_scale = gls(length)
            out[f"gls{length:g}"] = run()
    finally:
        ff.score_families, ff.error_scale = orig
    for g in RUNNER_UP_GAPS:
        out[f"runner{g:g}"] = [runner_up(r, g) for r in out[""]]
    # the sets of scenes without an untouched copy are left out of it (its count of sets says how many remain)
    out["invariant"] = [x for x in (bench.rescored(r, "probe", on_estimates=True) for r in invariant(rows)) if x is not None]
    return out


def invariant(rows: list[dict]) -> list[dict]:
    """Part 6: the rows of scenes with an untouched copy, each set's `per_frame` estimates replaced by the truth plus
    the untouched copy's errors at the frames it fitted (the others keep the set's), ready for `rescored`."""
    un = {r["capture"]: r for r in rows if r["kind"] == "none"}
    out = []
    for r in rows:
        if r["capture"] not in un:
            continue
        u = np.asarray(un[r["capture"]]["frame_err_d"], np.float64)
        fams = [dict(f) for f in r["families"]]
        per = next(f for f in fams if f["family"] == "per_frame")
        est = np.asarray(per["true_d"], np.float64)[0]
        per["true_d"] = [np.where(np.isfinite(u), truth(r) + u, est).tolist()]
        out.append({**r, "families": fams})
    return out


def precision(base: dict, var: list[dict]) -> dict:
    """Paired over the sets with an error: how many sets' largest error is smaller / larger in var than in base (by
    more than `focus_noise_weight.CHANGED_D`), and the medians."""
    from benchmarks.probes.focus_noise_weight import CHANGED_D

    pairs = [(base[(r["capture"], r["kind"])]["corrected_max_err_d"], r["corrected_max_err_d"]) for r in var
             if r["kind"] != "none"]
    a = np.asarray(pairs, np.float64).reshape(-1, 2)
    return {"sets": len(a), "smaller": int(np.sum(a[:, 1] < a[:, 0] - CHANGED_D)),
            "larger": int(np.sum(a[:, 1] > a[:, 0] + CHANGED_D)),
            "median_code_d": round(float(np.median(a[:, 0])), 4) if len(a) else None,
            "median_invariant_d": round(float(np.median(a[:, 1])), 4) if len(a) else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="bench_diagnose_focus results files (development rows)")
    ap.add_argument("--out", type=Path, help="also write the tables there (.md, and the numbers as .json; never an "
                    "existing file)")
    a = ap.parse_args(argv)
    for f in a.results:  # one line before any work
        if not f.is_file():
            ap.error(f"{f}: no such results file")
    if a.out is not None and (a.out.suffix != ".md" or a.out.exists() or a.out.with_suffix(".json").exists()):
        ap.error(f"--out {a.out}: a .md file that does not exist yet (nor its .json)")
    from benchmarks.probes.focus_choice_nearest import moved_table, scenes_moved
    from benchmarks.probes.focus_noise_weight import CHANGED_D, counts, last_row_per_set

    buf = io.StringIO()
    with redirect_stdout(buf):
        rows = last_row_per_set([json.loads(x) for f in a.results for x in f.read_text().splitlines() if x.strip()])
        rows = [r for r in rows if r.get("families") and r.get("frame_systematic_d") and r.get("frame_err_d")]
        res = variants(rows)
        sh, share = shared(rows)
        print(f"## 1. The misfit common to a scene's sets\n\nOver every scene: {share:.1%} of the per-frame estimates' "
              "sum of squared errors is the scene's mean pattern.\n")
        print("| scene | sets | common share | rms error (D) | rms common (D) | corr(untouched, others' mean) |\n"
              "|---|---|---|---|---|---|")
        for x in sh:
            print(f"| {x['scene']} | {x['sets']} | {x['common_share']} | {x['rms_err_d']} | {x['rms_common_d']} | "
                  f"{x['untouched_corr']} |")
        kinds = per_kind(rows)
        print("\n## 2. Each set against its scene's untouched copy\n\n| kind | sets | median coefficient on the "
              "untouched errors | median rms own part (D) | median rms untouched (D) |\n|---|---|---|---|---|")
        for x in kinds:
            print(f"| {x['kind']} | {x['sets']} | {x['coef_on_untouched']} | {x['rms_own_part_d']} | "
                  f"{x['rms_untouched_d']} |")
        slopes = apparent_slope(rows, res[""])
        print("\n## 3. The untouched misfit's slope against the true focus (a scale s adds 1 - 1/s: 0.9 -0.111, "
              "0.95 -0.053, 1.05 +0.048, 1.1 +0.091, 1.15 +0.130)\n\n| scene | slope b | a (D) | scale sets read as "
              "(family, largest error D) |\n|---|---|---|---|")
        for x in sorted(slopes, key=lambda x: x["slope"]):
            print(f"| {x['scene']} | {x['slope']:+.4f} | {x['offset_d']:+.4f} | "
                  + "; ".join(f"{k}: {v}" for k, v in x["scales_read"].items()) + " |")
        lo = left_out(rows)
        print(f"\n## 4. The left-out frames' robust estimates\n\n{lo['frames']} frames: rms error {lo['rms_d']} D, "
              f"median and 90th percentile |error| {lo['median_p90_abs_d']} D; by rank among the left-out frames "
              "(0 the nearest): " + "; ".join(f"{k}: {v['frames']} frames, rms {v['rms_d']} D, median/p90 "
                                              f"{v['median_p90_abs_d']} D" for k, v in lo["by_rank"].items()))
        print("\n## 5. Variants of the choice (rescored)\n\n| variant | " + " | ".join(counts(res[""]).keys()) +
              " | scenes better | scenes worse | sign test p |\n|---|" + "---|" * (len(counts(res[""])) + 3))
        moved = {}
        for v, rs in res.items():
            m = scenes_moved(res[""], rs) if v else {"scenes_better": "", "scenes_worse": "", "sign_test_p": ""}
            moved[v] = m
            print(f"| {v or 'code'} | " + " | ".join(str(x) for x in counts(rs).values()) +
                  f" | {m['scenes_better']} | {m['scenes_worse']} | {m['sign_test_p']} |")
        gaps = gap_by_outcome(res[""])
        print("\nThe code's sets with an error, the gap (-2 log evidence) to the best family that puts a frame over "
              "0.02 D away, by outcome: " + "; ".join(f"{k}: {v}" for k, v in gaps.items()))
        base = {(r["capture"], r["kind"]): r for r in res[""]}
        prec = precision(base, res["invariant"])
        print(f"\ninvariant against the code, the largest error per set with an error: smaller in {prec['smaller']}, "
              f"larger in {prec['larger']} (by more than {CHANGED_D} D); its median {prec['median_code_d']} D -> "
              f"{prec['median_invariant_d']} D")
        moved_table(res)
    print(buf.getvalue())
    if a.out is not None:
        from aat_deploy.io.atomic import write_text_atomic

        cmd = f"python -m benchmarks.probes.focus_shared_misfit {' '.join(str(f) for f in a.results)} --out {a.out}"
        write_text_atomic(a.out, f"# `{cmd}`\n\n" + buf.getvalue())
        write_text_atomic(a.out.with_suffix(".json"), json.dumps(
            {"command": cmd, "common_share": share, "scenes": sh, "kinds": kinds, "slopes": slopes, "left_out": lo, "invariant_precision": prec, "runner_gap": gaps,
             "counts": {v or "code": counts(rs) for v, rs in res.items()},
             "sign_tests": {v: {k: m[k] for k in ("scenes_better", "scenes_worse", "sign_test_p")}
                            for v, m in moved.items() if v}}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
