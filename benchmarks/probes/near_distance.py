"""Why the phone's near chart was fitted 0.75-0.9 mm long, and the fit's criterion for a fitted chart distance
(issue 33; docs/calibration.md, "The near chart's distance: the measured charts fix it").

    OMP_NUM_THREADS=1 python -m benchmarks.probes.near_distance --truth results/render_truth_map_cellphone_19p.json \
        [--variants nominal,copy,copy_s2026_0,copy_s2026_1,copy_s2026_2] --out results/near_distance.json

bench_calibrate's `cellphone_near` development sweeps (the nominal lens, the hand-chosen copy, the declared random
copies of seed 2026; no held-out scene), measured with the tapes as part a measures them. Per variant:

- **joint**: the near chart's distance as the fit found it until 2026-11-28 (an unknown of the joint least squares,
  Gauss-Newton: `model.distance_columns`), with the focus-error family as BIC chooses it, forced to each family,
  and replaced by the truth's own on-axis curve (the in-focus object at the frame centre for each reported focus,
  family `none` on it, or an offset or scale on top): whether the distance trades against the family;
- **parts**: the joint shift (linearised from the rendered 55.0 mm, the fit's order and family) split exactly into
  what each chart's tape error and each chart's tiles' measurement error (by field radius) contribute, from the
  tiles made exact (each tile's object the truth's in-focus object for its measured peak); the least squares is
  linear in the objects, so the parts add up to the whole; the same for the fit's criterion now
  (`model.profile_shifts`: the parabola's minimum is linear in the objects too);
- **profile**: the near chart fixed at distances 54.4-56.4 mm, the model refitted at the fit's order and family:
  the weighted squared residuals of the measured charts' tiles and of the near chart's own, and part a;
- **fit**: `fit_calibration` as it now is (the distance where the measured charts' tiles fit best,
  `model.profile_shifts`): the near chart's distance, part a (inside, 7-18 cm; render truth) and its family.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks.probes.tile_bias import VARIANTS, chosen_variants

EDGES = (0.0, 0.33, 0.5, 0.66, 0.75, 0.84, 0.93)
PROFILE_MM = tuple(np.round(np.arange(54.4, 56.41, 0.2), 1))


@contextlib.contextmanager
def families(names):
    """The model's families limited to `names` (None: as they are)."""
    from aat_deploy.calibrate import model as M

    old = M.families_for
    if names is not None:
        M.families_for = lambda obs: tuple(names)
    try:
        yield
    finally:
        M.families_for = old


def joint_distances(measures, obs, fit, start: dict, g=None, fams=None, iterations: int = 8):
    """The fit's loop until 2026-11-28: the joint least squares' shift of each fitted chart (Gauss-Newton, objects
    recomputed at the new distance), at `fit`'s order; g: the on-axis truth (a FocusError read first, family none)."""
    from aat_deploy.calibrate.fit import FITTED, _same_tiles, observations
    from aat_deploy.calibrate.model import refit

    f = None
    for _ in range(iterations):
        o = obs if g is None else dataclasses.replace(obs, reported_d=g.true_diopters(obs.reported_d))
        with families(fams):
            f = refit(o, fit)
        if max(abs(v) for v in f.shifts_mm.values()) < 1e-4:
            break
        measures = [m.at_distance(m.chart_distance_m + f.shifts_mm.get(i, 0.0) / 1000.0, FITTED) if i in start
                    else m for i, m in enumerate(measures)]
        obs = _same_tiles(observations(measures), obs)
    return measures, obs, f


def shift_parts(obs_true, exact: np.ndarray, tape_err: np.ndarray, meas_err: np.ndarray, radius: np.ndarray,
                shift_of) -> dict:
    """The linear split of a fitted shift: shift_of(objects) at the exact objects, and what each sweep's tape error
    and each (sweep, radius bin)'s measurement error add to it alone. The sum of the parts is returned beside the
    shift of all errors together (equal where shift_of is linear in the objects)."""
    base = shift_of(exact)
    out = {"exact": base, "all": shift_of(exact + tape_err + meas_err), "tape": {}, "measurement": {}}
    total = 0.0
    for s in np.unique(obs_true.sweep):
        sel = obs_true.sweep == s
        v = shift_of(exact + np.where(sel, tape_err, 0.0)) - base
        out["tape"][int(s)] = v
        total += v
        row = {}
        for lo, hi in zip(EDGES[:-1], EDGES[1:]):
            b = sel & (radius >= lo) & (radius < hi)
            if not b.any():
                continue
            v = shift_of(exact + np.where(b, meas_err, 0.0)) - base
            row[f"{lo:g}-{hi:g}"] = {"shift_mm": v, "tiles": int(b.sum()), "mean_error_d": float(np.mean(meas_err[b]))}
            total += v
        out["measurement"][int(s)] = row
    out["sum_of_parts"] = total + base
    return out


def truth_curve(rig, eff, scale: float):
    """The truth's on-axis curve as a FocusError (reported -> the in-focus object at the frame centre)."""
    from aat_deploy.calibrate.format import FocusError

    rgrid = np.linspace(0.5, 18.0, 351)
    gt = rig.truth_at(eff, [0.0], [0.0], 1.0 / (rgrid * scale))[:, 0]
    return FocusError("monotone", map_d=tuple(float(x) for p in zip(rgrid, np.maximum.accumulate(gt)) for x in p))


def run(variant: str, truth_path: str, log) -> dict:
    from aat_deploy.calibrate.fit import FITTED, _same_tiles, held_beyond_tiles, observations
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import profile_shifts, refit
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT
    from benchmarks.probes import phone_map_budget as P

    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"], truth=truth_path), "soft leaves", variant)
    s = rig.setup
    eff, scale, sweeps, ms, res = P.development_fit(rig, v, log)
    near = s.fit_distance[0]
    start = {near: ms[near].chart_distance_m}
    inside = s.inside()

    def part_a(focus, field, o) -> dict:
        cal = dataclasses.replace(res.calibration, focus_error=focus, best_focus=held_beyond_tiles(field, o))
        e = B.map_errors(rig, cal, eff, inside)["calibration"]
        return {"rms_d": e["rms_d"], "p95_d": e["p95_d"], "within_tiles_rms_d": e["within_tiles_rms_d"]}

    out = {"variant": variant, "rendered_mm": 1000 * s.distances_m[near], "tape_start_mm": 1000 * start[near],
           "fit": {"near_mm": 1000 * res.measures[near].chart_distance_m, **part_a(res.calibration.focus_error,
                                                                                   res.model.field,
                                                                                   res.observations),
                   "family": res.calibration.focus_error.family}}
    log(f"{variant} fit (profile): near {out['fit']['near_mm']:.3f} mm, part a {out['fit']['rms_d']:.4f} D")
    # the joint least squares from the fit's start (its order), as the fit was until 2026-11-28
    first = [m.at_distance(start[near], FITTED) if i == near else m for i, m in enumerate(res.measures)]
    obs = _same_tiles(observations(first), res.observations)
    mj, oj, fj = joint_distances(first, obs, res.model, start)
    fam = fj.focus.family
    g = truth_curve(rig, eff, scale)
    out["joint"] = {}
    for name, fams, gg in (("as BIC chooses", None, None), ("none", ["none"], None), ("offset", ["offset"], None),
                           ("scale", ["scale"], None), ("monotone", ["monotone"], None),
                           ("the truth's on-axis curve", ["none"], g), ("the truth's curve + offset", ["offset"], g),
                           ("the truth's curve x scale", ["scale"], g)):
        m2, o2, f2 = joint_distances(first, obs, res.model, start, gg, fams)
        focus = f2.focus if gg is None else gg
        out["joint"][name] = {"near_mm": 1000 * m2[near].chart_distance_m, **part_a(focus, f2.field, o2),
                              "family": f2.focus.family}
        log(f"{variant} joint, family {name}: near {out['joint'][name]['near_mm']:.3f} mm, part a "
            f"{out['joint'][name]['rms_d']:.4f} D")
    # the joint shift split into its parts (linearised from the rendered distances, the joint fit's family)
    true_ms = [m.at_distance(d, FITTED) for m, d in zip(res.measures, s.distances_m)]
    o_true = _same_tiles(observations(true_ms), res.observations)
    o_tape = _same_tiles(observations([m if i == near else first[i] for i, m in enumerate(true_ms)]),
                         res.observations)
    exact = P.truth_at_reported(rig.truth_at(eff, o_true.x, o_true.y, 1.0 / P.F_GRID_D), o_true.reported_d, scale)
    radius = field_radius_of(o_true.x, o_true.y, o_true.aspect)
    out["parts"] = {}
    for name, gg, fams in (("the joint fit's family", None, [fam]), ("the truth's on-axis curve", g, ["none"]),
                           ("the profile (the fit now)", None, None)):
        def shift_of(obj, gg=gg, fams=fams, profile=fams is None):
            o = dataclasses.replace(o_true, object_d=obj)
            if profile:  # `profile_shifts` at the fit's order and family: linear in the objects too
                return profile_shifts(o, res.model)[near]
            if gg is not None:
                o = dataclasses.replace(o, reported_d=gg.true_diopters(o.reported_d))
            with families(fams):
                return refit(o, res.model).shifts_mm[near]

        out["parts"][name] = shift_parts(o_true, exact, o_tape.object_d - o_true.object_d,
                                         o_true.object_d - exact, radius, shift_of)
        p = out["parts"][name]
        log(f"{variant} parts ({name}): all {p['all']:+.3f} mm, exact {p['exact']:+.3f}, sum of parts "
            f"{p['sum_of_parts']:+.3f}; near chart's tiles at 0.5-0.75 "
            f"{sum(p['measurement'][near][b]['shift_mm'] for b in ('0.5-0.66', '0.66-0.75')):+.3f}")
    # the profile along the near chart's distance (the joint fit's family)
    prof = []
    for zmm in PROFILE_MM:
        mz = [m.at_distance(zmm / 1000, FITTED) if i == near else m for i, m in enumerate(first)]
        o = dataclasses.replace(_same_tiles(observations(mz), res.observations), dz=None)
        with families([fam]):
            f = refit(o, res.model)
        r2 = o.weight * f.residual_d ** 2
        prof.append({"near_mm": float(zmm), "measured_rss": float(r2[o.sweep != near].sum()),
                     "near_rss": float(r2[o.sweep == near].sum()),
                     "per_chart_rss": [float(r2[o.sweep == k].sum()) for k in range(len(first))],
                     "part_a_rms_d": part_a(f.focus, f.field, o)["rms_d"]})
    out["profile"] = prof
    for key in ("measured_rss", "near_rss", "part_a_rms_d"):
        out[f"profile_min_{key}"] = parabola_min([p["near_mm"] for p in prof], [p[key] for p in prof])
    log(f"{variant} profile minima: measured charts {out['profile_min_measured_rss']:.3f}, near chart "
        f"{out['profile_min_near_rss']:.3f}, part a {out['profile_min_part_a_rms_d']:.3f} mm")
    return out


def parabola_min(x, y) -> float:
    """The minimum of the parabola through the least sampled value and its neighbours (an end: that end)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    k = int(np.argmin(y))
    if k in (0, len(y) - 1):
        return float(x[k])
    c = np.polyfit(x[k - 1:k + 2], y[k - 1:k + 2], 2)
    return float(-c[1] / (2 * c[0]))


def table(rows: list[dict]) -> str:
    out = ["| variant | fit: near (mm) / part a (D) | joint, BIC: near / part a | joint, the truth's on-axis curve: "
           "near / part a | profile minimum: measured charts / near chart / part a (mm) |", "|---|---|---|---|---|"]
    for r in rows:
        j, t = r["joint"]["as BIC chooses"], r["joint"]["the truth's on-axis curve"]
        out.append(f"| {r['variant']} | {r['fit']['near_mm']:.3f} / {r['fit']['rms_d']:.4f} | {j['near_mm']:.3f} / "
                   f"{j['rms_d']:.4f} | {t['near_mm']:.3f} / {t['rms_d']:.4f} | {r['profile_min_measured_rss']:.3f} / "
                   f"{r['profile_min_near_rss']:.3f} / {r['profile_min_part_a_rms_d']:.3f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--truth", required=True, help="a render-truth map (aat-render-truth-map-v1; a repo path)")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    if Path(a.out).exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    variants = chosen_variants(ap, a.variants)
    from benchmarks.render_truth_map import load_or_exit

    load_or_exit(a.truth, "near_distance")
    log = lambda m: print(m, file=sys.stderr, flush=True)
    rows = [run(v, a.truth, log) for v in variants]
    write_text_atomic(a.out, json.dumps({"what": __doc__.split("\n")[0], "truth": a.truth, "command":
                                         "python -m benchmarks.probes.near_distance " + " ".join(
                                             argv if argv is not None else sys.argv[1:]), "rows": rows},
                                        indent=1, default=float))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
