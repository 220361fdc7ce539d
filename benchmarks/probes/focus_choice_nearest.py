"""Does the family choice give the nearest fitted frame too much say? (issue 32, after the ninth round.) On stored
`bench_diagnose_focus` rows (development rows only: nothing held out enters it):

1. every fitted frame's error against its modelled error (bootstrap spread and systematic error in quadrature), by
   distance rank among the fitted frames (0: the nearest): rms error, median modelled error, median noise share, rms
   standardised error;
2. the whole choice redone from the rows' stored fits (`bench_diagnose_focus.rescored(on_estimates=True)`, the code as
   it is) with the choice's error model (`focusfit.error_scale`, `score_families`; not the standard errors) changed:
   `nearF` the nearest fitted frame's total variance times F squared (`focusfit.CHOICE_NEAREST_FACTOR` = F: near1 is
   the choice before it, the code's own factor is the `code` row), `weights` every frame's total variance divided by
   its noise-share weight (`focusfit.signal_weight`, rows with noise shares only; with the factor 1); the benchmark's
   counts for each, and every set whose family, largest error or undetermined count moved against `code`.

    python -m benchmarks.probes.focus_choice_nearest RESULTS.jsonl ... [--near 1,1.5,2,3]
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np


def by_rank(rows: list[dict]) -> list[dict]:
    """Per distance rank among each row's fitted frames (nearest first): frames, rms error (D), median modelled error
    (D), median noise share, rms standardised error."""
    acc: dict = {}
    for r in rows:
        err = np.asarray(r["frame_err_d"], np.float64)
        sd = np.asarray([np.nan if x is None else x for x in r["frame_focus_sd_d"][0]], np.float64)
        sig = np.hypot(sd, np.asarray(r["frame_systematic_d"], np.float64)[0])
        exc = np.asarray(r.get("frames_noise_dominated") or np.zeros(len(err), bool), bool)
        rep = np.asarray({x["family"]: x for x in r["families"]}["none"]["true_d"], np.float64)[0]
        share = np.asarray(r["frame_noise_share"], np.float64) if r.get("frame_noise_share") else np.full(len(err), np.nan)
        idx = np.where(~exc & np.isfinite(err) & np.isfinite(sig))[0]
        for k, i in enumerate(idx[np.argsort(-rep[idx])]):
            acc.setdefault(k, []).append((err[i], sig[i], share[i]))
    out = []
    for k in sorted(acc):
        a = np.array(acc[k], np.float64)
        out.append({"rank": k, "frames": len(a), "rms_err_d": round(float(np.sqrt(np.mean(a[:, 0] ** 2))), 4),
                    "median_model_d": round(float(np.median(a[:, 1])), 4),
                    "median_share": round(float(np.nanmedian(a[:, 2])), 3) if np.isfinite(a[:, 2]).any() else None,
                    "rms_z": round(float(np.sqrt(np.mean((a[:, 0] / a[:, 1]) ** 2))), 2)})
    return out


def variants(rows: list[dict], near: list[float]) -> dict:
    """{variant: rescored rows} with the choice's error model changed (module docstring); '' is the code as it is."""
    from aat_deploy.diagnose import focusfit as ff
    from benchmarks import bench_diagnose_focus as bench

    orig = ff.error_scale, ff.score_families, ff.signal_weight, ff.CHOICE_NEAREST_FACTOR
    state: dict = {}

    def inflate(frame_sd, sys_d, frames):  # `weights`: every frame's total variance over its noise-share weight
        sd2 = np.asarray(frame_sd, np.float64) ** 2
        tot = sd2 + np.asarray(sys_d, np.float64) ** 2
        aw = state.get("aw")
        if aw is None or aw.shape != tot.shape:
            return sys_d
        return np.sqrt(tot / np.clip(aw, 1e-3, 1.0) - sd2)

    def es(fits, frame_sd, frames, systematic_d=ff.SYSTEMATIC_D):
        return orig[0](fits, frame_sd, frames, inflate(frame_sd, systematic_d, frames) if state["v"] == "weights"
                       else systematic_d)

    def sf(fits, frame_sd, frames, systematic_d=ff.SYSTEMATIC_D):
        return orig[1](fits, frame_sd, frames, inflate(frame_sd, systematic_d, frames) if state["v"] == "weights"
                       else systematic_d)

    def sw(share, frames):
        w = orig[2](share, frames)
        state["aw"] = w if share is not None else None
        return w

    out = {}
    try:
        ff.error_scale, ff.score_families, ff.signal_weight = es, sf, sw
        for v in ["", "weights"] + [f"near{f:g}" for f in near]:
            state["v"] = v
            ff.CHOICE_NEAREST_FACTOR = (float(v[4:]) if v.startswith("near") else 1.0 if v == "weights"
                                        else orig[3])
            res = []
            for r in rows:
                state["aw"] = None
                x = bench.rescored(r, v or "code", on_estimates=True)
                if x is not None:
                    res.append(x)
            out[v] = res
    finally:
        ff.error_scale, ff.score_families, ff.signal_weight, ff.CHOICE_NEAREST_FACTOR = orig
    return out


def scenes_moved(base: list[dict], var: list[dict]) -> dict:
    """Paired against base (the same sets): per scene, the sets whose outcome is better in var (family right gained,
    or within 0.02 D with every frame determined gained, or a claimed-wrong set (over 0.02 D, every frame determined)
    no longer claimed, with none of these lost) or worse (the reverse), and a sign test over the scenes whose sets
    moved one way only (the sets of a scene are copies of the same images: the scene is the unit)."""
    from benchmarks.probes.focus_noise_weight import sign_test

    def marks(r):
        det = not r["frames_undetermined"]
        return (r["family_ok"], r["kind"] != "none" and det and r["corrected_max_err_d"] <= 0.02,
                not (r["kind"] != "none" and det and r["corrected_max_err_d"] > 0.02))

    b = {(r["capture"], r["kind"]): r for r in base}
    per: dict = {}
    for r in var:
        x, y = marks(b[(r["capture"], r["kind"])]), marks(r)
        up, down = any(v > u for u, v in zip(x, y)), any(v < u for u, v in zip(x, y))
        if up or down:
            per.setdefault(r["capture"], []).append(f"{r['kind']} {'better' if up and not down else 'worse' if down and not up else 'mixed'}")
    better = sum(all(s.endswith("better") for s in v) for v in per.values())
    worse = sum(all(s.endswith("worse") for s in v) for v in per.values())
    return {"scenes": per, "scenes_better": better, "scenes_worse": worse,
            "sign_test_p": round(sign_test(better, better + worse), 4) if better + worse else None}


def moved_table(res: dict[str, list[dict]]) -> None:
    """Print every set whose family, largest error (by more than 0.0005 D) or undetermined count moved in a variant
    against the code (res[""])."""
    base = {(r["capture"], r["kind"]): r for r in res[""]}
    print("\n| variant | set | true family | code: family, largest error, undetermined | variant |\n|---|---|---|---|---|")
    for v, rs in res.items():
        for x in rs if v else []:
            b = base[(x["capture"], x["kind"])]
            if (b["family"], b["frames_undetermined"]) != (x["family"], x["frames_undetermined"]) or \
                    abs(b["corrected_max_err_d"] - x["corrected_max_err_d"]) > 5e-4:
                print(f"| {v} | {x['capture']} {x['kind']} | {x['family_true']} | {b['family']}, "
                      f"{b['corrected_max_err_d']:.4f}, {b['frames_undetermined']} | {x['family']}, "
                      f"{x['corrected_max_err_d']:.4f}, {x['frames_undetermined']} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="bench_diagnose_focus results files (development rows)")
    ap.add_argument("--near", default="1,1.5,2,3", help="factors on the nearest fitted frame's error "
                    "(`focusfit.CHOICE_NEAREST_FACTOR`, comma-separated; 1: the choice before it)")
    ap.add_argument("--out", type=Path, help="also write the tables there (.md; never an existing file)")
    a = ap.parse_args(argv)
    for f in a.results:  # one line before any work
        if not f.is_file():
            ap.error(f"{f}: no such results file")
    if a.out is not None and (a.out.suffix != ".md" or a.out.exists()):
        ap.error(f"--out {a.out}: " + ("exists (choose another --out)" if a.out.exists() else "a .md file"))
    from benchmarks.probes.focus_noise_weight import counts, last_row_per_set

    buf = io.StringIO()
    with redirect_stdout(buf):
        given = [json.loads(x) for f in a.results for x in f.read_text().splitlines() if x.strip()]
        rows = last_row_per_set(given)
        print("| rank (0 nearest fitted) | frames | rms error (D) | median modelled error (D) | median noise share | rms z |")
        print("|---|---|---|---|---|---|")
        for b in by_rank(rows):
            print(f"| {b['rank']} | {b['frames']} | {b['rms_err_d']} | {b['median_model_d']} | {b['median_share']} | "
                  f"{b['rms_z']} |")
        res = variants(rows, [float(x) for x in a.near.split(",") if x])
        print("\n| variant | " + " | ".join(counts(res[""]).keys()) + " |\n|---|" + "---|" * len(counts(res[""])))
        for v, rs in res.items():
            print(f"| {v or 'code'} | " + " | ".join(str(x) for x in counts(rs).values()) + " |")
        moved_table(res)
        if "near1" in res:  # the code against the choice before the factor, scene by scene
            m = scenes_moved(res["near1"], res[""])
            print(f"\ncode against near1, by scene: {m['scenes_better']} scenes better, {m['scenes_worse']} worse "
                  f"(sign test p = {m['sign_test_p']}); " + "; ".join(f"{k}: {', '.join(v)}"
                                                                    for k, v in sorted(m["scenes"].items())))
    print(buf.getvalue())
    if a.out is not None:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(a.out, f"# `python -m benchmarks.probes.focus_choice_nearest "
                          f"{' '.join(str(f) for f in a.results)} --near {a.near} --out {a.out}`\n\n" + buf.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
