"""When the families tie on the fitted frames, should the corrected focus say so? (issue 32, after the tenth round; the
brief's option (a): scene 3076's scale 1.05, frames 0-3 left out for noise, read `offset` 0.055 D off and claimed.) On
stored `bench_diagnose_focus` rows (development rows only: nothing held out enters it), the whole choice redone as the
code makes it (`bench_diagnose_focus.rescored(on_estimates=True)`), then, per set, every family's posterior weight from
its evidence (p_f proportional to exp(-score_f / 2), `focusfit.score_families`) and either

- `mix:F,...`: the corrected focus kept (the chosen family's), its standard error the root mean square error of that
  value under the families F's posterior mixture: sqrt(sum_f p_f (sd_f^2 + (mu_f - mu_best)^2)), sd_f each family's
  own (`focusfit.corrected_sd`, `left_out_sd`: what the code would give were it chosen), never below the chosen
  family's; a frame is undetermined by the code's rule (`UNDETERMINED_SD_D`). Frames where families that tie on the
  fitted frames part (the left-out frames) become undetermined instead of claimed;
- `bma:F,...`: the corrected focus the posterior mean of the families F (when the chosen family is one of them), its
  standard error the chosen family's;

`mix:all` is every family. The benchmark's counts for each against the code, and every set whose outcome moved.

    python -m benchmarks.probes.focus_family_mixture RESULTS.jsonl ... --out results/focus_family_mixture.md
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

VARIANTS = ("mix:all", "mix:offset,scale,monotone", "mix:offset,scale", "bma:offset,scale",
            "bma:offset,scale,monotone")
Z95 = 1.959964


def posterior(fams: dict, members: list[str]) -> dict[str, float]:
    """{family: weight} over members, from the evidence scores (-2 log evidence), normalised."""
    m = min(fams[k]["score"] for k in members)
    w = {k: math.exp(-(fams[k]["score"] - m) / 2) for k in members}
    z = sum(w.values())
    return {k: v / z for k, v in w.items()}


def family_sd(row: dict, fams: dict, name: str) -> np.ndarray:
    """(n, S) the standard error the code gives a family's corrected focus were it chosen (`rescored`'s inputs)."""
    from aat_deploy.diagnose import focusfit as ff

    rep = np.asarray(fams["none"]["true_d"], np.float64)
    exc = np.asarray(row.get("frames_noise_dominated") or np.zeros(rep.shape[-1], bool), bool)[None]
    if row.get("frames_left_out_on_bound"):
        exc = exc | np.asarray(row["frames_left_out_on_bound"], bool)[None]
    sd = np.asarray(row["frame_focus_sd_d"], np.float64)
    sd = np.where(np.isfinite(sd), sd, 0.0)
    sys_d = np.asarray(row["frame_systematic_d"], np.float64)
    frames = (np.isfinite(rep) & ~exc).astype(np.float64)
    share = np.asarray(row["frame_noise_share"], np.float64).reshape(rep.shape) if row.get("frame_noise_share") else None
    aw = ff.signal_weight(share if ff.WEIGHT_BY_NOISE_SHARE else None, frames)
    f = ff.FamilyFit(name, int(fams[name]["k"]), {}, np.asarray(fams[name]["true_d"], np.float64), 0.0)
    quant = ff.quantiser(np.unique(np.round(rep[np.isfinite(rep)], 9)))
    if name == "quantisation" and quant is not None:
        f.detail = {"quantiser": quant[0], "step_d": quant[1]}
    tsd = ff.corrected_sd(f, rep, sd, frames, sys_d, at=(frames > 0) | exc, weight=aw)
    return ff.left_out_sd(f, rep, frames, exc, tsd)


def variant(row: dict, r: dict, how: str) -> dict:
    """The rescored row r of row under a variant (module docstring)."""
    from aat_deploy.diagnose import focusfit as ff

    kind, names = how.split(":")
    fams = {x["family"]: x for x in r["families"]}
    members = list(fams) if names == "all" else [k for k in names.split(",") if k in fams]
    best = r["family"]
    if best not in members:
        return r
    p = posterior(fams, members)
    mu_b = np.asarray(fams[best]["true_d"], np.float64)
    err = np.asarray(r["corrected_err_d"], np.float64)
    tsd = np.asarray(r["corrected_sd_d"], np.float64)
    if kind == "bma":
        mu = sum(p[k] * np.asarray(fams[k]["true_d"], np.float64) for k in members)
        err = err + (mu - mu_b)[0]
    else:
        var = sum(p[k] * (family_sd(row, fams, k) ** 2 + (np.asarray(fams[k]["true_d"], np.float64) - mu_b) ** 2)
                  for k in members)
        tsd = np.maximum(np.sqrt(var), tsd)
    und = tsd[0] >= ff.UNDETERMINED_SD_D
    return {**r, "corrected_err_d": err.round(4).tolist(), "corrected_max_err_d": float(np.abs(err).max()),
            "corrected_sd_d": np.round(tsd, 5).tolist(), "frames_undetermined": int(und.sum()),
            "undetermined_covers": [bool(abs(e) <= Z95 * s) for e, s, u in zip(err, tsd[0], und) if u]}


def outcome(r: dict) -> str:
    if r["kind"] == "none":
        return "untouched, " + ("blames focus" if r["family"] != "none" else "none")
    if r["frames_undetermined"]:
        return "undetermined"
    return "within 0.02 D" if r["corrected_max_err_d"] <= 0.02 else "claimed, over 0.02 D"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="bench_diagnose_focus results files (development rows)")
    ap.add_argument("--out", type=Path, required=True, help="the tables (.md; never an existing file)")
    a = ap.parse_args(argv)
    for f in a.results:  # one line before any work
        if not f.is_file():
            ap.error(f"{f}: no such results file")
    if a.out.suffix != ".md" or a.out.exists():
        ap.error(f"--out {a.out}: " + ("exists (choose another --out)" if a.out.exists() else "a .md file"))
    from aat_deploy.io.atomic import write_text_atomic
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes.focus_noise_weight import counts, last_row_per_set

    buf = io.StringIO()
    with redirect_stdout(buf):
        given = [json.loads(x) for f in a.results for x in f.read_text().splitlines() if x.strip()]
        rows = last_row_per_set(given)
        pairs = [(row, bench.rescored(row, "code", on_estimates=True)) for row in rows]
        pairs = [(row, r) for row, r in pairs if r is not None]
        base = [r for _, r in pairs]
        res = {v: [variant(row, r, v) for row, r in pairs] for v in VARIANTS}
        keys = list(counts(base))
        print("| variant | " + " | ".join(keys) + " |\n|---|" + "---|" * len(keys))
        for v, rs in [("code", base), *res.items()]:
            print(f"| {v} | " + " | ".join(str(counts(rs)[k]) for k in keys) + " |")
        print("\n| variant | set | code: family, largest error (D), outcome | variant: largest error (D), outcome |")
        print("|---|---|---|---|")
        for v, rs in res.items():
            for b, x in zip(base, rs):
                if outcome(b) != outcome(x):
                    print(f"| {v} | {b['capture']} {b['kind']} | {b['family']}, {b['corrected_max_err_d']:.4f}, "
                          f"{outcome(b)} | {x['corrected_max_err_d']:.4f}, {outcome(x)} |")
    write_text_atomic(a.out, f"# `python -m benchmarks.probes.focus_family_mixture "
                      f"{' '.join(str(f) for f in a.results)} --out {a.out}`\n\n" + buf.getvalue())
    print(buf.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
