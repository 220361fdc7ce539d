"""How alike neighbouring frames' focus errors are (issue 32): the correlation length `focusfit.ERROR_CORRELATION_D`
of the per-frame focus estimates' errors, estimated on the **tuning capture's** sets only (scene 2029 of
`bench_diagnose_focus`; scenes 2027 and 2028 and the shipped sample are test material and never enter it).

Per set (a row of `bench_diagnose_focus --fit-only`), every frame's error against the truth (`frame_err_d`: the
`per_frame` estimate less the true focus) in units of its standard error sigma (the bootstrap spread
`frame_focus_sd_d` and the systematic error `frame_systematic_d`, as `focusfit.corrected_sd` weighs them). The
model (`focusfit.error_correlation`): the standardised errors of one set are Gaussian with covariance c^2 R, R_ij =
exp(-|d_i - d_j| / L), d the frames' true focus (diopters); c (how far the sigmas are off overall) is profiled
out, L is found by maximum likelihood over a grid, the sets pooled. Printed: the profile, its maximum and the
95 % profile-likelihood interval (a drop of 1.92), the empirical correlation at each lag against the model's, and
what the corrected focus's standard error becomes on the same sets (the chosen family's error in units of its
standard error, independent and correlated).

The sets of one capture are copies of the same images with different focus metadata: far from independent
draws. The interval treats them as independent and so understates how uncertain L is.

    python -m benchmarks.focus_error_correlation results/diagnose_focus_tune2029_v2.jsonl \
        [--capture scene2029] [--out results/focus_error_correlation.md]
    python -m benchmarks.focus_error_correlation --sensitivity RESULTS.jsonl   # flags against the length

`--sensitivity` reads any sets (the benchmark's too) and chooses nothing: what the flags would be at other
lengths, to say whether any correlation of this form could change a verdict.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

TUNING_CAPTURE = "scene2029"
LENGTH_GRID_D = np.round(np.arange(0.0, 1.0 + 1e-9, 0.005), 4)  # candidate correlation lengths (diopters)
PROFILE_DROP = 1.92  # half the chi-square(1) 95 % quantile: the profile-likelihood interval


def standardised(row: dict) -> tuple[np.ndarray, np.ndarray]:
    """One set's per-frame errors in units of their sigma (S,) and the frames' true focus (S,) diopters (first
    capture of the row)."""
    err = np.asarray(row["frame_err_d"], np.float64)
    sd = np.asarray(row["frame_focus_sd_d"], np.float64)[0]
    sys_d = np.asarray(row["frame_systematic_d"], np.float64)[0]
    per = next(f for f in row["families"] if f["family"] == "per_frame")
    true_d = np.asarray(per["true_d"], np.float64)[0] - err
    return err / np.sqrt(sd ** 2 + sys_d ** 2), true_d


def usable(rows: list[dict], capture: str) -> list[dict]:
    """The rows of this capture (the last row of each set) with what `standardised` needs."""
    keys = ("frame_err_d", "frame_focus_sd_d", "frame_systematic_d", "families")
    last = {(r["capture"], r["kind"]): r for r in rows if r.get("capture") == capture}
    return [r for r in last.values() if all(r.get(k) for k in keys)]


def neg_profile_loglik(z: list[np.ndarray], d: list[np.ndarray], length_d: float) -> float:
    """-log likelihood of the standardised errors z (per set) under c^2 R(length_d), c profiled out (constant
    terms dropped)."""
    from aat_deploy.diagnose import focusfit as ff

    quad, logdet, n = 0.0, 0.0, 0
    for zs, ds in zip(z, d):
        r = ff.error_correlation(ds[None], np.ones((1, len(ds))), length_d)[0]
        logdet += float(np.linalg.slogdet(r)[1])
        quad += float(zs @ np.linalg.solve(r, zs))
        n += len(zs)
    return 0.5 * (n * np.log(quad / n) + logdet)


def estimate(rows: list[dict], capture: str = TUNING_CAPTURE, grid=LENGTH_GRID_D) -> dict:
    """The maximum-likelihood correlation length (diopters) on this capture's rows, its 95 % profile interval,
    the profile and the empirical correlation per lag (frames in focus order)."""
    use = usable(rows, capture)
    if not use:
        raise SystemExit(f"no rows of {capture} with frame_err_d, frame_focus_sd_d, frame_systematic_d and families")
    z, d = zip(*(standardised(r) for r in use))
    prof = np.array([neg_profile_loglik(z, d, float(g)) for g in grid])
    best = int(np.argmin(prof))
    inside = grid[prof <= prof[best] + PROFILE_DROP]
    zz = np.array([x for x in z if len(x) == len(z[0])])
    spacing = float(np.median(np.abs(np.diff(d[0]))))
    lags = []
    for k in range(1, zz.shape[1] - 1):
        a, b = zz[:, :-k], zz[:, k:]
        lags.append((k, float(np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b)))))
    return {"capture": capture, "sets": len(use), "kinds": [r["kind"] for r in use], "length_d": float(grid[best]),
            "interval_d": [float(inside.min()), float(inside.max())], "grid_d": grid.tolist(),
            "profile": prof.tolist(), "spacing_d": spacing, "lags": lags,
            "scale": float(np.sqrt(np.mean(np.concatenate(z) ** 2)))}


def calibration(rows: list[dict], capture: str, length_d: float) -> list[tuple]:
    """Per set: the chosen family's largest |corrected error| / standard error over the frames, independent
    (length 0) and correlated (length_d), from the row's stored fits (`row_sd`)."""
    out = []
    for r in usable(rows, capture):
        one = [row_sd(r, length) for length in (0.0, length_d)]
        if one[0] is None:
            continue
        err = np.abs(np.asarray(r["corrected_err_d"], np.float64))
        out.append((r["kind"], r["family"], float(err.max()), float(np.max(err / one[0])), float(np.max(one[0])),
                    float(np.max(err / one[1])), float(np.max(one[1]))))
    return out


def row_sd(row: dict, length_d: float) -> np.ndarray | None:
    """(S,) the standard error of a row's chosen family's corrected focus (`focusfit.corrected_sd` on the row's
    stored fits) at this correlation length; None for `none` or rows without the fits."""
    from aat_deploy.diagnose import focusfit as ff

    fams = {f["family"]: f for f in row.get("families") or []}
    if row.get("family") in (None, "none") or row["family"] not in fams or "none" not in fams \
            or not row.get("frame_focus_sd_d") or not row.get("frame_systematic_d"):
        return None
    fit = ff.FamilyFit(row["family"], int(fams[row["family"]]["k"]), {},
                       np.asarray(fams[row["family"]]["true_d"], np.float64), 0.0)
    sd, sys_d = np.asarray(row["frame_focus_sd_d"], np.float64), np.asarray(row["frame_systematic_d"], np.float64)
    rep = np.asarray(fams["none"]["true_d"], np.float64)
    return ff.corrected_sd(fit, rep, sd, np.ones_like(sd), sys_d, length_d)[0]


def sensitivity(rows: list[dict], lengths=(0.0, None, 0.5, 1.0, 10.0)) -> str:
    """How the undetermined flags of any rows (evaluation sets: this reads them, it chooses nothing) would move with
    the correlation length (None: the code's ERROR_CORRELATION_D): per length, the frames reported undetermined,
    and for every set some frame of which is more than 0.02 D off, its worst frame's standard error."""
    from aat_deploy.diagnose import focusfit as ff

    lengths = [ff.ERROR_CORRELATION_D if x is None else x for x in lengths]
    last = {(r["capture"], r["kind"]): r for r in rows}
    sds = {k: [row_sd(r, x) for x in lengths] for k, r in last.items()}
    sds = {k: v for k, v in sds.items() if v[0] is not None}
    lines = ["| correlation length (D) | " + " | ".join(f"{x:g}" for x in lengths) + " |",
             "|---|" + "---|" * len(lengths),
             "| frames undetermined (SE >= 0.02 D) | " + " | ".join(
                 str(sum(int(np.sum(v[j] >= ff.UNDETERMINED_SD_D)) for v in sds.values())) for j in range(len(lengths)))
             + " |"]
    for k, v in sorted(sds.items()):
        err = np.abs(np.asarray(last[k]["corrected_err_d"], np.float64))
        if err.max() > 0.02:
            i = int(np.argmax(err))
            lines.append(f"| {k[0]} {k[1]}: frame {i}, {err[i]:.3f} D off, its SE (D) | "
                         + " | ".join(f"{x[i]:.4f}" for x in v) + " |")
    return "\n".join(lines) + "\n"


def report(rows: list[dict], capture: str = TUNING_CAPTURE) -> str:
    from aat_deploy.diagnose import focusfit as ff

    e = estimate(rows, capture)
    others = sorted({r.get("capture") for r in rows} - {capture})
    rho = np.exp(-e["spacing_d"] / e["length_d"]) if e["length_d"] > 0 else 0.0
    lo, hi = e["interval_d"]
    lines = [f"# Correlation of the per-frame focus errors ({capture}, the tuning capture)", "",
             f"{e['sets']} sets ({', '.join(e['kinds'])})" + (f"; rows of {', '.join(others)} ignored" if others
                                                             else ""), "",
             f"maximum-likelihood correlation length: **{e['length_d']:.3f} D** (95 % profile interval "
             f"{lo:.3f}-{hi:.3f} D, the sets counted as independent, which they are not: the same images); "
             f"correlation at one frame spacing ({e['spacing_d']:.3f} D): {rho:.2f} "
             f"({np.exp(-e['spacing_d'] / lo) if lo > 0 else 0:.2f}-{np.exp(-e['spacing_d'] / hi):.2f}); "
             f"the errors' rms in units of their sigma: {e['scale']:.2f}", "",
             f"focusfit.ERROR_CORRELATION_D in the code: {ff.ERROR_CORRELATION_D}", "",
             "| lag (frames) | empirical correlation | model exp(-lag spacing / L) |", "|---|---|---|"]
    lines += [f"| {k} | {c:.2f} | {np.exp(-k * e['spacing_d'] / e['length_d']) if e['length_d'] > 0 else 0:.2f} |"
              for k, c in e["lags"]]
    lines += ["", "profile (-log likelihood less its minimum) at a few lengths:", "",
              "| L (D) | " + " | ".join(f"{g:g}" for g in (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5)) + " |",
              "|---|" + "---|" * 7,
              "| | " + " | ".join(f"{e['profile'][int(round(g / 0.005))] - min(e['profile']):.2f}"
                                 for g in (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5)) + " |", "",
              f"The chosen family's corrected focus on these sets: largest |error| / standard error over the frames, "
              f"independent errors and correlated (L = {e['length_d']:.3f} D):", "",
              "| set | family | max error (D) | independent: max z | max SE (D) | correlated: max z | max SE (D) |",
              "|---|---|---|---|---|---|---|"]
    lines += [f"| {k} | {f} | {m:.4f} | {z0:.2f} | {s0:.4f} | {z1:.2f} | {s1:.4f} |"
              for k, f, m, z0, s0, z1, s1 in calibration(rows, capture, e["length_d"])]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", help="bench_diagnose_focus results files (rows with the stored fits)")
    ap.add_argument("--capture", default=TUNING_CAPTURE, help="the tuning capture (never a benchmark capture)")
    ap.add_argument("--out", help="also write the report here (markdown)")
    ap.add_argument("--sensitivity", action="store_true", help="instead: how the undetermined flags of these rows "
                    "(any sets, e.g. the benchmark's) would move with the correlation length; chooses nothing")
    a = ap.parse_args()
    rows = [json.loads(x) for f in a.results for x in Path(f).read_text().splitlines() if x.strip()]
    text = sensitivity(rows) if a.sensitivity else report(rows, a.capture)
    print(text, end="")
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(Path(a.out), text)


if __name__ == "__main__":
    main()
