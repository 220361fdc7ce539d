"""Why the chart calibration read a +1 D reported-focus offset on the nominal phone lens (issue 33), and what a
chart sweep can measure at a phone's scale (1.26 px of blur per diopter).

    python -m benchmarks.probes.calibrate_phone_offset [--out results/calibrate_phone_offset.json]   # ~3 min

On bench_calibrate's cached nominal phone sweeps (charts at 7, 10 and 18 cm; `--lenses cellphone --parts map`
renders them) and its traced best-focus map, one candidate at a time:

1. **distance**: every counted tile's object diopters as the fit computes them (the tape distance, 2 mm SD as in
   the benchmark, and the markers' homography, the entrance pupil assumed) against the rendered chart's depth;
2. **peaks**: where the centre tiles' (field radius < 0.08) focus curves peak, in reported diopters minus the
   object's, against the same measured on axis with a dense sweep (0.1 D steps) of four textures (point 4);
3. **the model**: the fit (`aat_deploy.calibrate.model.fit_model`) on the measured tiles, and on tiles made from
   the traced map itself (each tile's peak where the map has its object in focus: no noise, no measurement), with
   the field term of monomials only (`radial=0`, the model before the radial powers, order by cross-validation as
   it was) and with the radial powers; its offset and its error at the frame centre;
4. **the floor at phone scale**: on axis and at field radius 0.75 (on the diagonal), where the focus measure (the
   runtime's) peaks for the chart's dead leaves and three photographs, with a dense sweep and with the chart
   sweeps' step (1.1 D, ten phases, the `gauss` estimator); the focus curve's width. The same for the RF50 at its
   scale (the same pixels of blur);
5. **the tiles against the benchmark's truth** (the calibrated map, lenses/best_focus/: where the measure peaks on
   photo textures): every counted tile's peak minus the truth's peak for its object, by field zone;
6. with `--truth-noise`: the calibrated map's own texture noise, its calibration points made twice with other
   photo textures (3 per point, the default; 2 x 1.5 min) and compared point by point;
7. with `--step-px S`: the nominal sweeps rendered again S px of blur apart (bench_calibrate's are 1.4 px, 1.1 D;
   cached under cache/phone_offset/), fitted, and the map's RMS error by field zone beside the benchmark's
   sweeps' (1 min): whether the chart sweep's step limits the map.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import RESULTS
from benchmarks import bench_calibrate as bc

CENTRE_R = 0.08


def rendered_depth(rig, i: int) -> np.ndarray:
    from aat_deploy.calibrate.pose import ChartPose
    from aat_deploy.calibrate.scene import chart_scene

    s = rig.setup
    img, layout = bc.chart_for(rig, s.distances_m[i])
    _, depth = chart_scene(img, layout, ChartPose(s.distances_m[i], *s.tilts[i]), rig.w, rig.h, rig.f_px, rig.pupil)
    return depth.astype(np.float64)


def part_distance_and_peaks(rig, ms) -> list[dict]:
    r = rig.fmap.radius_px(rig.h, rig.w).astype(np.float64)
    rows = []
    for i, m in enumerate(ms):
        g = m.peaks.grid
        ok = m.peaks.counted
        true_d = g.mean(1.0 / rendered_depth(rig, i))
        e = (m.object_d - true_d)[ok]
        centre = ok & (g.mean(r) < CENTRE_R)
        pk = (m.peaks.peak_d - true_d)[centre]
        rows.append({"chart_m": rig.setup.distances_m[i], "tiles": int(ok.sum()),
                     "object_error_mean_d": float(e.mean()), "object_error_rms_d": float(np.sqrt(np.mean(e ** 2))),
                     "object_error_max_d": float(np.abs(e).max()), "centre_tiles": int(centre.sum()),
                     "centre_peak_minus_object_d": float(pk.mean()), "centre_peak_sd_d": float(pk.std())})
    return rows


def map_made_observations(rig, ms, obs):
    """The same tiles with their peak where the traced map has their object in focus (no noise)."""
    from aat_deploy.calibrate.model import Observations

    r = rig.fmap.radius_px(rig.h, rig.w).astype(np.float64)
    rad = np.concatenate([m.peaks.grid.mean(r)[m.peaks.counted] for m in ms])
    f_grid = np.linspace(0.3, 25.0, 4000)
    t = rig.fmap.frame_diopters(1.0 / f_grid, rad, calibrated=False)  # (F, N): the traced, round field
    peak = np.array([np.interp(obs.object_d[j], t[:, j], f_grid) for j in range(len(obs))])
    return Observations(obs.x, obs.y, peak, obs.object_d, obs.sweep, obs.cell, aspect=obs.aspect)


def part_model(rig, obs, made) -> list[dict]:
    from aat_deploy.calibrate.model import fit_model

    rows = []
    for name, o in (("measured tiles", obs), ("tiles made from the traced map", made)):
        for label, radial in (("monomials only (before)", 0), ("with radial powers", None)):
            t0 = time.time()
            f = fit_model(o, radial=radial)
            centre = float(f.predict(0.0, 0.0, 10.0) - rig.fmap.frame_diopters([0.1], [0.0], calibrated=False)[0, 0])
            rows.append({"tiles": name, "model": label, "degree": f.degree, "radial": f.radial,
                         "focus_degree": f.focus_degree, "family": f.focus.family, "offset_d": f.focus.bias_d,
                         "scale": f.focus.scale,
                         "offset_fit_d": float(f.fits["offset"][0].bias_d) if "offset" in f.fits else None,
                         "residual_rms_d": float(np.sqrt(np.mean(f.residual_d ** 2))),
                         "centre_error_at_10d": centre, "seconds": round(time.time() - t0, 1)})
            print(f"  {name}, {label}: degree {f.degree} radial {f.radial}, {f.focus.family} offset "
                  f"{f.focus.bias_d:+.3f} D, centre {centre:+.3f} D", file=sys.stderr, flush=True)
    return rows


def peak_log(x: np.ndarray, m: np.ndarray) -> float:
    from training.render.focus_calibration import _peak_log

    return _peak_log(x, m)


def floor_stacks(key: str, object_m: float, half_px: float = 5.0, radius: float = 0.0, photos: int = 3,
                 cache: Path | None = None) -> tuple:
    """(rig, fd (F,) focus diopters, {texture: frames (F, 3, n, n)}): a patch at field radius `radius` on the
    diagonal (0: on axis) with the object at object_m, rendered through the lens's surrogate over a dense sweep
    +-half_px of blur about it, for the chart's dead leaves and `photos` training photographs (seeded). With
    `cache`, the frames are kept there (an .npz per setting) and read back."""
    import torch

    from aat_deploy.calibrate.pose import ChartPose
    from aat_deploy.calibrate.scene import chart_scene
    from aat_deploy.render import effects as fx
    from training.data.textures import photo_texture
    from training.render.layered import LayeredConfig
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF

    rig = bc.Rig(bc.LENSES[key])
    half_d = half_px / rig.blur_px_per_d
    fd = 1.0 / object_m + np.linspace(-half_d, half_d, 101)
    f = cache / f"floor_{key}_{object_m:g}m_r{radius:g}_{half_px:g}px_{photos}.npz" if cache else None
    if f is not None and f.exists():
        z = np.load(f)
        return rig, z["fd"], {k[4:]: z[k] for k in z.files if k.startswith("tex_")}
    torch.set_num_threads(1)
    sim = Simulator(rig.lens, OnnxPSF.from_source(rig.src), fx.parse(["aberrations"]), LayeredConfig(cell_px=32))
    n = 112
    origin = (int(round((1 - radius) / 2 * rig.h - n / 2)), int(round((1 + radius) / 2 * rig.w - n / 2)))
    img, layout = bc.chart_for(rig, object_m)
    # the chart's texture at its scale, a marker-free part of it on the axis
    rgb, _ = chart_scene(img, layout, ChartPose(object_m, axis_point_mm=(0.07 * object_m * 1000, 0.05 * object_m *
                                                                          1000)), rig.w, rig.h, rig.f_px, rig.pupil)
    textures = {"chart": rgb[:, origin[0]:origin[0] + n, origin[1]:origin[1] + n]}
    rng = np.random.default_rng(5)
    for i in range(photos):
        textures[f"photo {i}"] = photo_texture(rng, n, n, "train").transpose(2, 0, 1).astype(np.float32)
    stacks = {}
    for name, tex in textures.items():
        st = sim.render_stack(torch.from_numpy(np.ascontiguousarray(tex)), torch.full((n, n), object_m), 1.0 / fd,
                              origin=origin, rng=np.random.default_rng(0))
        stacks[name] = st.frames.numpy()
    if f is not None:
        f.parent.mkdir(parents=True, exist_ok=True)
        tmp = f.with_name(f.stem + ".tmp.npz")
        np.savez(tmp, fd=fd, **{f"tex_{k}": v for k, v in stacks.items()})
        tmp.replace(f)
    return rig, fd, stacks


def floor_peaks(rig, fd: np.ndarray, stacks: dict, object_m: float, coarse_px: float = 1.39,
                measure: str | None = None, levels: int = 3, prefilter_px: float | None = None,
                margin: int = 24) -> dict:
    """Where `measure` (the runtime's by default, its window and pre-filter unless given) peaks on each texture's stack of
    `floor_stacks`, in diopters from the object: dense, and at the chart sweeps' step (10 phases, the `gauss`
    estimator); the curve's width at half its height; the spread between textures (max - min, and SD)."""
    from aat_deploy.focus import FocusConfig
    from aat_deploy.focus.estimate import estimate_peak
    from aat_deploy.focus.measures import focus_volume

    cfg = FocusConfig()
    measure = measure or cfg.measure
    prefilter_px = cfg.prefilter_px if prefilter_px is None else prefilter_px
    step_d = coarse_px / rig.blur_px_per_d
    out = {"measure": measure, "levels": levels, "prefilter_px": prefilter_px, "blur_px_per_d": rig.blur_px_per_d,
           "dense_step_d": float(fd[1] - fd[0]), "coarse_step_d": step_d, "textures": {}}
    for name, fr in stacks.items():
        n = fr.shape[-1]
        vol = focus_volume(fr / max(float(fr.max()), 1e-12), measure, cfg.window_px, levels=levels,
                           prefilter_px=prefilter_px)
        curve = vol[:, margin:n - margin, margin:n - margin].mean((1, 2)).astype(np.float64)
        coarse = []
        for ph in np.linspace(0, step_d, 10, endpoint=False):
            xs = np.arange(fd[0] + ph, fd[-1], step_d)
            ys = np.interp(xs, fd, curve)
            pk = estimate_peak(ys[:, None, None].astype(np.float32), xs.astype(np.float32), None, "gauss")
            coarse.append(float(pk.diopters[0, 0]) - 1.0 / object_m)
        half = fd[curve >= 0.5 * curve.max()]
        out["textures"][name] = {"dense_peak_d": peak_log(fd, curve) - 1.0 / object_m,
                                 "coarse_mean_d": float(np.mean(coarse)), "coarse_min_d": float(min(coarse)),
                                 "coarse_max_d": float(max(coarse)), "half_max_width_d": float(half.max() - half.min())}
    dense = np.array([v["dense_peak_d"] for v in out["textures"].values()])
    out["dense_spread_d"] = float(dense.max() - dense.min())
    out["dense_sd_d"] = float(dense.std(ddof=1)) if len(dense) > 1 else float("nan")
    out["dense_spread_px"] = out["dense_spread_d"] * rig.blur_px_per_d
    return out


def part_floor(key: str, object_m: float, half_px: float = 5.0, coarse_px: float = 1.39, radius: float = 0.0
               ) -> dict:
    """At field radius `radius` on the diagonal (0: on axis): the measure's peak (D from the object) per texture,
    dense and at the chart sweeps' step."""
    rig, fd, stacks = floor_stacks(key, object_m, half_px, radius)
    return {"lens": key, "object_m": object_m, "radius": radius, **floor_peaks(rig, fd, stacks, object_m, coarse_px)}


ZONES = ((0.0, 0.33), (0.33, 0.66), (0.66, 0.9), (0.9, 1.01))


def part_tiles_vs_truth(rig, ms, zones=ZONES) -> list[dict]:
    """Per chart and field zone ((lo, hi) field radii): measured tile peak minus the calibrated truth's peak for the
    tile's object (D)."""
    r = rig.fmap.radius_px(rig.h, rig.w).astype(np.float64)
    f_grid = np.linspace(0.3, 25.0, 4000)
    rows = []
    for i, m in enumerate(ms):
        g = m.peaks.grid
        ok = m.peaks.counted
        rt = g.mean(r)[ok]
        true_d = g.mean(1.0 / rendered_depth(rig, i))[ok]
        t = rig.fmap.frame_diopters(1.0 / f_grid, rt)  # (F, N) the calibrated map
        peak = np.array([np.interp(true_d[j], t[:, j], f_grid) for j in range(len(rt))])
        e = m.peaks.peak_d[ok] - peak
        for lo, hi in zones:
            z = (rt >= lo) & (rt < hi)
            if z.any():
                rows.append({"chart_m": rig.setup.distances_m[i], "zone": [lo, hi], "tiles": int(z.sum()),
                             "mean_d": float(e[z].mean()), "sd_d": float(e[z].std()),
                             "rms_d": float(np.sqrt(np.mean(e[z] ** 2)))})
    return rows


def part_truth_noise(rig) -> dict:
    """The calibrated map's points made again with two other draws of photo textures (its command's settings)."""
    from training.render.focus_calibration import CalibrationConfig, calibrate

    c = rig.fmap.notes["calibration"]
    pts = []
    for seed in (1, 2):
        cfg = CalibrationConfig(psf=c["psf"], focus_m=tuple(c["focus_m"]), sweep_d=c["sweep_d"],
                                radii=tuple(c["radii"]), seed=seed)
        pts.append(np.array([p["offset_diopters"] for p in calibrate(rig.lens, rig.fmap, cfg, progress=False)[1]]))
    d = pts[0] - pts[1]
    radii = np.tile(np.array(c["radii"]), len(c["focus_m"]))
    ok = np.isfinite(d)
    return {"textures_per_point": CalibrationConfig().n_textures, "points": int(ok.sum()),
            "diff_rms_d": float(np.sqrt(np.mean(d[ok] ** 2))),
            "diff_rms_axis_d": float(np.sqrt(np.mean(d[ok & (radii == 0)] ** 2))),
            "diff_rms_off_axis_d": float(np.sqrt(np.mean(d[ok & (radii > 0)] ** 2)))}


def part_step(step_px: float, **rig_kw) -> dict:
    """The nominal map's RMS error by zone (inside the charts' range) from sweeps step_px apart and from the
    benchmark's. rig_kw: bench_calibrate.Rig's truth_map / measure / prefilter_px (another measure's fit)."""
    from aat_deploy.optics.focus_table import diopter_grid

    out = {}
    for label, step in (("benchmark", bc.SWEEP_STEP_PX), ("denser", step_px)):
        rig = bc.Rig(bc.LENSES["cellphone"], **rig_kw)
        saved = bc.SWEEP_STEP_PX, bc.CACHE
        bc.SWEEP_STEP_PX = step
        if label == "denser":
            bc.CACHE = bc.ROOT / "cache" / "phone_offset" / f"sweeps_{step:g}px"
        try:
            sw = [bc.sweep(rig, "nominal", i, lambda m: print(m, file=sys.stderr)) for i in range(3)]
            res = bc.fit(rig, "nominal", sw, 10)
        finally:
            bc.SWEEP_STEP_PX, bc.CACHE = saved
        s = rig.setup
        e = bc.map_errors(rig, res.calibration, bc.effects_for(s, "nominal"),
                          diopter_grid(max(s.distances_m), min(s.distances_m), 10))["calibration"]
        out[label] = {"step_px": step, "step_d": step / rig.blur_px_per_d, "measure": rig.measure,
                      "prefilter_px": rig.prefilter_px, "residual_rms_d": res.calibration.residuals["rms_d"],
                      "frames": [len(x["reported_m"]) for x in sw], "family": res.calibration.focus_error.family,
                      "rms_d": e["rms_d"], "zone_rms_d": e["zone_rms_d"]}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(RESULTS / "calibrate_phone_offset.json"))
    ap.add_argument("--truth-noise", action="store_true", help="also make the calibrated map's points again (3 min)")
    ap.add_argument("--step-px", type=float, default=None, help="also fit nominal sweeps this many px apart (1 min)")
    a = ap.parse_args(argv)
    from aat_deploy.calibrate.fit import observations

    rig = bc.Rig(bc.LENSES["cellphone"])
    sweeps = [bc.sweep(rig, "nominal", i, lambda m: print(m, file=sys.stderr)) for i in range(3)]
    ms = bc.measures(rig, sweeps, "nominal")
    obs = observations(ms)
    res = {"distance_and_peaks": part_distance_and_peaks(rig, ms)}
    res["model"] = part_model(rig, obs, map_made_observations(rig, ms, obs))
    res["floor"] = [part_floor("cellphone", 0.1), part_floor("rf50", 1.0), part_floor("cellphone", 0.1, radius=0.75),
                    part_floor("rf50", 1.0, radius=0.75)]
    res["tiles_vs_truth"] = part_tiles_vs_truth(rig, ms)
    if a.truth_noise:
        res["truth_noise"] = part_truth_noise(rig)
    if a.step_px:
        res["step"] = part_step(a.step_px)
    from aat_deploy.io.atomic import write_text_atomic

    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(a.out), json.dumps(res, indent=1))
    print("| chart (m) | tiles | object error: mean / RMS / max (D) | centre tiles | centre peak - object (D, SD) |")
    print("|---|---|---|---|---|")
    for r in res["distance_and_peaks"]:
        print(f"| {r['chart_m']:g} | {r['tiles']} | {r['object_error_mean_d']:+.4f} / {r['object_error_rms_d']:.4f} / "
              f"{r['object_error_max_d']:.4f} | {r['centre_tiles']} | {r['centre_peak_minus_object_d']:+.3f} "
              f"({r['centre_peak_sd_d']:.3f}) |")
    print("\n| tiles | field term | order (degree, radial, focus) | family chosen | offset (D) | residual RMS (D) | "
          "centre error, reported 10 D (D) |")
    print("|---|---|---|---|---|---|---|")
    for r in res["model"]:
        off = r["offset_fit_d"] if r["family"] != "offset" else r["offset_d"]
        print(f"| {r['tiles']} | {r['model']} | {r['degree']}, {r['radial']}, {r['focus_degree']} | {r['family']} | "
              f"{off:+.3f}{'' if r['family'] == 'offset' else ' (if chosen)'} | {r['residual_rms_d']:.3f} | "
              f"{r['centre_error_at_10d']:+.3f} |")
    print("\n| lens | object | field radius | texture | measure peak - object, dense (D) | at the chart step (D, 10 "
          "phases) | curve half-max width (D) |")
    print("|---|---|---|---|---|---|---|")
    for f in res["floor"]:
        for name, t in f["textures"].items():
            print(f"| {f['lens']} ({f['blur_px_per_d']:.2f} px/D) | {f['object_m']:g} m | {f['radius']:g} | {name} | "
                  f"{t['dense_peak_d']:+.4f} | {t['coarse_mean_d']:+.4f} "
                  f"({t['coarse_min_d']:+.4f}..{t['coarse_max_d']:+.4f})"
                  f" | {t['half_max_width_d']:.3f} |")
    print("\n| chart (m) | field radius | tiles | tile peak - calibrated truth's: mean (SD) (D) |")
    print("|---|---|---|---|")
    for r in res["tiles_vs_truth"]:
        print(f"| {r['chart_m']:g} | {r['zone'][0]:g}-{min(r['zone'][1], 1):g} | {r['tiles']} | {r['mean_d']:+.3f} "
              f"({r['sd_d']:.3f}) |")
    if "truth_noise" in res:
        t = res["truth_noise"]
        print(f"\nthe calibrated map's points made twice ({t['textures_per_point']} textures each, "
              f"{t['points']} points):"
              f" difference RMS {t['diff_rms_d']:.3f} D (on axis {t['diff_rms_axis_d']:.3f}, off axis "
              f"{t['diff_rms_off_axis_d']:.3f})")
    if "step" in res:
        print("\n| nominal sweeps | step (px / D) | frames | family | map RMS inside (D) | "
              "centre / middle / outer (D) |")
        print("|---|---|---|---|---|---|")
        for k, r in res["step"].items():
            z = r["zone_rms_d"]
            print(f"| {k} | {r['step_px']:g} / {r['step_d']:.2f} | {r['frames']} | {r['family']} | {r['rms_d']:.3f} | "
                  f"{z['centre']:.3f} / {z['middle']:.3f} / {z['outer']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
