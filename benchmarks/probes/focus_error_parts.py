"""Where the per-frame focus estimates' errors come from, scene by scene (issue 32: scenes 2036 and 2037's estimates
off by 0.05-0.11 D, far beyond their standard errors). Understanding only, from stored `bench_diagnose_focus` rows;
it changes nothing in the diagnosis.

Every set of one scene is a copy of the same images with other reported focus distances, so a frame's estimate
error splits into a part common to the scene's sets (what the twin gets wrong there: the same in every copy) and a
part that changes with the reported focus (where the fit started: nothing in the images). Per scene: the rms error,
its common part (the per-frame mean over the sets), its set-dependent part (the per-frame spread over the sets), the
error model's sigma (bootstrap spread and systematic error, median over the sets), the estimates' rms |error| /
sigma, the capture's error scale read from the estimates alone (`focusfit.error_scale`: the monotone curve's
residuals, median over the sets) and how far the `per_frame` family's search ended from the last per-frame
estimate of the robust preparation on the same sweep (`robust.frame_focus_d`, another start). Then, for every
set whose family was chosen wrong, the evidence's own probability of its choice (exp(-score / 2) over the families)
against the bootstrap's support. Last, whether choosing the family with the correlated errors the standard
errors assume (`focusfit.error_correlation`) would have chosen better.

    python -m benchmarks.probes.focus_error_parts results/diagnose_focus_tune2029_v2.jsonl \\
        results/diagnose_focus_fitonly36_v4.jsonl results/diagnose_focus_fresh_fitonly.jsonl \\
        results/diagnose_focus_fresh2_fitonly_consistency_off.jsonl [--out results/focus_error_parts.md]
"""

from __future__ import annotations

import argparse
import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np


def parts(rows: list[dict]) -> None:
    from aat_deploy.diagnose import focusfit as ff

    rows = list({(r["capture"], r["kind"]): r for r in rows}.values())
    print("| scene | sets | rms error (D) | common to its sets (D) | set-dependent (D) | largest common, frame | "
          "largest set-dependent, frame | sigma, median (D) | rms error / sigma | error scale, median | "
          "search end vs preparation's last estimate, largest (D) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for cap in sorted({r["capture"] for r in rows}):
        rs = [r for r in rows if r["capture"] == cap and r.get("frame_systematic_d")]
        if len(rs) < 2:
            continue
        err = np.array([r["frame_err_d"] for r in rs])  # (sets, S)
        sig = np.array([np.hypot(np.asarray(r["frame_focus_sd_d"])[0], np.asarray(r["frame_systematic_d"])[0])
                        for r in rs])
        common, spread = err.mean(0), err.std(0, ddof=1)
        scales, moved = [], []
        for r in rs:
            fams = {x["family"]: ff.FamilyFit(x["family"], int(x["k"]), {}, np.asarray(x["true_d"], np.float64), 0.0)
                    for x in r["families"]}
            sd = np.asarray(r["frame_focus_sd_d"], np.float64)
            scales.append(ff.error_scale(fams, sd, np.ones_like(sd), np.asarray(r["frame_systematic_d"])))
            last = np.asarray(r["robust"]["frame_focus_d"][-1], np.float64)
            moved.append(np.abs(fams["per_frame"].true_d - last).max())
        print(f"| {cap} | {len(rs)} | {np.sqrt(np.mean(err ** 2)):.4f} | {np.sqrt(np.mean(common ** 2)):.4f} | "
              f"{np.sqrt(np.mean(spread ** 2)):.4f} | {common[np.argmax(np.abs(common))]:+.3f}, "
              f"{int(np.argmax(np.abs(common)))} | {spread.max():.3f}, {int(np.argmax(spread))} | "
              f"{np.median(sig):.4f} | {np.sqrt(np.mean((err / sig) ** 2)):.2f} | {np.median(scales):.2f} | "
              f"{max(moved):.3f} |")
    wrong = [r for r in rows if not r["family_ok"]]
    print("\nsets whose family was chosen wrong: the evidence's probability of each family (exp(-score / 2), "
          "normalised) against the bootstrap's support")
    for r in wrong:
        sc = {x["family"]: x["score"] for x in r["families"]}
        lo = min(sc.values())
        p = {k: np.exp(-(v - lo) / 2) for k, v in sc.items()}
        tot = sum(p.values())
        print(f"- {r['capture']} {r['kind']} (truth `{r['family_true']}`, chosen `{r['family']}`): evidence "
              + ", ".join(f"{k} {v / tot:.2f}" for k, v in p.items() if v / tot >= 0.005)
              + "; support " + ", ".join(f"{k} {v:.2f}" for k, v in (r.get("support") or {}).items() if v >= 0.005)
              + "; per-frame errors " + " ".join(f"{x:+.3f}" for x in r["frame_err_d"]))


def correlated_choice(rows: list[dict]) -> None:
    """The family each set's stored fits choose (`score_families`, the model's errors, as the rows were run) and
    what they would choose with the correlated errors of `corrected_sd` in the evidence: chi2 = r^T C^-1 r and
    log det(J^T C^-1 J), C = sigma_i sigma_j exp(-|d_i - d_j| / ERROR_CORRELATION_D)."""
    import math

    from aat_deploy.diagnose import focusfit as ff

    rows = [r for r in {(r["capture"], r["kind"]): r for r in rows}.values() if r.get("frame_systematic_d")]
    wrong: dict = {"as run": [], "correlated": []}
    for r in rows:
        fits = {x["family"]: ff.FamilyFit(x["family"], int(x["k"]), {}, np.asarray(x["true_d"], np.float64), 0.0)
                for x in r["families"]}
        sd, sys_d = np.asarray(r["frame_focus_sd_d"], np.float64), np.asarray(r["frame_systematic_d"], np.float64)
        one = np.ones_like(sd)
        ff.score_families(fits, sd, one, sys_d)
        if ff.select(fits).name != r["family_true"]:
            wrong["as run"].append(f"{r['capture']} {r['kind']}: {ff.select(fits).name}")
        e, rep = fits["per_frame"].true_d, fits["none"].true_d
        sig = np.hypot(sd, sys_d)[0]
        cinv = np.linalg.inv(ff.error_correlation(rep, one)[0] * sig[:, None] * sig[None, :])
        for f in fits.values():
            res = (f.true_d - e)[0]
            jac, widths = ff.family_design(f.name, rep, f.true_d, one)
            k = jac.shape[-1]
            logdet = float(np.linalg.slogdet(jac[0].T @ cinv @ jac[0])[1]) if k else 0.0
            f.score = float(res @ cinv @ res) + logdet - k * math.log(2 * math.pi) + 2 * sum(map(math.log, widths))
        if ff.select(fits).name != r["family_true"]:
            wrong["correlated"].append(f"{r['capture']} {r['kind']}: {ff.select(fits).name}")
    print(f"\nthe family chosen from the stored fits, {len(rows)} sets:")
    for k, v in wrong.items():
        print(f"- {k} errors: {len(rows) - len(v)}/{len(rows)} right; wrong: {', '.join(v) or 'none'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+")
    ap.add_argument("--out", help="also write the output here (markdown)")
    a = ap.parse_args()
    rows = [json.loads(x) for f in a.results for x in Path(f).read_text().splitlines() if x.strip()]
    buf = io.StringIO()
    with redirect_stdout(buf):
        parts(rows)
        correlated_choice(rows)
    print(buf.getvalue(), end="")
    if a.out:
        if Path(a.out).resolve() in {Path(f).resolve() for f in a.results}:  # never write over an input
            raise SystemExit(f"{a.out}: is one of the results read; choose another --out")
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(Path(a.out), f"# Where the per-frame focus estimates' errors come from\n\n"
                          f"`python -m benchmarks.probes.focus_error_parts {' '.join(a.results)}`\n\n"
                          + buf.getvalue())


if __name__ == "__main__":
    main()
