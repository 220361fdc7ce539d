"""What a calibration can gain in depth over the prescription's map and the thin lens, per lens (exploratory: why
the EF50's copy gains less than the RF50's and the paper lens's in bench_calibrate b).

    OMP_WAIT_POLICY=PASSIVE nice -n 10 python -m benchmarks.probes.calibrate_gain --lens ef50 [--n 24] [--out F.json]

Two parts, on benchmarks/bench_calibrate.py's setup (its copy, its held-out stacks and chart sweeps, cached):
1. **Map amplitudes** over the depth schedule (8 frames, 0.5-10 m, the phone's 0.07-0.5 m; every pixel; diopters): how far each mapping of
   the reported focus is from the copy's truth, split into the common term (the frame's error at the centre, the
   reported focus's scale) and the field term (the rest); and the field terms themselves (in focus at (x, y) minus
   at the centre): the nominal prescription's, the copy's truth's, and the copy's departure from the prescription
   (what a calibration can add over the prescription in the field). Whole frame and outer field (radius > 0.66).
2. **Depth errors in diopters**: the classical method with the four mappings on the held-out stacks; per scene the
   MAE in metres (bench_calibrate's) and in diopters (|1/z - 1/z_true|, which weighs near and far alike), and the
   oracle's signed error in diopters by true-depth band; ratios paired over scenes. In metres the MAE is dominated
   by far pixels and by the scenes where the method itself fails (it is the same whatever the mapping); in diopters
   the mapping's share shows.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.eval.stats import N_BOOT, bootstrap_mean, paired_ratio, zone_masks
from aat_deploy.eval.stats import fmt_interval as fmt
from benchmarks import bench_calibrate as B

BANDS_M = ((0.5, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, 10.0))


def field_term(maps: np.ndarray) -> np.ndarray:
    """(S, H, W) in-focus diopters minus each frame's value at the centre."""
    h, w = maps.shape[1:]
    return maps - maps[:, h // 2, w // 2][:, None, None]


def rms(a: np.ndarray, mask: np.ndarray | None = None) -> float:
    return float(np.sqrt(np.mean((a if mask is None else a[:, mask]) ** 2)))


def amplitudes(rig: B.Rig) -> dict:
    eff = B.effects_for(rig.setup, "copy")
    true_m = rig.setup.schedule()  # the depth stacks' 8 frames (0.5-10 m; the phone 0.07-0.5 m)
    rep = true_m * B.SCALE
    truth = rig.truth(eff, true_m)
    nominal = rig.truth(["noise"], true_m)  # the nominal lens's truth at the true focus
    r = rig.fmap.radius_px(rig.h, rig.w)
    presc = np.stack([rig.fmap.frame_diopters([f], r.ravel())[0].reshape(rig.h, rig.w) for f in rep])
    thin = np.broadcast_to((1.0 / rep)[:, None, None], truth.shape)
    outer = zone_masks(rig.h, rig.w)["outer"]
    out = {}
    for name, m in (("thin lens", thin), ("prescription map", presc)):
        e = m - truth
        c = e[:, rig.h // 2, rig.w // 2][:, None, None]
        out[f"{name} - truth"] = {"all": rms(e), "common (centre)": rms(np.broadcast_to(c, e.shape)),
                                  "field": rms(e - c), "field outer": rms(e - c, outer)}
    out["field terms"] = {
        "prescription (nominal lens)": {"all": rms(field_term(nominal)), "outer": rms(field_term(nominal), outer)},
        "copy truth": {"all": rms(field_term(truth)), "outer": rms(field_term(truth), outer)},
        "copy - prescription": {"all": rms(field_term(truth) - field_term(nominal)),
                                "outer": rms(field_term(truth) - field_term(nominal), outer)}}
    for e in eff:  # each of the copy's focus effects alone: its departure from the prescription's field term
        if e.split(":")[0] in ("lens_tolerance", "sensor_tilt"):
            one = field_term(rig.truth([e], true_m)) - field_term(nominal)
            out["field terms"][f"{e.split(':')[0]} alone - prescription"] = {"all": rms(one), "outer": rms(one, outer)}
    return out


def depth(rig: B.Rig, n: int, log) -> dict:
    from aat_deploy.focus import FocusConfig, classical_depth
    from aat_deploy.focus.measures import focus_volume
    from training.train.testsets import TestSetSpec, load_test_set

    s = rig.setup
    eff = tuple(B.effects_for(s, "copy"))
    sweeps = [B.sweep(rig, "copy", i, log) for i in range(len(s.distances_m))]
    cal = B.fit(rig, "copy", sweeps, 10).calibration
    spec = TestSetSpec(s.lens, s.psf, 8, protocol="fixed", n_procedural=n, effects=eff)
    sets = load_test_set(spec, str(B.ROOT / "cache/heldout"))
    items = sets["procedural"] + sets.get("middlebury", [])
    cfg = FocusConfig()
    keys = ("thin lens", "prescription map", "calibration", "oracle")
    per = {k: [] for k in keys}
    bands = {k: [] for k in keys}
    for it in items:
        vol = focus_volume(it.stack, cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px)
        rep = np.asarray(it.focus_m, np.float64)
        runs = {"thin lens": dict(), "prescription map": dict(best_focus=rig.fmap),
                "calibration": dict(calibration=cal),
                "oracle": dict(frame_diopters=rig.truth(list(eff), rep / B.SCALE))}
        gt = it.depth_m
        valid = np.isfinite(gt) & (gt > 0)
        for k, kw in runs.items():
            z = classical_depth(it.stack, rep, config=cfg, volume=vol, **kw).depth_m
            ed = 1.0 / z[valid] - 1.0 / gt[valid]  # + : estimated nearer than true
            per[k].append({"scene": it.name, **B.zone_scores(z, gt), "bias_d": float(ed.mean())})
            bands[k].append([float(np.mean(ed[(gt[valid] >= lo) & (gt[valid] < hi)]))
                             if np.any((gt[valid] >= lo) & (gt[valid] < hi)) else float("nan") for lo, hi in BANDS_M])
        log(f"  {it.name}: " + ", ".join(f"{k} {per[k][-1]['mae']:.3f} m / {per[k][-1]['mae_d']:.4f} D" for k in keys))
    out = {"scenes": len(items), "per_scene": per, "bands_signed_d": bands}
    for k in keys:
        out[k] = {z: list(bootstrap_mean([x[z] for x in per[k]], n_boot=N_BOOT, seed=1))
                  for z in ("mae", "mae_d", "bias_d")}
    for z in ("mae", "mae_d"):
        for a, b in (("calibration", "prescription map"), ("calibration", "thin lens"), ("oracle", "thin lens")):
            out[f"{a} / {b} {z}"] = paired_ratio(per[a], per[b], z)
    # the scenes where the method itself does well (oracle MAE under its median) and the rest, in metres
    med = np.median([x["mae"] for x in per["oracle"]])
    for part, sel in (("easy half", lambda x: x["mae"] <= med), ("hard half", lambda x: x["mae"] > med)):
        idx = [i for i, x in enumerate(per["oracle"]) if sel(x)]
        for a, b in (("calibration", "prescription map"), ("calibration", "thin lens")):
            out[f"{part}: {a} / {b} mae"] = paired_ratio([per[a][i] for i in idx], [per[b][i] for i in idx], "mae")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", choices=sorted(B.LENSES), default="ef50")
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--parts", default="amplitudes,depth")
    ap.add_argument("--out", default=None, help="also write the results as JSON")
    ap.add_argument("--copy-effects", default=None,
                    help="amplitudes only: another copy (comma-separated effects, bench_calibrate's syntax)")
    a = ap.parse_args(argv)
    log = lambda m: print(m, file=sys.stderr, flush=True)
    setup = B.LENSES[a.lens]
    if a.copy_effects:
        if "depth" in a.parts:
            ap.error("--copy-effects: the held-out stacks and sweeps are rendered through bench_calibrate's copy; "
                     "use --parts amplitudes")
        setup = B.dataclasses.replace(setup, copy_effects=tuple(a.copy_effects.split(",")))
    rig = B.Rig(setup)
    res: dict = {"lens": a.lens}
    if "amplitudes" in a.parts:
        res["amplitudes"] = amp = amplitudes(rig)
        print(f"{a.lens}: map amplitudes over the {setup.schedule_m[0]:g}-{setup.schedule_m[1]:g} m schedule (RMS, D)")
        for k in ("thin lens - truth", "prescription map - truth"):
            print(f"  {k}: " + ", ".join(f"{z} {v:.4f}" for z, v in amp[k].items()))
        for k, v in amp["field terms"].items():
            print(f"  field term, {k}: all {v['all']:.4f}, outer {v['outer']:.4f}")
    if "depth" in a.parts:
        res["depth"] = d = depth(rig, a.n, log)
        print(f"{a.lens}: {d['scenes']} held-out stacks through the copy")
        for k in ("thin lens", "prescription map", "calibration", "oracle"):
            print(f"  {k}: MAE {fmt(d[k]['mae'])} m, {fmt(d[k]['mae_d'])} D; signed {fmt(d[k]['bias_d'])} D; by band "
                  + ", ".join(f"{lo:g}-{hi:g} m {np.nanmean([b[i] for b in d['bands_signed_d'][k]]):+.4f}"
                              for i, (lo, hi) in enumerate(BANDS_M)))
        for k, v in d.items():
            if " / " in k:
                print(f"  {k}: {fmt(v)}")
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(Path(a.out), json.dumps(res, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
