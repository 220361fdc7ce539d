"""Which smooth model of the phone's best-focus surface "object in focus at sensor (x, y) for reported focus F" the
chart calibration should fit (issue 33, part a): driven by tiles made exactly from the truth ("ideal tiles",
`phone_map_budget`), where the current model is 0.107-0.110 D off though its tiles are exact, then checked on the
measured tiles of the same rendered development sweeps. No held-out scene is used; a model is chosen by
cross-validation over the sweep's own tiles, never by the truth.

    OMP_NUM_THREADS=1 python -m benchmarks.probes.phone_map_model --dump [--variants ...]   # 1-2 min per variant
    python -m benchmarks.probes.phone_map_model [--variants ...] [--out results/phone_map_model.json]  # 3 min
    python -m benchmarks.probes.phone_map_model --tried --variants copy,nominal    # the forms tried, 1 min

--dump measures bench_calibrate's `cellphone_near` sweeps (the softened chart, cached under cache/calibrate/), fits
them as part a does, and keeps per variant, in cache/mapmodel/ (a few MB): the fit's tiles (after its outlier
pass and with the near chart at its fitted distance), the same tiles peaking where the truth has their object in
focus, and the truth on a 4-px grid at part a's 10 "inside" settings. The second step fits each model form to
either set of tiles and scores it against the truth: overall, where the tiles measured the surface (inside the
hull of their (x, y, F)) and beyond, and by field radius.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks import RESULTS

ROOT = Path(__file__).resolve().parents[2]
CACHE = ROOT / "cache" / "mapmodel"
VARIANTS = ("nominal", "copy", "copy_s2026_0", "copy_s2026_1", "copy_s2026_2")
STRIDE = 4  # the truth's grid (px); the map is smooth, the RMS over it is the full grid's within 0.001 D
OBS_KEYS = ("x", "y", "reported_d", "object_d", "sweep", "cell")


def dump(variant: str, log) -> Path:
    from aat_deploy.calibrate.format import field_grid
    from aat_deploy.calibrate.model import Observations  # noqa: F401
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT
    from benchmarks.probes import phone_map_budget as P

    base = B.Rig(B.LENSES["cellphone_near"])
    rig, v = CT.rig_for(base, "soft leaves", variant)
    s = rig.setup
    eff = B.effects_for(s, v)
    scale = B.SCALE if any(e.startswith("focus_metadata") for e in eff) else 1.0
    sweeps = [B.sweep(rig, v, i, log) for i in range(len(s.distances_m))]
    res = B.fit(rig, v, sweeps, 0)
    res.sweeps_measured = res.measures
    obs = res.observations
    tiles = P.tile_table(res, rig, eff, scale)
    key = P.tile_key
    fit_kept = P.kept_tiles(tiles, obs)
    ideal = P.observations_of(tiles, fit_kept & np.isfinite(tiles["ideal_d"]), tiles["ideal_d"], rig.w / rig.h)
    inside = s.inside()
    truth = rig.truth(eff, inside)[:, ::STRIDE, ::STRIDE]
    sched = s.schedule()
    gx, gy = field_grid(rig.h, rig.w)
    out = {"truth": truth.astype(np.float32), "gx": gx[::STRIDE, ::STRIDE], "gy": gy[::STRIDE, ::STRIDE],
           "reported_d": 1.0 / (inside * scale), "true_d": 1.0 / inside, "aspect": rig.w / rig.h,
           "scale": scale, "fit_family": res.calibration.focus_error.family,
           "fit_order": np.array([res.model.degree, res.model.radial, res.model.focus_degree]),
           "sched_truth": rig.truth(eff, sched)[:, ::STRIDE, ::STRIDE].astype(np.float32),
           "sched_reported_d": 1.0 / (sched * scale)}
    for pre, o in (("meas_", obs), ("ideal_", ideal)):
        for k in OBS_KEYS:
            out[pre + k] = getattr(o, k)
    # per measured tile (benchmarks/probes/within_tiles.py): where the truth has its object in focus (reported D),
    # the truth's in-focus object for the frame of its measured peak, its grid row and column; per sweep the tiles'
    # focus curves and the frames' reported diopters (to try other peak estimators on the same curves)
    at = {key(tiles["sweep"][j], tiles["x"][j], tiles["y"][j]): j for j in np.flatnonzero(tiles["counted"])}
    j = np.array([at[key(*t)] for t in zip(obs.sweep, obs.x, obs.y)])
    out["meas_ideal_reported_d"] = tiles["ideal_d"][j]
    out["meas_truth_at_peak_d"] = P.truth_at_reported(tiles["truth_f"][:, j], obs.reported_d, scale)
    rows, cols = np.zeros(len(obs), np.int64), np.zeros(len(obs), np.int64)
    for i, m in enumerate(res.measures):
        gx_t, gy_t = m.peaks.grid.field()
        sel = np.flatnonzero(obs.sweep == i)
        for n in sel:
            r, c = np.unravel_index(np.argmin((gx_t - obs.x[n]) ** 2 + (gy_t - obs.y[n]) ** 2), gx_t.shape)
            rows[n], cols[n] = r, c
        out[f"curves_{i}"] = m.peaks.curves
        out[f"frames_d_{i}"] = m.peaks.reported_d
    out["meas_row"], out["meas_col"] = rows, cols
    out["tiles_radius_max"] = float(res.calibration.best_focus.radius_max)
    # each chart's distance as fitted (the tape's, or the fit's where it was an unknown) and as rendered, and the
    # entrance pupil assumed: what moving a chart to its true distance does to its tiles' objects (within_tiles)
    out["chart_m"] = np.array([m.chart_distance_m for m in res.measures])
    out["true_chart_m"] = np.array(s.distances_m, np.float64)
    out["pupil_mm"] = float(res.measures[0].geometry.pupil_to_sensor_mm)
    # a dense truth for the diagnosis: true focus 3-19.8 D (the focus table stops at 5 cm) on the diagonal and the horizontal axis
    fd = np.linspace(3.0, 19.8, 43)
    rr = np.linspace(0, 1, 41)
    for name, (cx, cy) in {"diag": (1.0, 1.0), "diag2": (-1.0, -1.0), "hor": (1.0, 0.0)}.items():
        out[f"dense_{name}"] = rig.truth_at(eff, rr * cx, rr * cy, 1.0 / fd)  # (F, R)
    out["dense_fd"], out["dense_r"] = fd, rr
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"cellphone_near_{variant}.npz"
    import io

    from aat_deploy.io.atomic import write_bytes_atomic

    buf = io.BytesIO()  # atomically: within_tiles reads these dumps, and a half-written one is not a dump
    np.savez_compressed(buf, **out)
    write_bytes_atomic(path, buf.getvalue())
    log(f"{variant}: {len(obs)} tiles, ideal {len(ideal)}, order {out['fit_order']}, {out['fit_family']} -> {path}")
    return path


def load(variant: str) -> dict:
    z = np.load(CACHE / f"cellphone_near_{variant}.npz")
    return {k: z[k] for k in z.files}


def obs_of(d: dict, pre: str):
    from aat_deploy.calibrate.model import Observations

    return Observations(*(d[pre + k].astype(np.int64 if k in ("sweep", "cell") else np.float64) for k in OBS_KEYS),
                        aspect=float(d["aspect"]))


RADIUS_EDGES = (0.0, 0.33, 0.5, 0.66, 0.75, 0.84, 0.9, 1.0)
MODELS = {"quadratic in focus (before)": {"edge_focus": False},
          "edge powers cubic where frame-cell CV wants it (now)": {}}


def scores(pred: np.ndarray, truth: np.ndarray, d: dict, r_max: float) -> dict:
    """RMS (D) overall, inside the counted tiles' farthest field radius (`best_focus.radius_max`: where tiles
    measured the surface) and beyond it (the field term held there), and by field radius."""
    from aat_deploy.calibrate.format import field_radius_of

    e = pred - truth
    rad = field_radius_of(d["gx"], d["gy"], float(d["aspect"]))
    rms = lambda m: float(np.sqrt(np.mean(e[:, m] ** 2))) if m.any() else None
    return {"rms_d": float(np.sqrt(np.mean(e ** 2))), "within_tiles_rms_d": rms(rad <= r_max),
            "beyond_tiles_rms_d": rms(rad > r_max), "beyond_share": float(np.mean(rad > r_max)),
            "radius_rms_d": {f"{lo:g}-{hi:g}": rms((rad >= lo) & ((rad < hi) if hi < 1 else (rad <= hi)))
                             for lo, hi in zip(RADIUS_EDGES[:-1], RADIUS_EDGES[1:])}}


def evaluate(variant: str, log) -> dict:
    from aat_deploy.calibrate.fit import held_beyond_tiles
    from aat_deploy.calibrate.model import fit_model

    d = load(variant)
    out = {"variant": variant, "tiles": {}}
    for pre, label in (("ideal_", "ideal tiles"), ("meas_", "measured tiles")):
        o = obs_of(d, pre)
        rows = {}
        for name, kw in MODELS.items():
            f = fit_model(o, **kw)
            fp = held_beyond_tiles(f.field, o)
            row = {"order": {"degree": f.degree, "radial": f.radial, "focus_degree": f.focus_degree,
                             "low_focus_degree": f.low_focus_degree}, "family": f.focus.family,
                   "edge_focus_cv": f.edge_cv, "residual_rms_d": float(np.sqrt(np.mean(f.residual_d ** 2)))}
            for part, (rep, truth) in {"inside": (d["reported_d"], d["truth"]),
                                        "schedule": (d["sched_reported_d"], d["sched_truth"])}.items():
                t = f.focus.true_diopters(rep)
                row[part] = scores(t[:, None, None] + fp(d["gx"], d["gy"], t), truth, d, fp.radius_max)
            # the diagnosis: truth and fit against focus at field radius 0.8 on the diagonal (x = y: the dense truth)
            fd, rr = d["dense_fd"], d["dense_r"]
            k = int(np.argmin(np.abs(rr - 0.8)))
            t = f.focus.true_diopters(fd / float(d["scale"]))
            row["diagonal_r0.8"] = {"radius": float(rr[k]), "true_focus_d": fd.tolist(),
                                    "truth_d": d["dense_diag"][:, k].tolist(),
                                    "fit_d": (t + fp(np.array([rr[k]]), np.array([rr[k]]), t)[:, 0]).tolist()}
            rows[name] = row
            log(f"{variant} {label} {name}: order {row['order']}, inside {row['inside']['rms_d']:.3f} "
                f"(within tiles {row['inside']['within_tiles_rms_d']:.3f}), schedule {row['schedule']['rms_d']:.3f}")
        out["tiles"][label] = rows
    return out


# -- the forms tried (--tried): fixed orders of the model's own basis, and radial splines ------------------------------
def _bspline(u: np.ndarray, inner: np.ndarray, lo: float, hi: float, k: int = 3) -> np.ndarray:
    """(N, nb) clamped cubic B-splines on [lo, hi] with inner knots, u clipped (held beyond)."""
    from scipy.interpolate import BSpline

    u = np.clip(u, lo, hi)
    t = np.r_[[lo] * (k + 1), inner, [hi] * (k + 1)]
    nb = len(t) - k - 1
    out = np.stack([np.nan_to_num(BSpline(t, np.eye(nb)[i], k, extrapolate=False)(u)) for i in range(nb)], 1)
    out[u >= hi, -1] = 1.0
    return out


def spline_fit(o, n_u: int, n_t: int, degree: int = 2, focus_degree: int = 2, t_range=(4.0, 19.0)):
    """The field term as B-splines in rho^2 (n_u intervals) times B-splines in the on-axis focus (n_t intervals),
    plus monomials to `degree` times Legendre polynomials to `focus_degree`, every column minus its value at the frame
    centre; the reported focus's family a scale (iterated as `model.fit_family`). Returns predict(x, y, rep_d)."""
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import FieldBasis

    fb = FieldBasis(degree, 0, o.aspect)
    a2 = o.aspect ** 2 / (1 + o.aspect ** 2)
    lo, hi = t_range

    def cols(x, y, t):
        def raw(x, y):
            u = a2 * x * x + (1 - a2) * y * y
            bu = _bspline(u, np.linspace(0, 1, n_u + 1)[1:-1], 0.0, 1.0)
            bt = _bspline(t, np.linspace(lo, hi, n_t + 1)[1:-1], lo, hi)
            leg = np.polynomial.legendre.legvander(np.clip(2 * (t - lo) / (hi - lo) - 1, -1, 1), focus_degree)
            return np.column_stack([(bu[:, :, None] * bt[:, None, :]).reshape(len(x), -1),
                                    (fb.columns(x, y)[:, :, None] * leg[:, None, :]).reshape(len(x), -1)])
        return raw(x, y) - raw(np.zeros_like(x), np.zeros_like(y))

    s = 1.0
    for _ in range(8):
        a = np.column_stack([o.reported_d, cols(o.x, o.y, s * o.reported_d)])
        sol, *_ = np.linalg.lstsq(a, o.object_d, rcond=None)
        if abs(sol[0] - s) < 1e-9:
            break
        s = float(sol[0])
    r_max = float(np.max(field_radius_of(o.x, o.y, o.aspect)))

    def predict(x, y, rep_d):
        r = field_radius_of(x, y, o.aspect)
        k = np.where(r > r_max, r_max / np.maximum(r, 1e-300), 1.0)
        xs, ys = (x * k).ravel(), (y * k).ravel()
        return np.stack([sol[0] * rd + (cols(xs, ys, np.full(xs.shape, sol[0] * rd)) @ sol[1:]).reshape(x.shape)
                         for rd in rep_d])
    return predict, r_max


TRIED_ORDERS = {"quadratic in focus (degree 3, rho^12)": (3, 12, 2, None),
                "the whole field term cubic in focus": (3, 12, 3, None),
                "the whole field term quartic in focus": (3, 12, 4, None),
                "edge powers cubic, the rest quadratic": (3, 12, 3, 2)}
TRIED_SPLINES = {"splines: 6 radial x 3 focus intervals + monomials 2": (6, 3),
                 "splines: 8 x 4": (8, 4), "splines: 12 x 6": (12, 6)}


def tried(variant: str, log) -> dict:
    from aat_deploy.calibrate.fit import held_beyond_tiles
    from aat_deploy.calibrate.model import fit_model

    d = load(variant)
    out = {}
    for pre, label in (("ideal_", "ideal tiles"), ("meas_", "measured tiles")):
        o = obs_of(d, pre)
        rows = {}
        for name, (deg, rad, fd, low) in TRIED_ORDERS.items():
            f = fit_model(o, deg, fd, rad, low)
            fp = held_beyond_tiles(f.field, o)
            row = {}
            for part, (rep, truth) in {"inside": (d["reported_d"], d["truth"]),
                                        "schedule": (d["sched_reported_d"], d["sched_truth"])}.items():
                t = f.focus.true_diopters(rep)
                row[part] = scores(t[:, None, None] + fp(d["gx"], d["gy"], t), truth, d, fp.radius_max)
            rows[name] = row
        if pre == "ideal_":
            for name, (nu, nt) in TRIED_SPLINES.items():
                pred, r_max = spline_fit(o, nu, nt)
                rows[name] = {part: scores(pred(d["gx"], d["gy"], rep), truth, d, r_max) for part, (rep, truth) in
                              {"inside": (d["reported_d"], d["truth"]),
                               "schedule": (d["sched_reported_d"], d["sched_truth"])}.items()}
        for name, r in rows.items():
            log(f"{variant} {label} {name}: inside {r['inside']['rms_d']:.3f}, schedule {r['schedule']['rms_d']:.3f}")
        out[label] = rows
    return out


def tried_table(res: dict) -> str:
    lines = ["| variant | tiles | form | inside RMS | within / beyond the tiles' radius | 0-0.33 / 0.33-0.5 / 0.5-0.66 / "
             "0.66-0.75 / 0.75-0.84 / 0.84-0.9 / 0.9-1 | schedule RMS |", "|---|---|---|---|---|---|---|"]
    for v, labels in res["tried"].items():
        for label, rows in labels.items():
            for name, r in rows.items():
                i = r["inside"]
                lines.append(f"| {v} | {label} | {name} | {i['rms_d']:.3f} | {i['within_tiles_rms_d']:.3f} / "
                             f"{i['beyond_tiles_rms_d']:.3f} | " + " / ".join(f"{x:.3f}" for x in i["radius_rms_d"].values())
                             + f" | {r['schedule']['rms_d']:.3f} |")
    return "\n".join(lines)


def table(res: dict) -> str:
    lines = ["| variant | tiles | model | order (degree, radial, focus, rest's focus) | residual (D) | inside RMS | "
             "within the tiles' radius / beyond | 0.66-0.75 / 0.75-0.84 / 0.84-0.9 / 0.9-1 | schedule RMS |",
             "|---|---|---|---|---|---|---|---|---|"]
    for v in res["variants"]:
        for label, rows in v["tiles"].items():
            for name, r in rows.items():
                o, i, rb = r["order"], r["inside"], r["inside"]["radius_rms_d"]
                lines.append(f"| {v['variant']} | {label} | {name} | {o['degree']}, {o['radial']}, {o['focus_degree']}, "
                             f"{o['low_focus_degree'] if o['low_focus_degree'] is not None else o['focus_degree']} | "
                             f"{r['residual_rms_d']:.3f} | {i['rms_d']:.3f} | {i['within_tiles_rms_d']:.3f} / "
                             f"{i['beyond_tiles_rms_d']:.3f} | " + " / ".join(f"{rb[b]:.3f}" for b in
                                                                             ("0.66-0.75", "0.75-0.84", "0.84-0.9", "0.9-1"))
                             + f" | {r['schedule']['rms_d']:.3f} |")
    for v in res["variants"]:
        if v["variant"] != "copy":
            continue
        for label, rows in v["tiles"].items():
            names = list(rows)
            d0 = rows[names[0]]["diagonal_r0.8"]
            fd, tr = np.array(d0["true_focus_d"]), np.array(d0["truth_d"])
            lines += ["", f"copy, {label}: in-focus object minus the frame's on-axis focus (D) at field radius "
                      f"{d0['radius']:.2f} on the diagonal, truth / " + " / ".join(names), "",
                      "| frame's true focus (D) | truth | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
            for i in range(0, len(fd), 4):
                lines.append(f"| {fd[i]:.1f} | {tr[i] - fd[i]:+.2f} | " + " | ".join(
                    f"{rows[k]['diagonal_r0.8']['fit_d'][i] - fd[i]:+.2f}" for k in names) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dump", action="store_true")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--tried", action="store_true", help="the forms tried, at fixed orders, and radial splines "
                    "(results/phone_map_model_tried.json with the default --out)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    log = lambda m: print(m, file=sys.stderr, flush=True)
    if a.dump:
        for v in a.variants.split(","):
            dump(v, log)
        return 0
    from aat_deploy.io.atomic import write_text_atomic

    if a.tried:
        out = Path(a.out or RESULTS / "phone_map_model_tried.json")
        res = {"setup": "cellphone_near", "tried": {v: tried(v, log) for v in a.variants.split(",")}}
        write_text_atomic(out, json.dumps(res, indent=1, default=float))
        print(tried_table(res))
        return 0
    a.out = a.out or str(RESULTS / "phone_map_model.json")
    res = {"setup": "cellphone_near", "chart": "dead leaves softened 0.7 px", "truth": "lenses/best_focus/cellphone_asphere.json",
           "variants": [evaluate(v, log) for v in a.variants.split(",")]}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(a.out), json.dumps(res, indent=1, default=float))
    print(table(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
