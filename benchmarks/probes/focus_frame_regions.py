"""Which regions make one frame's focus estimate err (issue 32: scene 2027's monotone set, its nearest frame 0.043 D
off with a bootstrap spread of 0.005 D). Understanding only: it chooses nothing.

For one frame of a `bench_diagnose_focus` set, on the first round's sweep as the focus fit reads it (re-anchored,
exposure, floors and weights: `focus_level_probe.prepared_sweep`), with the other frames at their own estimates:
every region's weighted cost w_r ss_r(x) of the frame focused at x (`focusrobust.region_ss`, the region's level
profiled out). The frame's estimate minimises their sum, so its error splits exactly over the regions:

    est - true = sum_r pull_r,   pull_r = -w_r ss_r'(true) / H,

H the secant curvature of the summed cost between the truth and the estimate (where its slope is 0). Per region:
its pull, its share of the frame's information (w_r ss_r'' at the estimate), where its own cost is lowest, the
estimate without it (leave one out), where its twin curve peaks (its content in focus), its ground truth's
inverse depth (median and the 10-90 % span: a wide span is an occlusion edge or a slanted surface), its texture
(the twin curve's range over the sweep, log units), its fitted noise floor (log units below its twin's top) and the
side of focus the frame sees it from (the twin curve's slope there). Summaries: how concentrated the pull and the
information are (the largest region's share, the effective number of regions), and the frame's level misfit.

    python -m benchmarks.probes.focus_frame_regions scene2027:monotone scene2029:monotone [--frame 0] \\
        [--out results/focus_frame_regions.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import io
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

from benchmarks import RESULTS
from benchmarks import focus_level_probe as flp

WINDOW_D = 0.15  # the frame's focus is scanned this far either side of the truth (diopters)
STEP_D = 0.001


def region_costs(prepared, d: np.ndarray, frame: int, xs: np.ndarray) -> np.ndarray:
    """(X, R) every region's weighted cost with `frame` focused at xs (capture 0), the other frames at d (n, S)."""
    from aat_deploy.diagnose import focusrobust

    out = []
    for x in xs:
        dd = d.copy()
        dd[0, frame] = x
        out.append(prepared.weight[0] * focusrobust.region_ss(prepared.capture, focusrobust.twin_at(prepared, dd))[0])
    return np.array(out)


def profile(sweep, prepared, d: np.ndarray, frame: int, xs: np.ndarray) -> dict:
    """The frame's summed cost over xs with the floors as fitted (at the estimates d) and profiled (refitted for
    every x, the others at d), each in units of the residual variance at its minimum (sum of weighted squares over
    regions x frames less the regions' levels and floors and the frames' foci: regions counted as independent, which
    understates the width), and the focus range where each stays within 1 of its minimum (a 1-sigma interval)."""
    from aat_deploy.diagnose import focusrobust

    g = focusrobust.frame_gains_log(sweep)
    base = dataclasses.replace(sweep, capture=sweep.capture - 2.0 * g[:, None, :])
    w = prepared.weight
    fixed, prof = [], []
    for x in xs:
        dd = d.copy()
        dd[0, frame] = x
        fixed.append(float(np.sum(w * focusrobust.region_ss(prepared.capture, focusrobust.twin_at(prepared, dd)))))
        fl = focusrobust.floored(base, focusrobust.fit_floors(base, dd))
        prof.append(float(np.sum(w * focusrobust.region_ss(fl.capture, focusrobust.twin_at(fl, dd)))))
    n, r, s = prepared.capture.shape
    dof = max(int((w > 0).sum()) * (s - 2) - s, 1)
    out = {}
    for name, c in (("fixed", np.array(fixed)), ("profiled", np.array(prof))):
        var = c.min() / dof
        inside = xs[(c - c.min()) / var <= 1.0]
        out[name] = (float(xs[int(np.argmin(c))]), float(inside.min()), float(inside.max()))
    return out


def decompose(costs: np.ndarray, xs: np.ndarray, true: float) -> dict:
    """The frame's estimate (the summed cost's minimum over xs), its error split over regions, the information
    shares, every region's own minimum and the estimate without it. costs (X, R)."""
    total = costs.sum(1)
    i_hat = int(np.argmin(total))
    est = float(xs[i_hat])
    slope = np.gradient(costs, xs, axis=0)  # (X, R)
    i_true = int(np.argmin(np.abs(xs - true)))
    g = slope[i_true]  # each region's slope at the truth
    h_secant = -g.sum() / (est - true) if abs(est - true) > STEP_D / 2 else np.nan
    curv = np.gradient(slope, xs, axis=0)[i_hat]
    loo = np.array([xs[int(np.argmin(total - costs[:, r]))] for r in range(costs.shape[1])])
    own = xs[np.argmin(costs, 0)]
    own_edge = (np.argmin(costs, 0) == 0) | (np.argmin(costs, 0) == len(xs) - 1)
    return {"est": est, "pull": -g / h_secant, "curv": curv, "loo": loo, "own": own, "own_edge": own_edge}


def region_content(cap, sweep, prepared, d: np.ndarray, frame: int) -> dict:
    """Per region (R,): ground truth's inverse depth (median, 10 and 90 %), twin peak, texture, floor, slope."""
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose import focusrobust
    from aat_deploy.diagnose.compare import region_index

    h, w = cap.gt_m.shape
    reg = region_index(h, w, ff.FIT_GRID)
    inv = 1.0 / cap.gt_m
    n_r = ff.FIT_GRID[0] * ff.FIT_GRID[1]
    q = np.array([np.nanquantile(inv[reg == r], (0.1, 0.5, 0.9)) for r in range(n_r)])  # (R, 3)
    g = focusrobust.frame_gains_log(sweep)
    base = dataclasses.replace(sweep, capture=sweep.capture - 2.0 * g[:, None, :])
    beta = focusrobust.fit_floors(base, d)[0]
    top = sweep.twin[0].max(-1)
    n, r, s = prepared.capture.shape
    at = np.broadcast_to(d[:, None, :], (n, r, s))
    slope = (ff.curves_at(prepared, at + 0.01) - ff.curves_at(prepared, at - 0.01))[0, :, frame] / 0.02
    # the region's misfit in this frame at the truth-free estimates: capture less twin, its level over frames removed
    res = (prepared.capture - focusrobust.twin_at(prepared, d))[0]
    res = res - res.mean(-1, keepdims=True)
    # how much of the frame's (floored) twin measure is the floor: exp(beta) / (exp(t) + exp(beta))
    t = focusrobust.twin_at(sweep, d)[0, :, frame]
    floor_share = np.exp(beta - np.logaddexp(t, beta))
    return {"inv_q": q, "peak": sweep.grid_d[sweep.twin[0].argmax(-1)], "texture": np.ptp(sweep.twin[0], -1),
            "floor_below_top": top - beta, "floor_share": floor_share, "beta": beta,
            "lum": None if sweep.twin_lum is None else sweep.twin_lum[0], "slope": slope, "misfit": res[:, frame]}


def report(spec: str, frame: int | None, model, lens, src, threads: int) -> str:
    from aat_deploy.diagnose import focusfit as ff

    index, folder, kind = flp.set_spec(spec)
    cap, sweep, prepared, true_d, rep = flp.prepared_sweep(folder, kind, index, model, lens, src, threads)
    est_all = ff.frame_focus(prepared)
    err_all = est_all[0] - true_d
    f = int(np.argmax(np.abs(err_all))) if frame is None else frame
    xs = np.arange(true_d[f] - WINDOW_D, true_d[f] + WINDOW_D + 1e-9, STEP_D)
    dec = decompose(region_costs(prepared, est_all, f, xs), xs, true_d[f])
    con = region_content(cap, sweep, prepared, est_all, f)
    used = prepared.weight[0] > 0
    pull, curv = dec["pull"], np.maximum(dec["curv"], 0.0)
    err = dec["est"] - true_d[f]
    info = curv / max(curv.sum(), 1e-300)
    order = np.argsort(-np.abs(pull))
    eff_info = curv.sum() ** 2 / max(np.sum(curv ** 2), 1e-300)
    same_side = float(np.mean(np.sign(con["slope"][used]) == np.sign(np.median(con["slope"][used]))))
    rows, cols = ff.FIT_GRID
    out = io.StringIO()
    with redirect_stdout(out):
        print(f"\n### {spec}, frame {f} (true {true_d[f]:.3f} D, reported {rep[f]:.3f} D)\n")
        print(f"- per-frame estimates' errors (D), frames 0-{len(true_d) - 1}: "
              + ", ".join(f"{e:+.3f}" for e in err_all))
        print(f"- this frame: the fit's estimate {est_all[0, f] - true_d[f]:+.3f} D off; the scan's "
              f"{err:+.3f} D (other frames at their estimates; {STEP_D} D steps, Catmull-Rom twin)")
        print(f"- regions used: {int(used.sum())}/{used.size}; their content peaks at "
              f"{np.quantile(con['peak'][used], 0.1):.2f}-{np.quantile(con['peak'][used], 0.9):.2f} D (10-90 %); "
              f"the frame sees {100 * same_side:.0f} % of them from the same side of focus")
        print(f"- pull: the largest region's {abs(pull[order[0]]):.3f} D of {abs(err):.3f}; the 3 largest "
              f"{np.sum(pull[order[:3]]):+.3f} D; regions pulling the same way as the error: "
              f"{int(np.sum(np.sign(pull[used]) == np.sign(err)))}/{int(used.sum())}, their sum "
              f"{np.sum(pull[used & (np.sign(pull) == np.sign(err))]):+.3f} D, the others "
              f"{np.sum(pull[used & (np.sign(pull) != np.sign(err))]):+.3f} D")
        print(f"- information: effective number of regions {eff_info:.1f} (of {int(used.sum())}); the largest "
              f"region's share {100 * info.max():.0f} %")
        print(f"- the estimate without one region (leave one out): {np.min(dec['loo']) - true_d[f]:+.3f} to "
              f"{np.max(dec['loo']) - true_d[f]:+.3f} D off")
        own = dec["own"][used] - true_d[f]
        print(f"- regions' own minimum (D off the truth, 10/50/90 %): {np.quantile(own, 0.1):+.3f} / "
              f"{np.median(own):+.3f} / {np.quantile(own, 0.9):+.3f}; at the scan's edge (+-{WINDOW_D} D): "
              f"{int(dec['own_edge'][used].sum())}")
        print(f"- the frame's misfit (capture less twin at the estimates, each region's level over the frames "
              f"removed; weighted mean over regions): {np.average(con['misfit'][used], weights=prepared.weight[0][used]):+.3f} log")
        prof = profile(sweep, prepared, est_all, f, xs)
        for name, (x0, lo, hi) in prof.items():
            print(f"- the frame's cost with the floors {name}: lowest {x0 - true_d[f]:+.3f} D off, within 1 residual "
                  f"variance of it from {lo - true_d[f]:+.3f} to {hi - true_d[f]:+.3f} D (width {hi - lo:.3f} D)")
        fl = used & np.isfinite(con["beta"])
        print(f"- noise floors: fitted in {int(fl.sum())}/{int(used.sum())} regions; the floor's share of this "
              f"frame's twin measure (10/50/90 %): "
              + " / ".join(f"{100 * v:.0f} %" for v in np.quantile(np.where(fl, con["floor_share"], 0)[used],
                                                                (0.1, 0.5, 0.9))))
        if con["lum"] is not None and fl.sum() > 2:
            a, b = np.polyfit(con["lum"][fl], con["beta"][fl], 1)
            rr = np.corrcoef(con["lum"][fl], con["beta"][fl])[0, 1]
            print(f"- floors against the regions' log luminance: slope {a:.2f} (shot noise: 1), correlation "
                  f"{rr:.2f}; scatter about the line {np.std(con['beta'][fl] - (a * con['lum'][fl] + b)):.2f} log")
        print("\npull per region (mD; rows top to bottom, `.` unused):\n")
        print("| row | " + " | ".join(str(c) for c in range(cols)) + " |")
        print("|---|" + "---|" * cols)
        for i in range(rows):
            cells = [f"{1000 * pull[i * cols + c]:+.0f}" if used[i * cols + c] else "." for c in range(cols)]
            print(f"| {i} | " + " | ".join(cells) + " |")
        print("\nthe 8 regions pulling most:\n")
        print("| region (row, col) | pull (D) | info share | own min (D off) | without it (D off) | content peak (D) | "
              "GT inverse depth 10/50/90 % (D) | texture (log) | floor below top (log) | twin slope (log/D) | "
              "floor's share of the frame | misfit (log) | weight |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in order[:8]:
            q = con["inv_q"][r]
            print(f"| {r // cols}, {r % cols} | {pull[r]:+.4f} | {100 * info[r]:.0f} % | "
                  f"{dec['own'][r] - true_d[f]:+.3f}{' (edge)' if dec['own_edge'][r] else ''} | "
                  f"{dec['loo'][r] - true_d[f]:+.3f} | {con['peak'][r]:.2f} | {q[0]:.2f} / {q[1]:.2f} / {q[2]:.2f} | "
                  f"{con['texture'][r]:.1f} | {con['floor_below_top'][r]:.1f} | {con['slope'][r]:+.2f} | "
                  f"{100 * (con['floor_share'][r] if np.isfinite(con['beta'][r]) else 0):.0f} % | "
                  f"{con['misfit'][r]:+.3f} | {prepared.weight[0][r]:.2f} |")
    return out.getvalue()


def chain_table(spec: str, chains: list[str], model, lens, src, threads: int) -> str:
    """The same set's per-frame estimates with the twin carrying the capture's own effects (`aat-render`'s
    defaults, which made it: vignetting, noise; the runtime's RAW development as `raw_pipeline`): does the frame
    still err when the twin lacks nothing?"""
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.render import effects as fx

    index, folder, kind = flp.set_spec(spec)
    out = io.StringIO()
    with redirect_stdout(out):
        print(f"\n### {spec}: per-frame estimates' errors (D) by the twin's effects\n")
        print("| twin's effects | " + " | ".join(f"frame {f}" for f in range(8)) + " | floors fitted | "
              "the nearest frame: floor's share of its twin measure (median) |")
        print("|---|" + "---|" * 10)
        for spec_chain in chains:
            chain = [] if spec_chain == "none" else fx.parse(spec_chain.split(","))
            cap, sweep, prepared, true_d, _ = flp.prepared_sweep(folder, kind, index, model, lens, src, threads, chain)
            est = ff.frame_focus(prepared)
            con = region_content(cap, sweep, prepared, est, 0)
            used = prepared.weight[0] > 0
            fl = used & np.isfinite(con["beta"])
            share = np.median(np.where(fl, con["floor_share"], 0.0)[used])
            print(f"| {spec_chain} | " + " | ".join(f"{e:+.3f}" for e in est[0] - true_d)
                  + f" | {int(fl.sum())}/{int(used.sum())} | {100 * share:.0f} % |")
    return out.getvalue()


def starts_table(spec: str, shifts: list[float], model, lens, src, threads: int) -> str:
    """The same set's per-frame estimates with the floors <-> focus alternation (`focusrobust.prepare`) started
    elsewhere than the reported focus (every frame shifted alike), once from it run to a 10 times tighter
    convergence, and once from the truth (which the fit never knows): is its end point unique (the data decide) or
    does it depend on where it starts (several self-consistent floors and foci)?"""
    from aat_deploy.diagnose import focusrobust

    index, folder, kind = flp.set_spec(spec)
    _, sweep, _, true_d, _ = flp.prepared_sweep(folder, kind, index, model, lens, src, threads)
    out = io.StringIO()
    ends = []
    with redirect_stdout(out):
        print(f"\n### {spec}: per-frame estimates' errors (D) by where the alternation starts\n")
        print("| start | iterations | " + " | ".join(f"frame {f}" for f in range(len(true_d))) + " |")
        print("|---|---|" + "---|" * len(true_d))
        runs = [(f"reported {x:+.2f} D", x, focusrobust.RobustConfig()) for x in shifts]
        runs.append(("reported, converged to 0.0002 D (at most 48 iterations)", 0.0,
                     focusrobust.RobustConfig(iterations=48)))
        # where the data would hold the frames if the alternation began at the truth (the fit never knows it)
        runs.append(("the truth (for understanding only)", true_d[None] - sweep.base_d, focusrobust.RobustConfig()))
        for label, x, cfg in runs:
            tight = cfg.iterations != focusrobust.ITERATIONS
            old, focusrobust.CONVERGED_D = focusrobust.CONVERGED_D, (0.0002 if tight else focusrobust.CONVERGED_D)
            try:
                _, r = focusrobust.prepare(dataclasses.replace(sweep, base_d=sweep.base_d + x), cfg)
            finally:
                focusrobust.CONVERGED_D = old
            e = np.asarray(r["frame_focus_d"][-1])[0] - true_d
            ends.append(e)
            print(f"| {label} | {len(r['frame_focus_d']) - 1} | " + " | ".join(f"{v:+.3f}" for v in e) + " |")
        spread = np.ptp(np.array(ends[:-1]), 0)
        print("| **spread (max - min) over the starts from the reported focus** | | " + " | ".join(f"{v:.3f}" for v in spread) + " |")
    return out.getvalue()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sets", nargs="+", help="capture:kind (focus_level_probe's captures and the fresh ones)")
    ap.add_argument("--frame", type=int, help="the frame (near to far); default: the one whose estimate errs most")
    ap.add_argument("--chains", nargs="+", metavar="EFFECTS", help="instead: the per-frame estimates with these "
                    "effects in the twin (comma-separated; `none` = the first round's twin)")
    ap.add_argument("--starts", nargs="+", type=float, metavar="SHIFT_D", help="instead: the per-frame estimates "
                    "with the floors/focus alternation started at the reported focus shifted by these (diopters)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=str(RESULTS / "focus_frame_regions.md"))
    a = ap.parse_args()
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.infer.model import DfFModel

    model = DfFModel(str(flp.bench.ROOT / "models" / "rf50_dfvnet_aat_field.onnx"), threads=a.threads)
    lens, _ = find_lens(model, None)
    src = find_surrogate(lens, None, a.threads)
    text = "".join(chain_table(s, a.chains, model, lens, src, a.threads) if a.chains else
                   starts_table(s, a.starts, model, lens, src, a.threads) if a.starts else
                   report(s, a.frame, model, lens, src, a.threads) for s in a.sets)
    print(text)
    Path(a.out).write_text(f"# `python -m benchmarks.probes.focus_frame_regions {' '.join(a.sets)}"
                           f"{'' if a.frame is None else f' --frame {a.frame}'}"
                           f"{' --chains ' + ' '.join(a.chains) if a.chains else ''}"
                           f"{' --starts ' + ' '.join(map(str, a.starts)) if a.starts else ''}`\n" + text)


if __name__ == "__main__":
    main()
