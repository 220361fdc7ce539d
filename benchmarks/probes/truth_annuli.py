"""Does the phone's truth map say what the benchmark's renders do? (issue 33, part a: the tiles' bias, `within_tiles`;
`truth_texture` and `truth_renderer` hold the texture and the renderer's PSF cells.)

    OMP_NUM_THREADS=1 python -m benchmarks.probes.truth_annuli [--textures photos,leaves] [--seeds 1,2,3,4] \
        [--cell-px 64] [--out results/truth_annuli.json]

The truth (lenses/best_focus/cellphone_asphere.json) was calibrated on 64 px crops on the sensor diagonal at 11
radii, rendered with 32 px PSF cells, 48 photographs a point. The benchmark renders its chart sweeps and its depth
scenes with the virtual camera at 64 px cells over the whole frame. Here the benchmark's renderer (`shoot`, no
noise, the nominal lens) renders flat planes square to the camera at 1/Z = 2, 3, ..., 18 D, covered in a texture
(`photos`: the truth's photographs as a mosaic, `chart_texture.photo_mosaic`; `leaves`: the chart's softened dead
leaves), each in 21 frames 0.55 D apart from 1/Z - 3.3 D (kept inside the surrogate's focus range); the focus
measure (the runtime's) is averaged over every pixel of a field-radius annulus (width 0.05, every azimuth) and
summed over the texture draws, and its peak found as the truth's was (a parabola on log measure). The truth's
inconsistency at that annulus is 1/Z minus the truth's in-focus object for the frame of the peak (D of object, as
the tiles' bias): what a perfect calibration of these renders would read against this truth. No scene, held-out or
not, is rendered.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks import RESULTS

R_EDGES = np.round(np.arange(0.0, 0.951, 0.05), 3)
OBJ_D = np.arange(2.0, 18.01, 1.0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--textures", default="photos,leaves")
    ap.add_argument("--seeds", default="1,2,3,4")
    ap.add_argument("--cell-px", type=int, default=64)
    ap.add_argument("--out", default=str(RESULTS / "truth_annuli.json"))
    ap.add_argument("--score", default=None, help="two runs' json (disjoint seeds), comma-separated: score the "
                    "nominal chart calibration at their points into --out")
    a = ap.parse_args(argv)
    if Path(a.out).exists():  # a committed result is never overwritten
        ap.error(f"{a.out}: exists (choose another --out)")
    if a.score:
        files = a.score.split(",")
        if len(files) != 2 or not all(Path(f).is_file() for f in files):
            ap.error(f"--score {a.score}: two existing runs' json, comma-separated")
        seeds = [set(json.loads(Path(f).read_text())["seeds"].split(",")) for f in files]
        if seeds[0] & seeds[1]:  # the same draws twice would record a renders' noise of 0
            ap.error(f"--score {a.score}: the runs share seeds {','.join(sorted(seeds[0] & seeds[1]))}")
        print(json.dumps(score(files, a.out), indent=1))
        return 0
    from aat_deploy.calibrate.format import field_grid, field_radius_of
    from aat_deploy.focus import FocusConfig
    from aat_deploy.focus.bestfocus import load_json
    from aat_deploy.focus.measures import focus_volume
    from aat_deploy.lens.io import load_lens
    from aat_deploy.psf.surrogate import PSFSurrogate
    from benchmarks.probes.chart_texture import photo_mosaic
    from benchmarks.probes.truth_renderer import render
    from benchmarks.probes.truth_texture import _leaves
    from training.render.focus_calibration import _peak_log

    root = Path(__file__).resolve().parents[2]
    lens = load_lens(root / "lenses" / "cellphone_asphere.json")
    fmap = load_json(root / "lenses" / "best_focus" / "cellphone_asphere.json")
    psf = root / fmap.notes["calibration"]["psf"]
    fn, ff = PSFSurrogate(psf, threads=1).focus_range_m
    h, w = lens.sensor.height_px, lens.sensor.width_px
    gx, gy = field_grid(h, w)
    rad = field_radius_of(gx, gy, w / h)
    rings = [(lo, hi, (rad >= lo) & (rad < hi)) for lo, hi in zip(R_EDGES[:-1], R_EDGES[1:])]
    cfg = FocusConfig()
    out = {"what": __doc__.split("\n")[0], "cell_px": a.cell_px, "seeds": a.seeds, "rows": []}
    for tname in a.textures.split(","):
        for od in OBJ_D:
            t0 = time.time()
            fd = od - 3.3 + 0.55 * np.arange(21)
            fd = fd[(fd >= 1 / ff - 1e-9) & (fd <= 1 / fn + 1e-9)]
            curves = np.zeros((len(rings), fd.size))
            for seed in (int(v) for v in a.seeds.split(",")):
                rng = np.random.default_rng([seed, int(od * 10)])
                tex = _leaves(max(h, w), rng, False)[:h, :w] if tname == "leaves" else photo_mosaic(h, w, rng)
                rgb = np.ascontiguousarray(np.repeat(tex[None], 3, 0) * 0.6, np.float32)
                fr = render(f"shoot{a.cell_px}", lens, rgb, 1.0 / od, 1.0 / fd, psf)
                vol = focus_volume(fr / max(float(fr.max()), 1e-12), cfg.measure, cfg.window_px,
                                   prefilter_px=cfg.prefilter_px)
                for k, (_, _, m) in enumerate(rings):
                    curves[k] += vol[:, m].mean(1)
            for k, (lo, hi, _) in enumerate(rings):
                fp = _peak_log(fd, curves[k])
                r = 0.5 * (lo + hi)
                tr = float(fmap.frame_diopters([1.0 / fp], [r], calibrated=True)[0, 0]) if np.isfinite(fp) else None
                out["rows"].append({"texture": tname, "object_d": float(od), "r": r,
                                    "peak_reported_d": float(fp) if np.isfinite(fp) else None,
                                    "truth_at_peak_d": tr, "bias_d": None if tr is None else float(od - tr)})
            b = [q["bias_d"] for q in out["rows"][-len(rings):]]
            print(f"{tname} 1/Z {od:g} D ({time.time() - t0:.0f} s): " +
                  " ".join("  -  " if v is None else f"{v:+.2f}" for v in b), flush=True)
    write_text_atomic(a.out, json.dumps(out, indent=1))
    return 0


def score(files: list[str], out_path: str) -> dict:
    """The nominal phone's chart calibration (bench_calibrate's `cellphone_near` sweeps, cached; fitted as part a
    fits it) at the annuli's points, against the truth and against the renders (1/Z), for the points whose peak
    lies in part a's inside focus range (7-18 cm); `files`: two runs of the same texture on disjoint seeds (their
    difference estimates the renders' own noise). D of object, RMS weighted by the annuli's pixels."""
    from aat_deploy.calibrate.format import field_grid, field_radius_of, in_focus_diopters
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import chart_texture as CT

    rig, v = CT.rig_for(B.Rig(B.LENSES["cellphone_near"]), "soft leaves", "nominal")
    sweeps = [B.sweep(rig, v, i, lambda *_: None) for i in range(len(rig.setup.distances_m))]
    cal = B.fit(rig, v, sweeps, 0).calibration
    gx, gy = field_grid(rig.h, rig.w)
    rad = field_radius_of(gx, gy, rig.w / rig.h)
    runs = [json.loads(Path(f).read_text())["rows"] for f in files]
    lo_d, hi_d = 1.0 / max(rig.setup.inside()), 1.0 / min(rig.setup.inside())
    r_max = float(cal.best_focus.radius_max)
    pts = []
    for qa, qb in zip(*runs):
        if qa["bias_d"] is None or qb["bias_d"] is None:
            continue
        fp = 0.5 * (qa["peak_reported_d"] + qb["peak_reported_d"])
        if not lo_d <= fp <= hi_d:
            continue
        m = (rad >= qa["r"] - 0.025) & (rad < qa["r"] + 0.025)
        mp = float(in_focus_diopters(cal, [1.0 / fp], rig.h, rig.w)[0][m].mean())
        tr = 0.5 * (qa["truth_at_peak_d"] + qb["truth_at_peak_d"])
        pts.append((qa["r"], int(m.sum()), qa["object_d"], tr, mp, qa["bias_d"] - qb["bias_d"]))
    r, n, obj, tr, mp, dab = (np.array(c, np.float64) for c in zip(*pts))

    def rms(e, sel):
        return float(np.sqrt(np.sum(n[sel] * e[sel] ** 2) / np.sum(n[sel])))

    out = {"points": len(pts), "focus_range_d": [lo_d, hi_d], "radius_max": r_max}
    for name, sel in (("within the tiles' radius", r <= r_max), ("all radii", r < 1)):
        noise2 = rms(dab / 2, sel) ** 2  # variance of the two runs' mean
        out[name] = {"truth - renders": rms(tr - obj, sel), "calibration - truth": rms(mp - tr, sel),
                     "calibration - renders": rms(mp - obj, sel), "renders' noise (the two runs' mean)":
                     float(np.sqrt(noise2))}
        out[name]["truth - renders, noise removed"] = float(np.sqrt(max(out[name]["truth - renders"] ** 2 -
                                                                       noise2, 0)))
        out[name]["calibration - renders, noise removed"] = float(np.sqrt(max(
            out[name]["calibration - renders"] ** 2 - noise2, 0)))
        out[name]["by_radius"] = {f"{a:g}-{b:g}": {k: rms(e, sel & (r >= a) & (r < b)) for k, e in
                                                   (("truth - renders", tr - obj), ("calibration - truth", mp - tr),
                                                    ("calibration - renders", mp - obj))}
                                  for a, b in ((0, 0.33), (0.33, 0.66), (0.66, 0.84), (0.84, 0.95))
                                  if np.any(sel & (r >= a) & (r < b))}
    write_text_atomic(out_path, json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    sys.exit(main())
