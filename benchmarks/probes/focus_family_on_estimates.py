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
"""

from __future__ import annotations

import argparse
import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

from benchmarks import RESULTS

LINEAR = ("offset", "scale", "monotone")


def refit(row: dict) -> np.ndarray | None:
    """(S,) the row's chosen family fitted to its per-frame estimates by weighted least squares (diopters); None
    for families that are not linear in their parameters or rows without the stored fits."""
    from aat_deploy.diagnose import focusfit as ff

    fams = {f["family"]: f for f in row.get("families") or []}
    if row["family"] not in LINEAR or "per_frame" not in fams or not row.get("frame_systematic_d"):
        return None
    rep = np.asarray(fams["none"]["true_d"], np.float64)
    est = np.asarray(fams["per_frame"]["true_d"], np.float64)
    frames = np.ones_like(rep)
    jac, _ = ff.family_design(row["family"], rep, np.asarray(fams[row["family"]]["true_d"], np.float64), frames)
    # offset: d = rep - b (J = -1 about rep); scale: d = rep * s (J = d at the fit; linear in s through rep);
    # monotone: d = basis . knots (J = basis)
    base = rep if row["family"] == "offset" else np.zeros_like(rep)
    if row["family"] == "scale":
        jac = rep[..., None]
    sigma2 = np.asarray(row["frame_focus_sd_d"], np.float64) ** 2 + np.asarray(row["frame_systematic_d"]) ** 2
    a = jac[0] / sigma2[0][:, None]
    p = np.linalg.solve(jac[0].T @ a, a.T @ (est - base)[0])
    return base[0] + jac[0] @ p


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", help="bench_diagnose_focus results files; each gets its own table")
    ap.add_argument("--out", default=str(RESULTS / "focus_family_on_estimates.md"))
    a = ap.parse_args()
    buf = io.StringIO()
    with redirect_stdout(buf):
        for f in a.results:
            print(f"\n### {f}\n")
            table([json.loads(x) for x in Path(f).read_text().splitlines() if x.strip()])
    print(buf.getvalue())
    Path(a.out).write_text(f"# `python -m benchmarks.probes.focus_family_on_estimates {' '.join(a.results)}`\n"
                           + buf.getvalue())


if __name__ == "__main__":
    main()
