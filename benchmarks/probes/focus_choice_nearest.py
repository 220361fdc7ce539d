"""Does the family choice give the nearest fitted frame too much say? (issue 32, after the ninth round.) On stored
`bench_diagnose_focus` rows (development rows only: nothing held out enters it):

1. every fitted frame's error against its modelled error (bootstrap spread and systematic error in quadrature), by
   distance rank among the fitted frames (0: the nearest): rms error, median modelled error, median noise share, rms
   standardised error;
2. the whole choice redone from the rows' stored fits (`bench_diagnose_focus.rescored(on_estimates=True)`, the code as
   it is) with the choice's error model (`focusfit.error_scale`, `score_families`; not the standard errors) changed:
   `weights` every frame's total variance divided by its noise-share weight (`focusfit.signal_weight`, rows with
   noise shares only), `nearF` the nearest fitted frame's total variance times F squared; the benchmark's counts for
   each, and every set whose family, largest error or undetermined count moved.

    python -m benchmarks.probes.focus_choice_nearest RESULTS.jsonl ... [--near 1.5,2,3]
"""

from __future__ import annotations

import argparse
import json
import sys
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

    orig = ff.error_scale, ff.score_families, ff.signal_weight
    state: dict = {}

    def inflate(frame_sd, sys_d, frames):
        sd2 = np.asarray(frame_sd, np.float64) ** 2
        tot = sd2 + np.asarray(sys_d, np.float64) ** 2
        if state["v"] == "weights":
            aw = state.get("aw")
            if aw is None or aw.shape != tot.shape:
                return sys_d
            return np.sqrt(tot / np.clip(aw, 1e-3, 1.0) - sd2)
        fr, rep = np.asarray(frames) > 0, state["rep"]
        nearest = np.zeros(fr.shape, bool)
        for i in range(fr.shape[0]):
            idx = np.where(fr[i])[0]
            if len(idx):
                nearest[i, idx[np.argmax(rep[i, idx])]] = True
        return np.sqrt(np.where(nearest, tot * state["f"] ** 2, tot) - sd2)

    def es(fits, frame_sd, frames, systematic_d=ff.SYSTEMATIC_D):
        return orig[0](fits, frame_sd, frames, inflate(frame_sd, systematic_d, frames) if state["v"] else systematic_d)

    def sf(fits, frame_sd, frames, systematic_d=ff.SYSTEMATIC_D):
        return orig[1](fits, frame_sd, frames, inflate(frame_sd, systematic_d, frames) if state["v"] else systematic_d)

    def sw(share, frames):
        w = orig[2](share, frames)
        state["aw"] = w if share is not None else None
        return w

    out = {}
    try:
        ff.error_scale, ff.score_families, ff.signal_weight = es, sf, sw
        for v in ["", "weights"] + [f"near{f:g}" for f in near]:
            state["v"], state["f"] = v, float(v[4:]) if v.startswith("near") else 1.0
            res = []
            for r in rows:
                state["aw"] = None
                state["rep"] = np.asarray({x["family"]: x for x in r.get("families") or []}.get(
                    "none", {"true_d": [[np.nan]]})["true_d"], np.float64)
                x = bench.rescored(r, v or "code", on_estimates=True)
                if x is not None:
                    res.append(x)
            out[v] = res
    finally:
        ff.error_scale, ff.score_families, ff.signal_weight = orig
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="bench_diagnose_focus results files (development rows)")
    ap.add_argument("--near", default="1.5,2,3", help="factors on the nearest fitted frame's error (comma-separated)")
    a = ap.parse_args(argv)
    from benchmarks.probes.focus_noise_weight import counts

    rows = [json.loads(x) for f in a.results for x in f.read_text().splitlines() if x.strip()]
    rows = list({(r["capture"], r["kind"]): r for r in rows}.values())
    print("| rank (0 nearest fitted) | frames | rms error (D) | median modelled error (D) | median noise share | rms z |")
    print("|---|---|---|---|---|---|")
    for b in by_rank(rows):
        print(f"| {b['rank']} | {b['frames']} | {b['rms_err_d']} | {b['median_model_d']} | {b['median_share']} | {b['rms_z']} |")
    res = variants(rows, [float(x) for x in a.near.split(",") if x])
    print("\n| variant | " + " | ".join(counts(res[""]).keys()) + " |\n|---|" + "---|" * len(counts(res[""])))
    for v, rs in res.items():
        print(f"| {v or 'code'} | " + " | ".join(str(x) for x in counts(rs).values()) + " |")
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
