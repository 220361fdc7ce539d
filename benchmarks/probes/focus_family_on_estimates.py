"""What if a focus-error family's corrected focus were its weighted least-squares fit to the per-frame estimates
(issue 32)? Understanding only, from stored `bench_diagnose_focus` rows: it changes nothing in the diagnosis.

The focus fit fits each family's parameters to the focus curves (sum of squares over regions and frames), but
states the corrected focus's standard error (`focusfit.corrected_sd`) as that of a least-squares fit to the per-frame
estimates, weighted 1 / (bootstrap spread^2 + systematic^2). Where the two differ, the stated standard error is
not that of the estimate given: a frame that shows little in focus (the nearest, in a far scene) weighs little in
the curves' sum of squares, so a curve's end knot there is extrapolated from the other frames. This refits the
row's chosen family (offset, scale, monotone: linear in their parameters, `focusfit.family_design`) to the row's
per-frame estimates with exactly those weights, i.e. the estimator whose standard error the fit reports, and
compares both with the truth, frame by frame (`|error| / standard error`: the reported one, unchanged).

    python -m benchmarks.probes.focus_family_on_estimates results/diagnose_focus_tune2029_v2.jsonl \\
        [RESULTS.jsonl ...] [--out results/focus_family_on_estimates.md]

`--choice` (2026-11-27, `focusfit.FAMILIES_ON_ESTIMATES`): every family refitted to the estimates and the whole
choice redone (`bench_diagnose_focus.rescored` with and without `on_estimates`: error scale, evidence, standard
errors, undetermined and left-out frames), the benchmark's summary for both, variants of the standard error
(`sd_variants`), a JSON summary, and every set whose family, corrected focus or claim changed; the files together (a
set in several counts once, its last row):

    python -m benchmarks.probes.focus_family_on_estimates --choice RESULTS.jsonl ... \\
        --out results/focus_families_on_estimates_choice.md     # and its .json
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

from benchmarks import RESULTS

LINEAR = ("offset", "scale", "monotone")


def refit(row: dict) -> np.ndarray | None:
    """(S,) the row's chosen family fitted to its per-frame estimates by weighted least squares (diopters,
    `focusfit.fit_on_estimates`, weights 1 / (spread^2 + systematic^2)); None for families that are not linear in
    their parameters or rows without the stored fits."""
    from aat_deploy.diagnose import focusfit as ff

    fams = {f["family"]: f for f in row.get("families") or []}
    if row["family"] not in LINEAR or "per_frame" not in fams or not row.get("frame_systematic_d"):
        return None
    fits = {k: ff.FamilyFit(k, int(fams[k].get("k", 0)), {}, np.asarray(fams[k]["true_d"], np.float64), 0.0)
            for k in ("none", "per_frame")}
    sd = np.asarray(row["frame_focus_sd_d"], np.float64)
    exc = np.asarray(row.get("frames_noise_dominated") or np.zeros(sd.shape[-1], bool), bool)[None]
    if row.get("frames_left_out_on_bound"):  # left out because its estimate sat on its search bound
        exc = exc | np.asarray(row["frames_left_out_on_bound"], bool)[None]
    out = ff.fit_on_estimates(fits, fits["none"].true_d, np.where(np.isfinite(sd), sd, 0.0), (~exc).astype(float),
                              np.asarray(row["frame_systematic_d"], np.float64))
    return out[row["family"]].true_d[0] if row["family"] in out else None


def choice(rows: list[dict]) -> dict:
    """The benchmark's summary with the row's own fits and with every family refitted to the estimates (the whole
    choice redone both ways, `bench_diagnose_focus.rescored`), and the sets that changed."""
    from benchmarks import bench_diagnose_focus as bench

    rows = list({(r["capture"], r["kind"]): r for r in rows}.values())
    both = [(bench.rescored(r, "curves"), bench.rescored(r, "estimates", on_estimates=True)) for r in rows]
    both = [(a, b) for a, b in both if a is not None]
    for i, name in enumerate(("fitted to the curves (the rows' own fits, rescored)", "fitted to the estimates")):
        print(f"\n#### {name}\n")
        bench.table([x[i] for x in both])

    summary = {"sets": len(both), "fitted_to": {}, "standard_error_variants": sd_variants([b for _, b in both])}
    for i, name in enumerate(("curves", "estimates")):
        rs = [x[i] for x in both]
        err = [r for r in rs if r["kind"] != "none"]
        summary["fitted_to"][name] = {
            "family_right": sum(r["family_ok"] for r in rs),
            "within_0.02_d": sum(r["corrected_max_err_d"] <= 0.02 and not r["frames_undetermined"] for r in err),
            "claimed_over_0.02_d": sum(r["corrected_max_err_d"] > 0.02 and not r["frames_undetermined"] for r in err),
            "sets_with_an_error": len(err), "largest_error_d": max(r["corrected_max_err_d"] for r in rs),
            "untouched_blaming_focus": sum(r["family"] != "none" for r in rs if r["kind"] == "none")}
    print("\n#### the corrected focus's standard error, variants (fitted to the estimates)\n")
    print("| standard error | within 0.02 D, every frame determined | claimed determined, over 0.02 D | undetermined, "
          "every frame within 0.02 D | frames whose 95 % interval holds the truth |\n|---|---|---|---|---|")
    for name, v in summary["standard_error_variants"].items():
        print(f"| {name} | {v['within']}/{v['sets_with_an_error']} | {v['claimed_wrong']} | {v['undetermined_within']} | "
              f"{v['covered']}/{v['frames']} |")
    print("\n```json\n" + json.dumps(summary, indent=1) + "\n```")

    def claim(r):
        return "undetermined" if r["frames_undetermined"] else "claimed"

    print("\n| set | curves: family, max error (D), claim | estimates: family, max error (D), claim |\n|---|---|---|")
    for a, b in sorted(both, key=lambda x: (x[0]["capture"], x[0]["kind"])):
        if (a["family"], claim(a)) != (b["family"], claim(b)) or abs(a["corrected_max_err_d"] - b["corrected_max_err_d"]) > 0.005:
            print(f"| {a['capture']} {a['kind']} | {a['family']}, {a['corrected_max_err_d']:.3f}, {claim(a)} | "
                  f"{b['family']}, {b['corrected_max_err_d']:.3f}, {claim(b)} |")
    return summary


def table(rows: list[dict]) -> None:
    rows = sorted({(r["capture"], r["kind"]): r for r in rows}.values(), key=lambda r: (r["capture"], r["kind"]))
    print("| set | family | corrected max error (D): as fitted (curves) | on the estimates | frame of the largest, "
          "as fitted / on the estimates / its own estimate | its standard error (D) | largest error / SE: as "
          "fitted, on the estimates |")
    print("|---|---|---|---|---|---|---|")
    old_all, new_all, z_old, z_new = [], [], [], []
    for r in rows:
        d = refit(r)
        if d is None:
            continue
        est = np.asarray([f for f in r["families"] if f["family"] == "per_frame"][0]["true_d"], np.float64)[0]
        truth = est - np.asarray(r["frame_err_d"], np.float64)
        old = np.asarray(r["corrected_err_d"], np.float64)
        new = d - truth
        sd = np.asarray(r["corrected_sd_d"], np.float64)[0]
        i = int(np.argmax(np.maximum(np.abs(old), np.abs(new))))
        old_all.append(np.abs(old).max())
        new_all.append(np.abs(new).max())
        z_old.append(np.abs(old) / sd)
        z_new.append(np.abs(new) / sd)
        print(f"| {r['capture']} {r['kind']} | {r['family']} | {np.abs(old).max():.3f} | {np.abs(new).max():.3f} | "
              f"{i}: {old[i]:+.3f} / {new[i]:+.3f} / {est[i] - truth[i]:+.3f} | {sd[i]:.4f} | "
              f"{np.max(z_old[-1]):.2f}, {np.max(z_new[-1]):.2f} |")
    if old_all:
        zo, zn = np.concatenate(z_old), np.concatenate(z_new)
        print(f"\n{len(old_all)} sets: corrected focus within 0.02 D in every frame {sum(e <= 0.02 for e in old_all)} "
              f"as fitted, {sum(e <= 0.02 for e in new_all)} on the estimates; largest error per set, mean "
              f"{np.mean(old_all):.4f} vs {np.mean(new_all):.4f} D; frames within 1.96 standard errors "
              f"{int(np.sum(zo <= 1.959964))}/{len(zo)} vs {int(np.sum(zn <= 1.959964))}/{len(zn)}")


def sd_variants(rows: list[dict]) -> dict:
    """Rescored rows (`bench_diagnose_focus.rescored`): sets within 0.02 D with every frame determined, sets claimed
    determined but over 0.02 D, sets undetermined though every frame is within 0.02 D, and frames whose 95 % interval
    holds the truth, with the rows' standard errors; times their error scale (`focusfit.error_scale`); and with the
    choice's own uncertainty added, sum_k p_k (f_k - f_chosen)^2, p_k proportional to exp(-score_k / 2) over the
    families but `per_frame` (Bayesian model averaging's spread about the chosen family's focus), at every frame or at
    the left-out frames only."""
    from aat_deploy.diagnose import focusfit as ff

    out = {}
    for name in ("as fitted", "times the error scale", "model averaging, every frame",
                 "model averaging, left-out frames"):
        v = {"within": 0, "claimed_wrong": 0, "undetermined_within": 0, "covered": 0, "frames": 0, "sets_with_an_error": 0}
        for r in rows:
            sd = np.asarray(r["corrected_sd_d"], np.float64)[0]
            err = np.abs(np.asarray(r["corrected_err_d"], np.float64))
            fams = {x["family"]: x for x in r["families"] if x["family"] != "per_frame"}
            if name == "times the error scale":
                sd = sd * r["error_scale"]
            elif name.startswith("model averaging"):
                best = np.asarray(fams[r["family"]]["true_d"], np.float64)[0]
                low = min(x["score"] for x in fams.values())
                p = {k: np.exp(-(x["score"] - low) / 2) for k, x in fams.items()}
                add = sum(p[k] * (np.asarray(fams[k]["true_d"], np.float64)[0] - best) ** 2 for k in p) / sum(p.values())
                if name.endswith("left-out frames"):
                    add = add * np.asarray(r.get("frames_noise_dominated") or np.zeros(len(sd), bool), bool)
                sd = np.sqrt(sd ** 2 + add)
            und = bool(np.any(sd >= ff.UNDETERMINED_SD_D))
            v["covered"] += int(np.sum(err <= 1.959964 * sd + 1e-4))  # the rows' errors are rounded to 1e-4 D
            v["frames"] += len(err)
            if r["kind"] == "none":
                continue
            v["sets_with_an_error"] += 1
            v["within"] += int(not und and err.max() <= 0.02)
            v["claimed_wrong"] += int(not und and err.max() > 0.02)
            v["undetermined_within"] += int(und and err.max() <= 0.02)
        out[name] = v
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="bench_diagnose_focus results files; each gets its own table")
    ap.add_argument("--choice", action="store_true", help="the whole choice redone with the families refitted to the "
                    "estimates, all files together")
    ap.add_argument("--out", type=Path, default=None,
                    help="the tables (.md; with --choice also its .json beside it); never an existing file")
    a = ap.parse_args(argv)
    out = a.out or RESULTS / ("focus_families_on_estimates_choice.md" if a.choice else "focus_family_on_estimates.md")
    # one line before any work: the defaults are committed results, which a rerun must not replace
    for f in a.results:
        if not f.is_file():
            ap.error(f"{f}: no such results file")
    if out.suffix == ".json" and a.choice:
        ap.error(f"--out {out}: the tables' file, not .json (the summary goes beside it as .json)")
    for f in (out, out.with_suffix(".json")) if a.choice else (out,):
        if f.exists():
            ap.error(f"{f}: exists (choose another --out)")
    from aat_deploy.io.atomic import write_text_atomic

    buf = io.StringIO()
    with redirect_stdout(buf):
        if a.choice:
            summary = choice([json.loads(x) for f in a.results for x in f.read_text().splitlines() if x.strip()])
            write_text_atomic(out.with_suffix(".json"),
                              json.dumps({"files": [str(f) for f in a.results], **summary}, indent=1) + "\n")
        for f in [] if a.choice else a.results:
            print(f"\n### {f}\n")
            table([json.loads(x) for x in f.read_text().splitlines() if x.strip()])
    print(buf.getvalue())
    flag = "--choice " if a.choice else ""
    write_text_atomic(out, f"# `python -m benchmarks.probes.focus_family_on_estimates {flag}"
                           f"{' '.join(str(f) for f in a.results)}`\n" + buf.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
