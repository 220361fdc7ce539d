"""Is the phone's tile bias the chart's texture, or the renderer? (issue 33, part a: the tiles read their object
-0.05 D off at the centre and -0.13/-0.14 D at field radius 0.66-0.9, `within_tiles`.)

    OMP_NUM_THREADS=1 python -m benchmarks.probes.truth_texture [--textures photos,soft_leaves] \
        [--radii 0,0.65,0.75,0.85] [--focus-m 0.07,0.1,0.15] [--n 48] [--out results/truth_texture.json]

The truth map (lenses/best_focus/cellphone_asphere.json) is the traced best focus calibrated to where the focus
measure peaks on **photographs**: `training.render.focus_calibration.measure_point` renders 48 `photo_texture`
crops (training split, RGB, 64 px scored + 24 px margin) as a plane at the traced best focus D*(r, F), on the sensor
diagonal at radius r, through the training `Simulator` with the PSF surrogate, in 21 frames over +-5.5 D, sums the
measure (mlap2, 15 px window, 1 px pre-filter) over the crop and finds its peak by a parabola on log measure.
The chart's tiles are the chart's softened dead leaves (grey) through the virtual camera (`aat_deploy.capture`).

Here the truth's own procedure is repeated with only the texture changed (the nominal lens; no scene, held-out
or not), so a texture's bias is measured in the truth's own renderer: bias = D* - the calibrated map's in-focus
object for the frame where that texture's measure peaks (D of object; the tiles' bias is defined the same way).
`photos` (the same draw as the truth: ~0 by construction) is the check. Textures: `photos`; `photos_grey` (their
luminance: colour against grey); `photos_turned` (each turned by a uniform random angle: the photographs' spectrum
with isotropic orientation); `soft_leaves` (the chart: dead leaves at the benchmark's 3 chart px per sensor px,
softened 0.7 sensor px, area-sampled); `square_leaves` (the same with axis-aligned squares instead of discs).
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

K = 3  # chart image px per sensor px (bench_calibrate.CHART_PX_PER_PX)
SOFT = 0.7  # the chart's softening, sensor px (aat_deploy.calibrate.chart.SOFT_SENSOR_PX)
LEAF_MAX = 62.0  # the largest leaf radius, sensor px (0.1 x the 1.3-frame chart's height on a 480 px frame)


def _leaves(n: int, rng, square: bool, soft: float = SOFT) -> np.ndarray:
    """(n, n) linear grey: dead leaves (discs or axis-aligned squares, radii ~ r^-3 over 0.5..LEAF_MAX sensor px)
    drawn at K x, softened by `soft` sensor px (default SOFT) and area-sampled, as the benchmark's chart is seen in
    focus."""
    import cv2

    from aat_deploy.calibrate.chart import dead_leaves
    from aat_deploy.io.color import srgb_to_linear

    m = n * K
    if square:
        a, b = 0.5 * K, LEAF_MAX * K
        img = np.full((m, m), 128, np.uint8)
        cnt = int(6 * m * m / (4 * 2 * a * a * b * b / (b * b - a * a) * np.log(b / a))) + 1
        u = rng.random(cnt)
        r = 1.0 / np.sqrt(1 / a ** 2 - u * (1 / a ** 2 - 1 / b ** 2))
        cx, cy = rng.uniform(-b, m + b, cnt), rng.uniform(-b, m + b, cnt)
        g = rng.integers(20, 236, cnt)
        for i in range(cnt):
            x0, x1 = int(round(cx[i] - r[i])), int(round(cx[i] + r[i]))
            y0, y1 = int(round(cy[i] - r[i])), int(round(cy[i] + r[i]))
            img[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = g[i]
    else:
        img = dead_leaves(m, m, 0.5 * K, LEAF_MAX * K, rng)
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), soft * K) if soft > 0 else img.astype(np.float32)
    lin = srgb_to_linear(np.clip(img, 0, 255) / 255.0)
    return cv2.resize(lin, (n, n), interpolation=cv2.INTER_AREA).astype(np.float32)


def texture(name: str, rng, n: int) -> np.ndarray:
    """(n, n, 3) float32 linear RGB."""
    import cv2

    from training.data.textures import photo_texture

    if name == "photos":
        return photo_texture(rng, n, n, "train").astype(np.float32)
    if name == "photos_grey":
        t = photo_texture(rng, n, n, "train")
        return np.repeat((t @ np.array([0.2126, 0.7152, 0.0722], np.float32))[..., None], 3, 2)
    if name == "photos_turned":
        big = int(np.ceil(n * 1.5)) + 2
        t = photo_texture(rng, big, big, "train")
        rot = cv2.getRotationMatrix2D((big / 2, big / 2), float(rng.uniform(0, 360)), 1.0)
        t = cv2.warpAffine(t, rot, (big, big), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        o = (big - n) // 2
        return np.clip(t[o:o + n, o:o + n], 0, 1).astype(np.float32)
    if name in ("soft_leaves", "square_leaves"):
        return np.repeat(_leaves(n, rng, name == "square_leaves")[..., None], 3, 2)
    raise SystemExit(f"unknown texture {name!r}")


def peak(lens, fmap, r: float, focus_m: float, cfg, sim, name: str, n_tex: int) -> dict:
    """measure_point's procedure with `name`'s texture: the peak (reported D) and the bias (D of object)."""
    import torch

    from aat_deploy.focus.measures import focus_volume
    from training.render.focus_calibration import _peak_log, renderable_diopters

    d_star = float(fmap.frame_diopters([focus_m], [r], calibrated=False)[0, 0])
    (dlo, dhi), (flo, fhi) = renderable_diopters(cfg)
    if not dlo <= d_star <= dhi:
        return {"note": "outside the PSFs' depth range"}
    s = lens.sensor
    n = cfg.crop_px + 2 * cfg.margin_px
    col = (1 + r) / 2 * s.width_px - n / 2
    row = (1 - r) / 2 * s.height_px - n / 2
    fd = 1.0 / focus_m + np.linspace(-cfg.sweep_d, cfg.sweep_d, cfg.n_sweep)
    fd = fd[(fd > 0) & (fd >= flo - 1e-9) & (fd <= fhi + 1e-9)]
    rng = np.random.default_rng([cfg.seed, int(r * 1000), int(focus_m * 1000)])  # the truth's draw for photos
    curve = np.zeros(fd.size)
    for _ in range(n_tex):
        img = torch.from_numpy(np.ascontiguousarray(texture(name, rng, n).transpose(2, 0, 1)))
        st = sim.render_stack(img, torch.full((n, n), 1.0 / d_star), 1.0 / fd, origin=(int(round(row)),
                                                                                       int(round(col))))
        fr = st.frames.numpy()
        vol = focus_volume(fr / max(float(fr.max()), 1e-12), cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px)
        m = cfg.margin_px
        curve += vol[:, m:m + cfg.crop_px, m:m + cfg.crop_px].mean((1, 2))
    f_peak = _peak_log(fd, curve)
    if not np.isfinite(f_peak):
        return {"note": "peak outside the sweep"}
    truth = float(fmap.frame_diopters([1.0 / f_peak], [r], calibrated=True)[0, 0])
    k = int(np.argmax(curve))
    second = [int(i) for i in range(1, len(curve) - 1) if curve[i] > curve[i - 1] and curve[i] > curve[i + 1]
              and i != k and curve[i] > 0.8 * curve[k]]
    return {"peak_reported_d": f_peak, "object_d": d_star, "truth_at_peak_d": truth, "bias_d": d_star - truth,
            "two_peaks": bool(second)}


def own_points(fmap) -> dict:
    """The truth map at its own calibration points, no rendering: its in-focus object for the frame where the
    photographs' measure peaked (`measure_peak_focus_diopters`) against the plane's D* (what it was calibrated to
    give there); the miss is the offsets' placement at the peak's frame and their interpolation onto the map's
    (radius, focus) grid and back (D of object)."""
    rows = []
    for q in fmap.notes["calibration_points"]:
        if "measure_peak_focus_diopters" not in q or not np.isfinite(q.get("offset_diopters", np.nan)):
            continue
        t = float(fmap.frame_diopters([1.0 / q["measure_peak_focus_diopters"]], [q["r"]], calibrated=True)[0, 0])
        rows.append({"r": q["r"], "focus_m": q["focus_m"], "miss_d": q["traced_object_diopters"] - t})
    miss = np.array([q["miss_d"] for q in rows])
    by_r = {}
    for r in sorted({q["r"] for q in rows}):
        m = np.array([q["miss_d"] for q in rows if q["r"] == r])
        by_r[f"{r:g}"] = {"n": int(m.size), "rms_d": float(np.sqrt(np.mean(m ** 2))),
                          "max_abs_d": float(np.max(np.abs(m)))}
    return {"points": len(rows), "rms_d": float(np.sqrt(np.mean(miss ** 2))), "max_abs_d": float(np.abs(miss).max()),
            "by_radius": by_r, "grid_radius": fmap.radius.tolist(), "rows": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--textures", default="photos,photos_grey,photos_turned,soft_leaves,square_leaves")
    ap.add_argument("--radii", default="0,0.65,0.75,0.85")
    ap.add_argument("--focus-m", default="0.07,0.1,0.15")
    ap.add_argument("--n", type=int, default=48, help="textures per point (the truth's 48)")
    ap.add_argument("--out", default=str(RESULTS / "truth_texture.json"))
    ap.add_argument("--own-points", action="store_true", help="no rendering: the truth map at its own calibration "
                    "points (into --out)")
    a = ap.parse_args(argv)
    if Path(a.out).exists():  # a committed result is never overwritten
        ap.error(f"{a.out}: exists (choose another --out)")
    from aat_deploy.focus.bestfocus import load_json
    from aat_deploy.lens.io import load_lens
    from training.render import focus_calibration as FC

    root = Path(__file__).resolve().parents[2]
    lens = load_lens(root / "lenses" / "cellphone_asphere.json")
    fmap = load_json(root / "lenses" / "best_focus" / "cellphone_asphere.json")
    if a.own_points:
        out = own_points(fmap)
        write_text_atomic(a.out, json.dumps(out, indent=1))
        print(json.dumps({k: v for k, v in out.items() if k not in ("rows", "grid_radius")}, indent=1))
        return 0
    c = fmap.notes["calibration"]
    cfg = FC.CalibrationConfig(sweep_d=c["sweep_d"], n_sweep=c["n_sweep"], crop_px=c["crop_px"],
                               margin_px=c["margin_px"], psf=str(root / c["psf"]), seed=c["seed"])
    sim = FC._simulator(lens, cfg)
    rows = []
    for name in a.textures.split(","):
        for f in (float(v) for v in a.focus_m.split(",")):
            for r in (float(v) for v in a.radii.split(",")):
                t0 = time.time()
                p = peak(lens, fmap, r, f, cfg, sim, name, a.n)
                rows.append({"texture": name, "r": r, "focus_m": f, **p})
                print(f"{name:14s} r {r:.2f} F {f:.2f} m: bias {p.get('bias_d', float('nan')):+.3f} D "
                      f"peak {p.get('peak_reported_d', float('nan')):.3f} ({time.time() - t0:.0f} s)", flush=True)
    summary = {}
    for name in a.textures.split(","):
        for r in (float(v) for v in a.radii.split(",")):
            b = [q["bias_d"] for q in rows if q["texture"] == name and q["r"] == r and "bias_d" in q]
            summary[f"{name} r={r:g}"] = float(np.mean(b)) if b else None
    out = {"what": __doc__.split("\n")[0], "n_textures": a.n, "rows": rows, "mean_bias_by_texture_radius_d": summary}
    write_text_atomic(a.out, json.dumps(out, indent=1))
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
