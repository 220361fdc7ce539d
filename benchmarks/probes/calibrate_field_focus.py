"""Do chart sweeps rendered with focus varying over the field peak where the focus function says (exploratory)?

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.calibrate_field_focus [--lens paper50] [--effect sensor_tilt]
        [--distance 3]

One chart sweep of benchmarks/bench_calibrate.py (its chart, pose, sweep and noise seed) rendered twice by the
virtual camera: nominal (noise only) and with one of the copy's effects alone (`sensor_tilt` or `lens_tolerance`,
the copy's settings, plus noise). Per tile, where the focus curve peaks (`aat_deploy.calibrate.sweep`) in both; the
peak's move (nominal minus with-effect, true diopters) against the move the effect's focus function predicts
(`effects.focus_at` at the tile, for the sweep's mean peak focus), by field region; and the benchmark's truth at the
measured peak minus the tile's object diopters. Renders are not cached (15-60 s per sweep). This is how the renderer's
per-anchor cell size defect (fixed in c9c07bd) was found: with it, at x > 0.5 the tilt's peaks stayed put.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks import bench_calibrate as B


def render(rig: B.Rig, effects: list[str], index: int) -> dict:
    """The bench's sweep `index` rendered with `effects` (not cached)."""
    from aat_deploy.calibrate.pose import ChartPose
    from aat_deploy.calibrate.scene import chart_scene
    from aat_deploy.capture.virtual import shoot

    s = rig.setup
    d, (tx, ty) = s.distances_m[index], s.tilts[index]
    img, layout = B.chart_for(rig, d)
    rgb, depth = chart_scene(img, layout, ChartPose(d, tx, ty), rig.w, rig.h, rig.f_px, rig.pupil)
    fd = B.sweep_diopters(rig, float((1 / depth).max()), float((1 / depth).min()))
    frames, reported = shoot(rig.lens, rgb * 0.6, depth, 1.0 / fd, effects, rig.src, seed=1000 + index, workers=2)
    return {"frames": frames, "reported_m": reported, "true_m": 1.0 / fd, "layout": layout, "distance_m": d}


def main(argv: list[str] | None = None) -> int:
    from aat_deploy.render import effects as fx

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", choices=sorted(B.LENSES), default="paper50")
    ap.add_argument("--effect", choices=("sensor_tilt", "lens_tolerance"), default="sensor_tilt")
    ap.add_argument("--distance", type=float, default=3.0, help="one of the setup's chart distances (m)")
    a = ap.parse_args(argv)
    rig = B.Rig(B.LENSES[a.lens])
    i = list(rig.setup.distances_m).index(a.distance)
    one = [e for e in B.effects_for(rig.setup, "copy") if e.startswith(a.effect)]
    nom, eff = render(rig, ["noise"], i), render(rig, one + ["noise"], i)
    mn, me = B.measures(rig, [nom], "nominal")[0], B.measures(rig, [eff], a.effect)[0]
    ok = mn.peaks.counted & me.peaks.counted
    x, y = mn.peaks.grid.field()
    fn = fx.focus_at(fx.parse(one), rig.ctx())
    f_mean = float(np.nanmean(me.peaks.peak_d[ok]))
    predicted = 1.0 / fn(x, y, 1.0 / f_mean) - f_mean  # the effect focuses the tile nearer by this (D)
    moved = mn.peaks.peak_d - me.peaks.peak_d
    truth = mn.peaks.grid.mean(rig.truth(one, eff["true_m"]))  # (S, ny, nx) in focus per frame
    at_peak = np.full(ok.shape, np.nan)
    for j, k in zip(*np.nonzero(me.peaks.counted)):
        at_peak[j, k] = np.interp(me.peaks.peak_d[j, k], me.peaks.reported_d, truth[:, j, k])
    err = at_peak - me.object_d
    print(f"{a.lens}, {one[0]}, chart at {a.distance:g} m: {int(ok.sum())} tiles counted in both sweeps")
    print("| field | tiles | peak moved (D) | focus function says (D) | truth at the peak - object (D) |")
    print("|---|---|---|---|---|")
    for name, sel in (("x < -0.5", x < -0.5), ("|x| < 0.2", np.abs(x) < 0.2), ("x > 0.5", x > 0.5), ("all", x == x)):
        m = ok & sel
        print(f"| {name} | {int(m.sum())} | {moved[m].mean():+.4f} | {predicted[m].mean():+.4f} | "
              f"{np.nanmean(err[m & me.peaks.counted]):+.4f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
