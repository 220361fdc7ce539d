"""Calibrate the confidence of the classical focus method and of DfF models on held-out validation stacks, then
measure how well it predicts on other held-out validation stacks (reliability diagram).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.calibrate_confidence [--n-fit 20] [--n-assess 12] [--write]
        [--models rf50_dfvnet_aat_field,paper50_dfvnet_aat]

What confidence means (aat_deploy/confidence.py): the chance that the pixel's depth is within 10 % of the truth.
Fitted by isotonic regression of "within 10 %" on each method's own score (for the focus method together with a
second score, the tolerance in frame steps, `aat_deploy.confidence.tolerance_steps`: 10 % of the estimate in
diopters over the local frame spacing, so one calibration serves near and far depths and any schedule):
- the focus method: `estimate` against its own (unfilled) estimate, on the score among ESTIMATE_SCORES whose
  calibrated confidence has the lowest Brier score on the fit stacks (the most informative; every one is
  calibrated): the focus-curve contrast with floors 1e-3 .. 1e-1 (`aat_deploy.focus.estimate.contrast`), or the
  estimates' agreement with their neighbours (`aat_deploy.confidence.agreement`); then `fill`, the fill's
  support, against the final depth of the pixels the fill changed
  (those whose contrast is below the fill's c_full: the fill itself weighs by the contrast, as before);
- a model: `relative_std`, its std_m / depth_m, against its depth (non-increasing).

Material: validation stacks only, never the test sets (seeds 777777, test photographs). Fit: the validation stacks
of `select_focus_noise.py` (training photographs, seed 424242); assessment: other validation stacks (training
photographs, seed 434343). Cells: each shipped lens's fixed schedule (RF50 8 frames, paper lens 10, 0.5-10 m), clean,
with sensor noise (8000 e- full well), and with noise and a typical phone's processing (`phone_jpeg`), plus a
phone-like 5-frame RF50 stack with the phone processing. The focus method runs as `aat-infer --method focus --lens`
(aberration-aware, the lens's map): the confidence speaks for the image evidence under the right mapping.
Pixels: every 4th row and column of each stack (the fit has millions; neighbours are not independent anyway).

Prints the tables of BENCHMARKS.md ("Calibrated confidence"), writes results/confidence_calibration.json
and results/figures/confidence_reliability.png; with --write also the calibrations themselves
(aat_deploy/focus/data/confidence.json, models/<model>.confidence.json).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks import FIGURES, RESULTS
from benchmarks.bench_table2 import LENSES
from benchmarks.select_focus_noise import CONDITIONS, VAL_SEED

ROOT = Path(__file__).resolve().parents[1]

ASSESS_SEED = 434343  # validation stacks apart from the fit's (424242), the test sets' (777777) and training seeds
STRIDE = 4
ESTIMATE_SCORES = ("contrast 0.001", "contrast 0.01", "contrast 0.03", "contrast 0.1", "agreement")
N_BINS, N_BINS2 = 24, 10  # quantile bins of the score and of the tolerance in frame steps
CELLS = [(lens, LENSES[lens]["stack_size"], cond) for lens in ("rf50", "paper50") for cond in CONDITIONS] + \
        [("rf50", 5, "phone")]


def cell_name(cell) -> str:
    return f"{cell[0]} {cell[1]} frames {cell[2]}"


def stacks(cell, seed: int, n: int):
    from training.train.testsets import TestSetSpec, load_test_set

    lens, size, cond = cell
    spec = TestSetSpec(LENSES[lens]["lens"], LENSES[lens]["psf"], size, n_procedural=n, middlebury=False, seed=seed,
                       photo_split="train", effects=CONDITIONS[cond])
    return load_test_set(spec, str(ROOT / "cache/heldout"), progress=True)["procedural"]


def within(depth_m: np.ndarray, gt_m: np.ndarray, tol: float) -> np.ndarray:
    return np.abs(depth_m - gt_m) <= tol * gt_m


def sub(a: np.ndarray) -> np.ndarray:
    return a[::STRIDE, ::STRIDE]


def focus_map(lens: str):
    from aat_deploy.focus.bestfocus import load_json, map_path_for_lens

    return load_json(map_path_for_lens(ROOT / LENSES[lens]["lens"]))


def fit_focus(cells, n: int, cfg, tol: float):
    """Stage 1: the score and `estimate` on the unfilled estimates; stage 2: `fill` on the filled pixels' final
    depth. Returns the calibration (its notes name the chosen score, `estimate_score`) and each score's Brier
    score."""
    from aat_deploy.confidence import Calibration, Curve, agreement, fit_curve, tolerance_steps
    from aat_deploy.focus import classical_depth
    from aat_deploy.focus.estimate import contrast
    from aat_deploy.focus.measures import focus_volume

    raw = replace(cfg, confidence="raw", fill="none")
    score, ok1, steps1 = {t: [] for t in ESTIMATE_SCORES}, [], []
    for cell in cells:
        fmap = focus_map(cell[0])
        for it in stacks(cell, VAL_SEED, n):
            vol = focus_volume(it.stack, cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px)
            r = classical_depth(it.stack, it.focus_m, fmap, raw, volume=vol)
            v = sub(it.depth_m) > 0
            d = 1.0 / np.maximum(sub(r.diopters), 1e-3)
            m_max, m_min = vol.max(0), vol.min(0)
            for t in ESTIMATE_SCORES:
                s = (agreement(r.diopters, r.focus_m, cfg.window_px) if t == "agreement"
                     else contrast(m_max, m_min, float(t.split()[1])))
                score[t].append(sub(s)[v])
            steps1.append(sub(tolerance_steps(r.diopters, r.focus_m, tol))[v])
            ok1.append(within(d, sub(it.depth_m), tol)[v])
    ok1, steps1 = np.concatenate(ok1), np.concatenate(steps1)
    curves, brier = {}, {}
    for t in ESTIMATE_SCORES:
        s = np.concatenate(score[t])
        curves[t] = fit_curve(s, ok1, n_bins=N_BINS, second=steps1, n_bins2=N_BINS2)
        brier[t] = float(np.mean((curves[t](s, steps1) - ok1) ** 2))
    best = min(ESTIMATE_SCORES, key=lambda t: brier[t])
    if best not in ("agreement", "contrast 0.001"):  # the method computes these two (its contrast floor is 1e-3)
        raise SystemExit(f"the best score is {best}: teach aat_deploy.focus.method to compute it first")
    kind = "agreement" if best == "agreement" else "contrast"
    est = curves[best]
    interim = Calibration({"estimate": est, "fill": Curve([0.0, 1.0], [0.0, 1.0])}, tol, {"estimate_score": kind})
    support, ok2, steps2 = [], [], []
    for cell in cells:
        fmap = focus_map(cell[0])
        for it in stacks(cell, VAL_SEED, n):
            vol = focus_volume(it.stack, cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px)
            r = classical_depth(it.stack, it.focus_m, fmap, cfg, volume=vol, confidence_calibration=interim)
            m = (sub(it.depth_m) > 0) & sub(r.filled)
            support.append(sub(r.fill_support)[m])
            steps2.append(sub(tolerance_steps(1.0 / r.depth_m, r.focus_m, tol))[m])
            ok2.append(within(sub(r.depth_m), sub(it.depth_m), tol)[m])
    fill = fit_curve(np.concatenate(support), np.concatenate(ok2), n_bins=N_BINS, second=np.concatenate(steps2),
                     n_bins2=N_BINS2)
    return Calibration({"estimate": est, "fill": fill}, tol, {
        "made_by": "benchmarks/calibrate_confidence.py", "fit_seed": VAL_SEED, "photo_split": "train",
        "cells": [cell_name(c) for c in cells], "scenes_per_cell": n, "pixel_stride": STRIDE,
        "focus_config": {k: getattr(cfg, k) for k in ("measure", "window_px", "prefilter_px", "estimator", "c_full")},
        "estimate_score": kind, "brier_by_score": brier,
        "mapping": "aberration-aware (the lens's calibrated best-focus map)"}), brier


def assess_focus(cells, n: int, cfg, cal, thresholds):
    """The calibrated confidence against the final depth, per cell and pooled; beside it the confidence the method
    gave before the calibration (the raw contrast with the fill's floor, read as a probability)."""
    from aat_deploy.confidence import reliability
    from aat_deploy.focus import classical_depth
    from aat_deploy.focus.estimate import contrast
    from aat_deploy.focus.measures import focus_volume

    out, pooled = {}, {"conf": [], "ok": [], "raw": [], "filled": []}
    for cell in cells:
        fmap = focus_map(cell[0])
        conf, ok, rawc, filled = [], [], [], []
        for it in stacks(cell, ASSESS_SEED, n):
            vol = focus_volume(it.stack, cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px)
            r = classical_depth(it.stack, it.focus_m, fmap, cfg, volume=vol, confidence_calibration=cal)
            v = sub(it.depth_m) > 0
            conf.append(sub(r.confidence)[v])
            ok.append(within(sub(r.depth_m), sub(it.depth_m), cal.tolerance_rel)[v])
            rawc.append(sub(contrast(vol.max(0), vol.min(0), 1e-3))[v])  # the confidence before calibration
            filled.append(sub(r.filled)[v])
        conf, ok, rawc, filled = (np.concatenate(a) for a in (conf, ok, rawc, filled))
        for k, a in zip(("conf", "ok", "raw", "filled"), (conf, ok, rawc, filled)):
            pooled[k].append(a)
        out[cell_name(cell)] = summarise(conf, ok, thresholds) | {
            "ece_raw_contrast": reliability(rawc, ok)["ece"], "filled_share": float(filled.mean()),
            "reliability_own": reliability(conf[~filled], ok[~filled]),
            "reliability_filled": reliability(conf[filled], ok[filled])}
    p = {k: np.concatenate(v) for k, v in pooled.items()}
    out["all"] = summarise(p["conf"], p["ok"], thresholds) | {
        "ece_raw_contrast": reliability(p["raw"], p["ok"])["ece"], "filled_share": float(p["filled"].mean()),
        "reliability_raw_contrast": reliability(p["raw"], p["ok"])}
    return out


def summarise(conf: np.ndarray, ok: np.ndarray, thresholds) -> dict:
    from aat_deploy.confidence import reliability

    rel = reliability(conf, ok)
    d = {"ece": rel["ece"], "within_share": float(ok.mean()), "reliability": rel, "pixels": int(ok.size)}
    for t in thresholds:
        known = conf >= t
        d[f"at_{t:g}"] = {"unknown_share": float(1 - known.mean()),
                          "within_share_of_known": float(ok[known].mean()) if known.any() else None}
    return d


def model_cells(model, cells):
    from aat_deploy.lens.io import load_lens

    lo, hi = model.stack_range
    return [c for c in cells if load_lens(ROOT / LENSES[c[0]]["lens"]).name == model.lens_name and lo <= c[1] <= hi]


def run_model(model, it):
    r = model.infer(it.stack, it.focus_m)
    return r.depth_m, r.std_m


def fit_model(model, cells, n: int, tol: float):
    from aat_deploy.confidence import Calibration, fit_curve

    rel, ok = [], []
    for cell in cells:
        for it in stacks(cell, VAL_SEED, n):
            d, s = run_model(model, it)
            v = sub(it.depth_m) > 0
            rel.append((sub(s) / np.maximum(sub(d), 1e-6))[v])
            ok.append(within(sub(d), sub(it.depth_m), tol)[v])
    curve = fit_curve(np.concatenate(rel), np.concatenate(ok), increasing=False)
    return Calibration({"relative_std": curve}, tol, {
        "made_by": "benchmarks/calibrate_confidence.py", "model": model.path.name, "fit_seed": VAL_SEED,
        "photo_split": "train", "cells": [cell_name(c) for c in cells], "scenes_per_cell": n,
        "pixel_stride": STRIDE})


def assess_model(model, cells, n: int, cal, thresholds):
    from aat_deploy.confidence import std_confidence

    out, pc, po = {}, [], []
    for cell in cells:
        conf, ok = [], []
        for it in stacks(cell, ASSESS_SEED, n):
            d, s = run_model(model, it)
            v = sub(it.depth_m) > 0
            conf.append(sub(std_confidence(cal, d, s))[v])
            ok.append(within(sub(d), sub(it.depth_m), cal.tolerance_rel)[v])
        conf, ok = np.concatenate(conf), np.concatenate(ok)
        pc.append(conf)
        po.append(ok)
        out[cell_name(cell)] = summarise(conf, ok, thresholds)
    out["all"] = summarise(np.concatenate(pc), np.concatenate(po), thresholds)
    return out


def figure(path: Path, focus: dict, models: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = 2 + bool(models)
    fig, axes = plt.subplots(1, n, figsize=(5.2 * n, 5), squeeze=False)
    axes = axes[0]

    def curve(ax, rel, label, **kw):
        b = [r for r in rel["bins"] if r["pixels"] >= 100]
        ax.plot([r["confidence"] for r in b], [r["observed"] for r in b], "o-", ms=3, label=label, **kw)

    for ax in axes:
        ax.plot([0, 1], [0, 1], "k:", lw=1)
        ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="confidence (mean in bin)", ylabel="observed share within 10 %")
        ax.grid(alpha=0.3)
    for k, v in focus.items():
        if k != "all":
            curve(axes[0], v["reliability"], f"{k} (ECE {v['ece']:.3f})")
    axes[0].set_title("focus method, calibrated (held-out validation)")
    curve(axes[1], focus["all"]["reliability_raw_contrast"],
          f"raw focus-curve contrast (ECE {focus['all']['ece_raw_contrast']:.3f})", color="C3")
    curve(axes[1], focus["all"]["reliability"], f"calibrated (ECE {focus['all']['ece']:.3f})", color="C0")
    axes[1].set_title("focus method, all cells pooled")
    if models:
        for name, res in models.items():
            curve(axes[2], res["all"]["reliability"], f"{name} (ECE {res['all']['ece']:.3f})")
        axes[2].set_title("DfF models: std_m -> confidence")
    for ax in axes:
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n-fit", type=int, default=20, help="fit scenes per cell (the pre-filter selection's stacks)")
    ap.add_argument("--n-assess", type=int, default=12, help="assessment scenes per cell")
    ap.add_argument("--models", default="rf50_dfvnet_aat_field,paper50_dfvnet_aat",
                    help="shipped model names or paths to calibrate ('' for none)")
    ap.add_argument("--write", action="store_true", help="write the calibrations the runtime reads")
    ap.add_argument("--out", type=Path, default=RESULTS / "confidence_calibration.json")
    ap.add_argument("--figure", type=Path, default=FIGURES / "confidence_reliability.png")
    a = ap.parse_args(argv)
    if a.n_fit < 1 or a.n_assess < 1:
        ap.error("--n-fit and --n-assess must be >= 1")
    from aat_deploy.confidence import FOCUS_CALIBRATION, MIN_CONFIDENCE, TOLERANCE_REL, model_calibration_path
    from aat_deploy.focus import FocusConfig
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.io.atomic import write_text_atomic
    from aat_deploy.shipped import resolve

    thresholds = (0.3, MIN_CONFIDENCE, 0.7)
    cfg = FocusConfig()
    cal, brier = fit_focus(CELLS, a.n_fit, cfg, TOLERANCE_REL)
    print("\nBrier score on the fit stacks of each calibrated score of the method's own estimate: "
          + ", ".join(f"{t}: {b:.4f}" for t, b in brier.items()) + f" (chosen: {cal.notes['estimate_score']})")
    focus = assess_focus(CELLS, a.n_assess, cfg, cal, thresholds)
    results = {"tolerance_rel": TOLERANCE_REL, "fit_seed": VAL_SEED, "assess_seed": ASSESS_SEED,
               "n_fit": a.n_fit, "n_assess": a.n_assess, "focus": {"calibration": cal.to_dict(), "assessment": focus},
               "models": {}}
    if a.write:
        cal.save(FOCUS_CALIBRATION)
    for m in [x for x in a.models.split(",") if x]:
        model = DfFModel(resolve(m, "models"))
        cells = model_cells(model, CELLS)
        if not cells:
            print(f"{m}: no validation cell for its lens and stack size; skipped", file=sys.stderr)
            continue
        mcal = fit_model(model, cells, a.n_fit, TOLERANCE_REL)
        results["models"][model.path.stem] = {"calibration": mcal.to_dict(),
                                              "assessment": assess_model(model, cells, a.n_assess, mcal, thresholds)}
        if a.write:
            mcal.save(model_calibration_path(model.path))

    def table(title, res):
        print(f"\n{title}\n")
        print("| cell | pixels | within 10 % | ECE | ECE of the raw score | unknown at 0.5 | within 10 % of the known "
              "| filled |")
        print("|---|---|---|---|---|---|---|---|")
        for k, v in res.items():
            t = v[f"at_{MIN_CONFIDENCE:g}"]
            kn = "–" if t["within_share_of_known"] is None else f"{t['within_share_of_known']:.3f}"
            print(f"| {k} | {v['pixels']} | {v['within_share']:.3f} | {v['ece']:.3f} | "
                  f"{v.get('ece_raw_contrast', float('nan')):.3f} | {t['unknown_share']:.3f} | {kn} | "
                  f"{v.get('filled_share', float('nan')):.3f} |")

    table(f"Focus method (aberration-aware), held-out validation stacks ({a.n_assess} scenes per cell, seed "
          f"{ASSESS_SEED}); calibration fitted on {a.n_fit} per cell (seed {VAL_SEED})", focus)
    for name, r in results["models"].items():
        table(f"{name}: std_m -> confidence, held-out validation stacks", r["assessment"])
    write_text_atomic(a.out, json.dumps(results, indent=1))
    figure(a.figure, focus, {k: v["assessment"] for k, v in results["models"].items()})
    print(f"\nwrote {a.out}, {a.figure}"
          + (" and the calibrations" if a.write else " (calibrations not written: --write)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
