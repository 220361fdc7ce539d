"""A render-consistent truth for part a: where the focus measure peaks in the benchmark's own renders, with a
bootstrap standard error per point (issue 33; docs/calibration.md, "A render-consistent truth: what it costs").

    OMP_NUM_THREADS=1 python -m benchmarks.probes.render_truth [--objects-d 5,8,11,14] [--draws 12] \
        [--cell-px 64] [--texture photos] [--phase-d 0.275] [--until 17:15] [--boot 400] [--out results/render_truth.json]

Part a's truth (lenses/best_focus/cellphone_asphere.json) is the traced smallest-spot focus plus offsets measured
on 64 px crops on the sensor diagonal, rendered by the training `Simulator` at 32 px PSF cells; it is 0.06 D RMS
from where the measure peaks in the benchmark's renders (virtual camera, 64 px cells) within the tiles' radius
(`truth_annuli`). This measures those peaks directly, as `truth_annuli` does (and reusing its pieces): a flat plane
square to the camera at object diopters 1/Z, covered in a full-frame mosaic of training photographs
(`chart_texture.photo_mosaic`, the truth's own `photo_texture` draws, split "train"; `leaves`: the chart's softened
dead leaves), rendered noise-free by the benchmark's renderer (`truth_renderer.render`, `shoot` at `--cell-px`) in
frames 0.55 D apart from 1/Z - 3.3 D (inside the surrogate's focus range); the runtime's measure averaged over each
field-radius annulus (width 0.05, every azimuth) and summed over the draws; its peak F_peak by the truth's estimator
(`focus_calibration._peak_log`, a parabola on log measure). The point (r, F_peak, 1/Z) is the render-consistent
truth: in frame F_peak, at radius r, the object 1/Z is in focus. Its error is the draws' bootstrap (draws resampled
with replacement): SE of F_peak (frame D) and of the current truth's in-focus object at F_peak (object D: the map's
slope turns the first into the second), so `bias` = 1/Z - truth(r, F_peak) is the current truth's error there,
with its SE. Draws needed for SE 0.02 D: N (SE_N / 0.02)^2.

Resumable: each (plane, draw) is cached under cache/render_truth/<setup key>/ (its ring curves and render seconds);
a run renders only what is missing, draw by draw over all planes (so a stop leaves the planes balanced), and stops
rendering at `--until` (UTC HH:MM). Nothing is adopted: the truth file is not touched. No scene, held-out or not,
is rendered.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks import RESULTS, ROOT

CACHE = ROOT / "cache" / "render_truth"
R_EDGES = tuple(float(v) for v in np.round(np.arange(0.0, 0.951, 0.05), 3))  # truth_annuli's annuli
TARGET_D = 0.02
INSIDE_M = (0.07, 0.18)  # part a's "inside" reported focus range on the phone (bench_calibrate's cellphone_near)
TILES_R = 0.92  # the farthest counted tile's field radius on the phone ("The tiles and the frame's corners")
BINS = ((0.0, 0.33), (0.33, 0.66), (0.66, 0.84), (0.84, 0.92))


@dataclasses.dataclass(frozen=True)
class Setup:
    """What a cached draw depends on. lens / psf / fmap: repository-relative paths (psf None: the thin-lens
    Gaussian, an ideal lens; fmap None: no truth to compare, object SE taken as frame SE); sensor_px (W, H): the
    lens's sensor resampled (tests)."""

    lens: str = "lenses/cellphone_asphere.json"
    psf: str | None = "models/psf_cellphone.onnx"
    fmap: str | None = "lenses/best_focus/cellphone_asphere.json"
    cell_px: int = 64
    texture: str = "photos"
    step_d: float = 0.55
    before_d: float = 3.3
    n_frames: int = 21
    r_edges: tuple = R_EDGES
    sensor_px: tuple | None = None
    block_px: int = 128  # photos: the mosaic's blocks (chart_texture.photo_mosaic), one photograph each
    leaves_soft_px: float = 0.7  # leaves: their softening, sensor px (the chart's, truth_texture.SOFT)

    def key(self) -> str:
        d = {k: v for k, v in dataclasses.asdict(self).items() if k != "fmap"}  # the map only reads the peaks
        if d["block_px"] == 128:  # keys made before the field existed
            del d["block_px"]
        if d["leaves_soft_px"] == 0.7:
            del d["leaves_soft_px"]
        return hashlib.sha1(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]


def _lens(setup: Setup):
    from aat_deploy.lens.io import load_lens

    lens = load_lens(ROOT / setup.lens)
    if setup.sensor_px:
        lens = dataclasses.replace(lens, sensor=lens.sensor.with_resolution(*setup.sensor_px))
    return lens


def frames_d(setup: Setup, od: float) -> np.ndarray:
    """The plane's sweep (frame focus, D), kept inside the surrogate's focus range."""
    fd = od - setup.before_d + setup.step_d * np.arange(setup.n_frames)
    if setup.psf is not None:
        from aat_deploy.psf.surrogate import PSFSurrogate

        fn, ff = PSFSurrogate(ROOT / setup.psf, threads=1).focus_range_m
        fd = fd[(fd >= 1 / ff - 1e-9) & (fd <= 1 / fn + 1e-9)]
    return fd[fd > 0]


def texture(setup: Setup, h: int, w: int, od: float, seed: int) -> np.ndarray:
    """(h, w) linear grey: draw `seed` of the setup's texture for the plane at od (independent per plane)."""
    from benchmarks.probes.chart_texture import photo_mosaic
    from benchmarks.probes.truth_texture import _leaves

    rng = np.random.default_rng([33, seed, int(round(od * 1000))])
    if setup.texture == "photos":
        return photo_mosaic(h, w, rng, setup.block_px)
    if setup.texture == "leaves":
        return _leaves(max(h, w), rng, False, setup.leaves_soft_px)[:h, :w]
    raise SystemExit(f"--texture {setup.texture}: photos or leaves")


def ring_means(vol: np.ndarray, r_edges) -> np.ndarray:
    """(S, H, W) focus volume -> (len(r_edges) - 1, S): its mean over each field-radius annulus [lo, hi) (NaN where an
    annulus holds no pixel); radius as `field_radius_of` (1 at the frame's corner)."""
    from aat_deploy.calibrate.format import field_grid, field_radius_of

    s, h, w = vol.shape
    gx, gy = field_grid(h, w)
    rad = field_radius_of(gx, gy, w / h)
    edges = np.asarray(r_edges)
    out = np.full((edges.size - 1, s), np.nan)
    for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        m = (rad >= lo) & (rad < hi)
        if m.any():
            out[k] = vol[:, m].mean(1)
    return out


def ring_curves(setup: Setup, od: float, seed: int) -> dict:
    """One draw of the plane at od: the measure's mean per annulus and frame, (R, S), and the frames' focus."""
    from aat_deploy.focus import FocusConfig
    from aat_deploy.focus.measures import focus_volume
    from benchmarks.probes.truth_renderer import render

    t0, w0 = time.process_time(), time.time()
    lens = _lens(setup)
    h, w = lens.sensor.height_px, lens.sensor.width_px
    fd = frames_d(setup, od)
    rgb = np.ascontiguousarray(np.repeat(texture(setup, h, w, od, seed)[None], 3, 0) * 0.6, np.float32)
    fr = render(f"shoot{setup.cell_px}", lens, rgb, 1.0 / od, 1.0 / fd,
                None if setup.psf is None else ROOT / setup.psf)
    cfg = FocusConfig()
    vol = focus_volume(fr / max(float(fr.max()), 1e-12), cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px)
    curves = ring_means(vol, setup.r_edges)
    return {"frames_d": fd, "curves": curves, "cpu_s": time.process_time() - t0, "wall_s": time.time() - w0}


def draw(setup: Setup, od: float, seed: int, render: bool = True, cache: Path | None = None) -> dict | None:
    """The cached draw (rendered when missing and `render`; None when missing and not)."""
    path = (cache or CACHE) / setup.key() / f"od{od:.3f}_s{seed}.npz"
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    if not render:
        return None
    d = ring_curves(setup, od, seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    (path.parent / "setup.json").write_text(json.dumps(dataclasses.asdict(setup), indent=1))
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **d)
    tmp.replace(path)
    return d


def peaks(frames: np.ndarray, curves: np.ndarray) -> np.ndarray:
    """(R,) frame diopters where each annulus's summed measure peaks (nan: at the sweep's end, or no pixels)."""
    from training.render.focus_calibration import _peak_log

    return np.array([_peak_log(frames, c) if np.all(np.isfinite(c)) else np.nan for c in curves])


def plane_stats(setup: Setup, od: float, curves: np.ndarray, frames: np.ndarray, fmap, boot: int,
                rng: np.random.Generator) -> list[dict]:
    """Per annulus: F_peak over the N draws `curves` (N, R, S), and its bootstrap SE in frame D and in object D
    (the current truth's in-focus object at F_peak; fmap None: taken as equal), the truth's bias there, and the SE
    from the first 4, 8, 16, ... draws (how it falls with draws)."""
    edges = np.asarray(setup.r_edges)
    mid = 0.5 * (edges[:-1] + edges[1:])

    def obj(fp):  # (..., R) frame D -> the truth's in-focus object D at those frames
        if fmap is None:
            return fp
        out = np.full(fp.shape, np.nan)
        for k, r in enumerate(mid):
            f = fp[..., k]
            ok = np.isfinite(f) & (f > 0)
            if ok.any():
                out[..., k][ok] = fmap.frame_diopters(1.0 / f[ok], [r], calibrated=True)[:, 0]
        return out

    def se(n):
        idx = rng.integers(0, n, (boot, n))
        bp = np.stack([peaks(frames, curves[i].sum(0)) for i in idx])  # (boot, R)
        bo = obj(bp)
        good = np.isfinite(bo).mean(0)
        return (np.nanstd(bp, 0, ddof=1), np.nanstd(bo, 0, ddof=1), good)

    n = curves.shape[0]
    fp = peaks(frames, curves.sum(0))
    tr = obj(fp)
    se_f, se_o, good = se(n) if n > 1 else (np.full(mid.size, np.nan),) * 2 + (np.ones(mid.size),)
    sub = {m: se(m)[1] for m in (4, 8, 16, 32, 64, 128, 256) if m < n}  # the first m draws
    rows = []
    for k, r in enumerate(mid):
        ok = bool(np.isfinite(fp[k]) and good[k] >= 0.95 and n > 1)  # a peak, inside the sweep in 95 % of resamples
        rows.append({"object_d": float(od), "r": float(r), "n_draws": int(n), "ok": ok,
                     "peak_frame_d": None if not np.isfinite(fp[k]) else float(fp[k]),
                     "se_peak_frame_d": None if not ok else float(se_f[k]),
                     "truth_object_at_peak_d": None if not np.isfinite(tr[k]) else float(tr[k]),
                     "bias_d": None if not np.isfinite(tr[k]) else float(od - tr[k]),
                     "se_object_d": None if not ok else float(se_o[k]),
                     "se_object_d_by_draws": {str(m): float(v[k]) for m, v in sub.items()} if ok else {},
                     "draws_for_target": None if not ok else int(np.ceil(n * (se_o[k] / TARGET_D) ** 2))})
    return rows


def summary(rows: list[dict], cpu_s: float, planes_full: int) -> dict:
    """RMS of the truth's bias and of its SE, and the draws needed, over the points inside part a's range and
    within the tiles' radius, by radius bin."""
    lo, hi = 1 / INSIDE_M[1], 1 / INSIDE_M[0]
    sel = [q for q in rows if q["ok"] and q["bias_d"] is not None and lo <= q["peak_frame_d"] <= hi
           and q["r"] <= TILES_R]

    def agg(qs):
        if not qs:
            return None
        b = np.array([q["bias_d"] for q in qs])
        s = np.array([q["se_object_d"] for q in qs])
        need = np.array([q["draws_for_target"] for q in qs])
        by_n = {}
        for q in qs:
            for m, v in [*q["se_object_d_by_draws"].items(), (str(q["n_draws"]), q["se_object_d"])]:
                by_n.setdefault(int(m), []).append(v)
        return {"points": len(qs), "bias_rms_d": float(np.sqrt(np.mean(b ** 2))), "bias_mean_d": float(b.mean()),
                "se_rms_d": float(np.sqrt(np.mean(s ** 2))), "se_max_d": float(s.max()),
                "bias_rms_noise_removed_d": float(np.sqrt(max(np.mean(b ** 2) - np.mean(s ** 2), 0.0))),
                "draws_for_target_median": float(np.median(need)), "draws_for_target_p90": float(
                    np.percentile(need, 90)), "draws_for_target_max": int(need.max()),
                "se_rms_by_draws": {str(m): float(np.sqrt(np.mean(np.square(v)))) for m, v in sorted(by_n.items())},
                "draws_for_rms_target": float(np.mean([q["n_draws"] for q in qs]) * np.mean(s ** 2) / TARGET_D ** 2)}

    out = {"selection": f"peak frame in {lo:.2f}-{hi:.2f} D (part a's inside range {INSIDE_M} m), r <= {TILES_R}",
           "all": agg(sel), "by_radius": {f"{a:g}-{b:g}": agg([q for q in sel if a <= q["r"] < b]) for a, b in BINS},
           "cpu_s_per_draw_plane": cpu_s}
    a = out["by_radius"].get("0.66-0.84") or out["all"]
    if a:
        n90, nr = a["draws_for_target_p90"], a["draws_for_rms_target"]
        out["full_truth_estimate"] = {
            "what": f"{planes_full} planes (truth_annuli's 2..18 D) on one core, with the draws the outer field "
                    "(radius 0.66-0.84) needs for an RMS SE of 0.02 D, and for 90 % of its points each at 0.02 D",
            "draws_per_plane_rms": nr, "cpu_hours_rms": nr * planes_full * cpu_s / 3600,
            "draws_per_plane_p90": n90, "cpu_hours_p90": n90 * planes_full * cpu_s / 3600}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--objects-d", default="5,8,11,14", help="planes, object diopters (1/Z, Z from the sensor)")
    ap.add_argument("--draws", type=int, default=12, help="texture draws per plane (seeds 1..N)")
    ap.add_argument("--cell-px", type=int, default=64, help="the renderer's PSF cells (the benchmark's: 64)")
    ap.add_argument("--texture", default="photos", help="photos (the truth's) or leaves (the chart's)")
    ap.add_argument("--block-px", type=int, default=128, help="photos: the mosaic's blocks, one photograph each "
                    "(smaller: more photographs per annulus and render)")
    ap.add_argument("--leaves-soft-px", type=float, default=0.7, help="leaves: their softening (sensor px; the "
                    "chart's 0.7)")
    ap.add_argument("--phase-d", type=float, default=0.0, help="the frames shifted nearer by this many D (the sweep "
                    "starts at 1/Z - 3.3 + phase): the estimator's bias with the peak's phase between frames")
    ap.add_argument("--until", default=None, help="UTC HH:MM: render nothing new after it (report what is cached)")
    ap.add_argument("--no-render", action="store_true", help="report the cached draws only")
    ap.add_argument("--boot", type=int, default=400)
    ap.add_argument("--planes-full", type=int, default=17, help="planes a full truth renders (for the estimate)")
    ap.add_argument("--out", default=str(RESULTS / "render_truth.json"))
    a = ap.parse_args(argv)
    if Path(a.out).exists():  # a committed result is never overwritten
        ap.error(f"{a.out}: exists (choose another --out)")
    try:
        objects = [float(v) for v in a.objects_d.split(",")]
    except ValueError:
        ap.error(f"--objects-d {a.objects_d}: numbers, comma-separated")
    if a.draws < 1 or a.boot < 10 or any(v <= 0 for v in objects):
        ap.error("--draws >= 1, --boot >= 10, --objects-d > 0")
    if a.texture not in ("photos", "leaves"):
        ap.error(f"--texture {a.texture}: photos or leaves")
    if a.block_px < 2 * 16 + 1:
        ap.error(f"--block-px {a.block_px}: above twice the mosaic's 16 px cross-fade")
    if not 0.0 <= a.phase_d < Setup.step_d:
        ap.error(f"--phase-d {a.phase_d}: in [0, {Setup.step_d}) D")
    setup = Setup(cell_px=a.cell_px, texture=a.texture, block_px=a.block_px,
                  before_d=round(Setup.before_d - a.phase_d, 6), leaves_soft_px=a.leaves_soft_px)
    stop = None
    if a.until:
        hh, mm = (int(v) for v in a.until.split(":"))
        now = datetime.now(timezone.utc)
        stop = now.replace(hour=hh, minute=mm, second=0, microsecond=0).timestamp()
    for seed in range(1, a.draws + 1):  # draw-major: a stop leaves every plane with the same draws
        for od in objects:
            if stop is not None and time.time() > stop:
                break
            render = not a.no_render and (stop is None or time.time() < stop)
            t0 = time.time()
            d = draw(setup, od, seed, render=render)
            if d is not None and time.time() - t0 > 1:
                print(f"draw {seed} plane {od:g} D: {float(d['cpu_s']):.1f} s CPU, {float(d['wall_s']):.1f} s wall",
                      flush=True)
    from aat_deploy.focus.bestfocus import load_json

    fmap = load_json(ROOT / setup.fmap)
    rng = np.random.default_rng(0)
    rows, cpu = [], []
    for od in objects:
        got = [d for d in (draw(setup, od, s, render=False) for s in range(1, a.draws + 1)) if d is not None]
        if not got:
            continue
        cpu += [float(d["cpu_s"]) for d in got]
        rows += plane_stats(setup, od, np.stack([d["curves"] for d in got]), got[0]["frames_d"], fmap, a.boot, rng)
    out = {"what": __doc__.split("\n")[0], "setup": dataclasses.asdict(setup), "setup_key": setup.key(),
           "objects_d": objects, "target_d": TARGET_D, "boot": a.boot,
           "summary": summary(rows, float(np.median(cpu)) if cpu else float("nan"), a.planes_full), "rows": rows}
    write_text_atomic(a.out, json.dumps(out, indent=1))
    print(json.dumps(out["summary"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
