"""What the phone's map error within the farthest tile's radius is made of (issue 33, part a: the hand-chosen copy
0.083 D RMS there, the dominant part of its 0.101 D): the tiles' measurement against the smooth model's misfit.

    OMP_NUM_THREADS=1 python -m benchmarks.probes.phone_map_model --dump [--variants ...]   # 15 s per variant
    python -m benchmarks.probes.within_tiles [--variants ...] [--out results/within_tiles.json]   # seconds

On the dumps of `phone_map_model` (bench_calibrate's `cellphone_near` development sweeps: the nominal lens, the
hand-chosen copy and the three declared random copies of seed 2026; no held-out scene), per variant:

- **measurement error, per tile**: the tile's object minus the truth's in-focus object at the tile centre for the
  frame of its measured peak (D of object, what a fit through the tile reads minus the truth), and the measured peak
  minus the peak the truth gives it (D of reported focus); by field radius, by chart and by where the peak falls
  between two frames (the estimator's sub-frame phase);
- **model error**: the model fitted to the same tiles made exact (each peaking where the truth has its object in
  focus), scored against the truth over part a's 10 "inside" settings within the farthest tile's radius; at the fit's
  own order and family (what the measured fit's form can do with perfect tiles) and with the order chosen on them;
- **propagated measurement error**: the measured tiles' fit minus the exact tiles' fit at the same order and
  family (the part of the map's error the tiles' errors make);
- the tiles' errors split into their systematic part (the mean per chart and field-radius bin) and the scatter
  about it, each added alone to the exact tiles; and the measured tiles with every chart moved to its true distance
  (the tape's 2 mm and the near chart's fitted distance taken out);
- each by field radius and by focus setting, and the share of the squared error within the tiles' radius of the
  measured tiles' map at the rule's order (`model.fit_model`'s reported order, without the blend of orders) that
  model and propagated measurement explain (they add up to it but for their cross term, given).

Tried at the rule's order: other peak estimators on the same curves (`ESTIMATORS`; the fit's is `gauss`, a Gaussian
through the three frames around the peak, which is also how the truth map's points were found), and the fit's
weighting (tiles weighted by 1 / their residuals' robust variance per field-radius bin; Tukey's biweight).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks import RESULTS

VARIANTS = ("nominal", "copy", "copy_s2026_0", "copy_s2026_1", "copy_s2026_2")
RADIUS_EDGES = (0.0, 0.33, 0.5, 0.66, 0.75, 0.84, 0.9, 1.0)
PHASE_EDGES = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0)  # where a peak falls between its two frames (0: on the lower frame)


def _bins(v: np.ndarray, edges) -> dict:
    return {f"{lo:g}-{hi:g}": (v >= lo) & ((v < hi) if hi < edges[-1] else (v <= hi)) for lo, hi in
            zip(edges[:-1], edges[1:])}


def _stats(e: np.ndarray, groups: dict) -> dict:
    out = {}
    for k, m in groups.items():
        m = m & np.isfinite(e)
        if m.any():
            out[k] = {"n": int(m.sum()), "mean_d": float(np.mean(e[m])), "sd_d": float(np.std(e[m])),
                      "rms_d": float(np.sqrt(np.mean(e[m] ** 2)))}
    return out


def map_parts(pred: dict, truth: np.ndarray, d: dict, r_max: float) -> dict:
    """pred {name: (S, h, w) map}: RMS within the tiles' radius, by field radius and by focus setting, for each map
    minus the truth, and for the measured map minus the exact tiles' (propagated measurement error)."""
    from aat_deploy.calibrate.format import field_radius_of

    rad = field_radius_of(d["gx"], d["gy"], float(d["aspect"]))
    within = rad <= r_max
    rbins = {k: m & within for k, m in _bins(rad, RADIUS_EDGES).items() if (m & within).any()}
    out = {}
    for name, e in pred.items():
        rms = lambda m: float(np.sqrt(np.mean(e[:, m] ** 2)))
        out[name] = {"within_tiles_rms_d": rms(within), "overall_rms_d": float(np.sqrt(np.mean(e ** 2))),
                     "radius_rms_d": {k: rms(m) for k, m in rbins.items()},
                     "radius_mean_d": {k: float(np.mean(e[:, m])) for k, m in rbins.items()},
                     "radius_share_of_squared": {k: float(np.sum(e[:, m] ** 2) / np.sum(e[:, within] ** 2))
                                                 for k, m in rbins.items()},
                     "focus_rms_d": [float(np.sqrt(np.mean(e[s][within] ** 2))) for s in range(e.shape[0])]}
    return out


def estimator_peaks(d: dict, estimator: str) -> np.ndarray:
    """(N,) the measured tiles' peaks (reported D) from their stored curves with `estimator`."""
    from aat_deploy.focus.estimate import estimate_peak

    out = np.full(len(d["meas_x"]), np.nan)
    for i in np.unique(d["meas_sweep"]):
        c, fd = d[f"curves_{i}"], d[f"frames_d_{i}"]
        p = estimate_peak(c.astype(np.float32), fd.astype(np.float32), None, estimator).diopters
        sel = d["meas_sweep"] == i
        out[sel] = p[d["meas_row"][sel], d["meas_col"][sel]]
    return out


def phase(d: dict, reported: np.ndarray) -> np.ndarray:
    """(N,) where each peak lies between the two frames around it, 0..1 from the lower frame's diopters."""
    out = np.full(len(reported), np.nan)
    for i in np.unique(d["meas_sweep"]):
        fd = d[f"frames_d_{i}"]
        sel = d["meas_sweep"] == i
        k = np.clip(np.searchsorted(fd, reported[sel]) - 1, 0, len(fd) - 2)
        out[sel] = (reported[sel] - fd[k]) / (fd[k + 1] - fd[k])
    return out


def run(variant: str, estimators: tuple, log) -> dict:
    from aat_deploy.calibrate.fit import held_beyond_tiles
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import fit_family, fit_model
    from benchmarks.probes import phone_map_model as M

    d = M.load(variant)
    if "meas_truth_at_peak_d" not in d:
        raise SystemExit(f"{variant}: a dump without the per-tile truth: run phone_map_model --dump again")
    aspect = float(d["aspect"])
    meas, ideal = M.obs_of(d, "meas_"), M.obs_of(d, "ideal_")
    rad = field_radius_of(meas.x, meas.y, aspect)
    sweep_groups = {f"chart {i}": meas.sweep == i for i in np.unique(meas.sweep)}
    bias = meas.object_d - d["meas_truth_at_peak_d"]  # D of object: what a fit through the tile reads, minus truth
    peak_err = meas.reported_d - d["meas_ideal_reported_d"]  # D of reported focus
    ph = phase(d, meas.reported_d)
    out = {"variant": variant, "tiles": int(len(meas)),
           "measurement": {"bias_rms_d": float(np.sqrt(np.nanmean(bias ** 2))), "bias_mean_d": float(np.nanmean(bias)),
                           "by_radius": _stats(bias, _bins(rad, RADIUS_EDGES)),
                           "by_chart": _stats(bias, sweep_groups),
                           "by_phase": _stats(bias, _bins(ph, PHASE_EDGES)),
                           "peak_error_by_radius": _stats(peak_err, _bins(rad, RADIUS_EDGES))}}
    # the measured fit as the calibration makes it, and the exact tiles' at its order and family and at their own
    fit = fit_model(meas)
    order = (fit.degree, fit.focus_degree, fit.radial, fit.low_focus_degree)
    out["order"] = {"degree": fit.degree, "radial": fit.radial, "focus_degree": fit.focus_degree,
                    "low_focus_degree": fit.low_focus_degree, "family": fit.focus.family}
    r_max = float(np.max(rad))
    truth = d["truth"].astype(np.float64)

    def map_of(focus, field, obs):
        fp = held_beyond_tiles(field, obs)
        t = focus.true_diopters(d["reported_d"])
        return t[:, None, None] + fp(d["gx"], d["gy"], t)

    def at_order(obs):
        """The fit's order (the rule's, not a blend) and family on other tiles or weights: (map, residuals)."""
        res = fit_family(obs, fit.focus.family, order[0], order[1], radial=order[2], low_focus_degree=order[3])
        return map_of(res[0], res[1], obs), res[2]

    m_meas = map_of(fit.focus, fit.field, meas)
    m_ideal, ideal_res = at_order(ideal)
    fi = fit_model(ideal)
    m_ideal_own = map_of(fi.focus, fi.field, ideal)
    out["ideal_order"] = {"degree": fi.degree, "radial": fi.radial, "focus_degree": fi.focus_degree,
                          "low_focus_degree": fi.low_focus_degree, "family": fi.focus.family}
    out["ideal_residual_rms_d"] = float(np.sqrt(np.mean(ideal_res ** 2)))
    out["ideal_residual_by_radius"] = _stats(ideal_res, _bins(field_radius_of(ideal.x, ideal.y, aspect),
                                                               RADIUS_EDGES))
    # the tiles' errors split: systematic (their mean per chart and field-radius bin) and the scatter about it, each
    # added alone to the exact tiles (the same tiles: every measured tile has its exact peak); and the measured
    # tiles with every chart at its true distance (the tape's error and the near chart's fitted distance taken out)
    groups = np.zeros(len(meas), np.int64)
    for g, m in enumerate(((meas.sweep == s) & mb) for s in np.unique(meas.sweep)
                          for mb in _bins(rad, RADIUS_EDGES).values()):
        groups[m] = g
    if len(ideal) != len(meas) or not np.all(np.isfinite(bias)):
        raise SystemExit(f"{variant}: measured tiles without an exact peak (the split needs them paired)")
    sys_part = np.array([bias[groups == g].mean() for g in groups])
    maps = {"measured tiles": m_meas - truth}
    for name, err in (("systematic (chart x radius means)", sys_part), ("scatter about them", bias - sys_part)):
        o = M.obs_of(d, "ideal_")
        o.object_d = o.object_d + err
        maps[f"exact tiles + {name}"] = at_order(o)[0] - truth
    true_m = M.obs_of(d, "meas_")
    p = float(d["pupil_mm"])
    for s in np.unique(meas.sweep):
        m = meas.sweep == s
        ratio = (1000.0 / meas.object_d[m] - p) / (1000.0 * float(d["chart_m"][s]) - p)  # the plane's depth ratio
        true_m.object_d[m] = 1000.0 / ((1000.0 * float(d["true_chart_m"][s]) - p) * ratio + p)
    ft = fit_model(true_m)
    out["charts_m"] = {"as fitted": d["chart_m"].tolist(), "true": d["true_chart_m"].tolist()}
    # the fit's weighting, tried: tiles weighted by their residuals' robust spread per field-radius bin (the outer
    # tiles scatter twice as much), and Tukey's biweight (iterated); at the fit's order
    res0 = fit.residual_d
    edges = np.array(RADIUS_EDGES)
    b = np.clip(np.searchsorted(edges, rad, side="right") - 1, 0, len(edges) - 2)
    sd_bin = np.array([1.4826 * np.median(np.abs(res0[b == i] - np.median(res0[b == i]))) if (b == i).sum() > 5
                       else np.nan for i in range(len(edges) - 1)])
    sd = np.where(np.isfinite(sd_bin[b]), sd_bin[b], np.nanmax(sd_bin))
    w_tukey = np.ones(len(meas))
    for _ in range(5):
        r = fit_family(replace(meas, weight=w_tukey), fit.focus.family, order[0], order[1], radial=order[2],
                       low_focus_degree=order[3])[2]
        u = r / (4.685 * 1.4826 * float(np.median(np.abs(r))))
        w_tukey = np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0)
    for name, w in (("weighted 1 / SD^2 by radius", 1 / sd ** 2), ("Tukey biweight", w_tukey)):
        maps[f"measured tiles, {name}"] = at_order(replace(meas, weight=w / np.mean(w)))[0] - truth
    # the rule's order alone (the fit before the blend of orders): the decomposition's measured map
    m_rule = at_order(meas)[0]
    maps["measured tiles, the rule's order alone"] = m_rule - truth
    out["order"]["blend"] = [[c.degree, c.radial, c.focus_degree, c.low_focus_degree, round(c.weight, 4)]
                             for c in fit.blend]
    maps.update({"measured tiles, every chart at its true distance": map_of(ft.focus, ft.field, true_m) - truth,
                 "exact tiles, the measured fit's order": m_ideal - truth,
                 "exact tiles, their own order": m_ideal_own - truth, "propagated measurement": m_rule - m_ideal})
    # the estimators on the same curves: their tiles' errors and their maps (the fit's order and family)
    est = {}
    for e in estimators:
        pk = estimator_peaks(d, e)
        ok = np.isfinite(pk)
        o = meas.subset(ok)
        o.reported_d = pk[ok]
        err = (pk - d["meas_ideal_reported_d"])
        m_e, _ = at_order(o)
        maps[f"estimator {e}"] = m_e - truth
        est[e] = {"peak_error_rms_d": float(np.sqrt(np.nanmean(err ** 2))),
                  "peak_error_by_radius": _stats(err, _bins(rad, RADIUS_EDGES)),
                  "peak_error_by_phase": _stats(err, _bins(phase(d, pk), PHASE_EDGES))}
    out["estimators"] = est
    out["maps"] = map_parts(maps, truth, d, r_max)
    tot = out["maps"]["measured tiles, the rule's order alone"]["within_tiles_rms_d"] ** 2
    mod = out["maps"]["exact tiles, the measured fit's order"]["within_tiles_rms_d"] ** 2
    prop = out["maps"]["propagated measurement"]["within_tiles_rms_d"] ** 2
    out["within_tiles_share"] = {"model": mod / tot, "propagated measurement": prop / tot,
                                 "cross term": (tot - mod - prop) / tot}
    out["tiles_radius_max"] = r_max
    log(f"{variant}: within {out['maps']['measured tiles']['within_tiles_rms_d']:.4f} D (the rule's order alone "
        f"{np.sqrt(tot):.4f}); model (exact tiles, its "
        f"order) {np.sqrt(mod):.4f}, own order {out['maps']['exact tiles, their own order']['within_tiles_rms_d']:.4f}; "
        f"propagated measurement {np.sqrt(prop):.4f}; tile bias RMS {out['measurement']['bias_rms_d']:.4f}")
    return out


def jitter(variant: str, n: int, sd_d: float, log) -> dict:
    """How much the map moves when the tiles move a little (as sweeps rendered again on another machine did): n
    replicates with every measured tile's peak moved by N(0, sd_d) D, each fitted as the calibration fits (the orders
    chosen by the CVs and blended, `model.fit_model`) and at the order the rule picks alone (the fit before the
    blend); the spread of the map's RMS within the tiles' radius over the replicates, and each replicate map's RMS
    difference from the unmoved tiles' (D)."""
    from aat_deploy.calibrate.fit import held_beyond_tiles
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import fit_model
    from benchmarks.probes import phone_map_model as M

    d = M.load(variant)
    meas = M.obs_of(d, "meas_")
    rad = field_radius_of(d["gx"], d["gy"], float(d["aspect"]))
    within = rad <= float(np.max(field_radius_of(meas.x, meas.y, float(d["aspect"]))))
    truth = d["truth"].astype(np.float64)

    def maps(o):
        f = fit_model(o)
        r = fit_model(o, f.degree, f.focus_degree, f.radial, f.low_focus_degree)
        out = []
        for g in (f, r):
            t = g.focus.true_diopters(d["reported_d"])
            out.append(t[:, None, None] + held_beyond_tiles(g.field, o)(d["gx"], d["gy"], t))
        return out

    base = maps(meas)
    rng = np.random.default_rng(0)
    rows = {"blended (the fit now)": [], "the rule's order alone (before)": []}
    for _ in range(n):
        o = replace(meas, reported_d=meas.reported_d + rng.normal(0, sd_d, len(meas)))
        for (name, acc), m, m0 in zip(rows.items(), maps(o), base):
            acc.append((float(np.sqrt(np.mean((m - truth)[:, within] ** 2))),
                        float(np.sqrt(np.mean((m - m0)[:, within] ** 2)))))
    out = {}
    for name, acc in rows.items():
        a = np.array(acc)
        out[name] = {"within_rms_d": a[:, 0].tolist(), "sd_d": float(np.std(a[:, 0])),
                     "range_d": [float(a[:, 0].min()), float(a[:, 0].max())],
                     "moved_rms_d": float(np.sqrt(np.mean(a[:, 1] ** 2)))}
        log(f"{variant} {name}: within {np.mean(a[:, 0]):.4f} D, SD {np.std(a[:, 0]):.4f}, range "
            f"{a[:, 0].min():.4f}-{a[:, 0].max():.4f}; the map moved {out[name]['moved_rms_d']:.4f} D RMS")
    return out


def table(res: dict) -> str:
    cols = ("measured tiles", "measured tiles, the rule's order alone", "exact tiles, the measured fit's order", "exact tiles, their own order",
            "propagated measurement", "exact tiles + systematic (chart x radius means)",
            "exact tiles + scatter about them", "measured tiles, every chart at its true distance",
            "measured tiles, weighted 1 / SD^2 by radius", "measured tiles, Tukey biweight")
    lines = ["RMS within the farthest tile's radius (D, part a's 10 inside settings):", "",
             "| variant | " + " | ".join(cols) + " | shares model / measurement / cross | tile bias RMS (mean) |",
             "|---|" + "---|" * (len(cols) + 2)]
    for v in res["variants"]:
        m, s = v["maps"], v["within_tiles_share"]
        lines.append(f"| {v['variant']} | " + " | ".join(f"{m[c]['within_tiles_rms_d']:.4f}" for c in cols)
                     + f" | {s['model']:.2f} / {s['propagated measurement']:.2f} / {s['cross term']:.2f} | "
                     f"{v['measurement']['bias_rms_d']:.3f} ({v['measurement']['bias_mean_d']:+.3f}) |")
    lines += ["", "| variant | map | " + " | ".join(RADIUS_EDGES_LABELS) + " |",
              "|---|---|" + "---|" * len(RADIUS_EDGES_LABELS)]
    for v in res["variants"]:
        for name, m in v["maps"].items():
            lines.append(f"| {v['variant']} | {name} | " + " | ".join(
                f"{m['radius_rms_d'][k]:.3f}" if k in m["radius_rms_d"] else "" for k in RADIUS_EDGES_LABELS) + " |")
    return "\n".join(lines)


RADIUS_EDGES_LABELS = [f"{lo:g}-{hi:g}" for lo, hi in zip(RADIUS_EDGES[:-1], RADIUS_EDGES[1:])]


def refuse(ap: argparse.ArgumentParser, a: argparse.Namespace) -> None:
    """One line and exit before any work: an existing --out (results are committed; a rerun must not replace them),
    unknown variants or estimators, no replicates or spread, and variants phone_map_model has not dumped."""
    from aat_deploy.focus.estimate import ESTIMATORS
    from benchmarks.probes.phone_map_model import CACHE

    if Path(a.out).exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    bad = [v for v in a.variants.split(",") if v not in VARIANTS]
    if bad:
        ap.error(f"--variants {','.join(bad)}: not among {', '.join(VARIANTS)}")
    bad = [e for e in a.estimators.split(",") if e and e not in ESTIMATORS]
    if bad:
        ap.error(f"--estimators {','.join(bad)}: not among {', '.join(ESTIMATORS)}")
    if a.jitter < 0 or not a.jitter_sd > 0:
        ap.error(f"--jitter: 0 or more replicates, --jitter-sd: above 0 D, got {a.jitter}, {a.jitter_sd}")
    missing = [v for v in a.variants.split(",") if not (CACHE / f"cellphone_near_{v}.npz").is_file()]
    if missing:
        ap.error(f"{CACHE}: no dump of {','.join(missing)} (run phone_map_model --dump --variants "
                 f"{','.join(missing)} first)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--estimators", default="parabola,ratio,argmax")
    ap.add_argument("--out", default=str(RESULTS / "within_tiles.json"))
    ap.add_argument("--jitter", type=int, default=0, metavar="N",
                    help="instead: N replicates of the tiles moved by --jitter-sd (`jitter`)")
    ap.add_argument("--jitter-sd", type=float, default=0.02, help="D of reported focus")
    a = ap.parse_args(argv)
    refuse(ap, a)
    log = lambda m: print(m, file=sys.stderr, flush=True)
    if a.jitter:
        from aat_deploy.io.atomic import write_text_atomic

        res = {"setup": "cellphone_near (development sweeps; no held-out scene)", "replicates": a.jitter,
               "sd_d": a.jitter_sd, "variants": {v: jitter(v, a.jitter, a.jitter_sd, log) for v in a.variants.split(",")}}
        write_text_atomic(Path(a.out), json.dumps(res, indent=1) + "\n")
        return 0
    ests = tuple(e for e in a.estimators.split(",") if e)
    res = {"setup": "cellphone_near (development sweeps; no held-out scene)",
           "variants": [run(v, ests, log) for v in a.variants.split(",")]}
    from aat_deploy.io.atomic import write_text_atomic

    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(a.out), json.dumps(res, indent=1, default=float) + "\n")
    print(table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
