"""Where the focus measure peaks, relative to the traced best focus: measured on rendered stacks of the lens.

The best-focus map (`training.optics.field_focus`) says which object distance D*(r, F) has its smallest RMS spot
on the sensor of a frame focused at F, at field radius r. Depth from focus finds instead the frame in which a
focus measure (a high-pass energy) peaks. Under spherical aberration and astigmatism these differ: the RMS spot
weighs every ray alike, the measure weighs the sharp core of the PSF. This module measures the difference.

For each (r, F): a textured plane at D*(r, F) (photo textures of the training split), placed on the sensor
diagonal at radius r, is rendered through the lens (`Simulator` with its PSFs, ray-traced by default) in a dense
sweep of frames around F (`n_sweep` focus settings over +-`sweep_d` diopters); the runtime's focus measure
(`aat_deploy.focus.measures`) is averaged over the patch per frame, summed over `n_textures` textures, and its peak
found by a parabola on log measure around the best frame of the sweep. The frame F_peak where the measure peaks
should, by the map, have D*(r, F_peak) in focus; the object is at D*(r, F). The offset that makes the map agree
with the measure is offset = D*(r, F) - D*(r, F_peak) (object diopters; added by `BestFocusMap` when calibrated),
and it belongs to the frame F_peak, where it is placed (`offset_grid`): under astigmatism the measure can peak
diopters from the min-RMS focus (a phone lens's outer field: up to 3.7 D, following the sagittal focus near and
lying between the two foci farther), and an offset placed at F moved the map there by as much (BestFocusMap
files made before record no `placed_at` in their calibration notes).
Points whose D* is beyond infinity, or outside a surrogate's depth range (it would render the object at the range's
end: a phone lens's corner focused at 7 cm is in focus nearer than its surrogate's 5 cm), are left out, and a
surrogate's sweep frames are kept inside its focus range; the offset is interpolated over F_peak and r (held
beyond the measured ranges).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from aat_deploy.focus import FocusConfig
from aat_deploy.focus.bestfocus import BestFocusMap
from aat_deploy.focus.measures import focus_volume


@dataclass(frozen=True)
class CalibrationConfig:
    """radii: field radii (normalised, on the diagonal); focus_m: frame focus settings (m from the sensor);
    sweep_d / n_sweep: the dense frame sweep around each; crop_px: patch side; n_textures; measure / window_px /
    prefilter_px: the focus measure calibrated (the runtime's defaults, `aat_deploy.focus.FocusConfig`); psf: "trace" (real rays) or a surrogate .onnx path."""

    radii: tuple = (0.0, 0.3, 0.5, 0.65, 0.8, 0.9)
    focus_m: tuple = (0.6, 1.0, 2.0, 5.0)
    sweep_d: float = 0.2
    n_sweep: int = 21
    crop_px: int = 64
    margin_px: int = 24
    n_textures: int = 3
    measure: str = FocusConfig.measure
    window_px: float = FocusConfig.window_px
    prefilter_px: float = FocusConfig.prefilter_px
    psf: str = "trace"
    seed: int = 0


def _simulator(lens, cfg: CalibrationConfig):
    from aat_deploy.render import effects as fx
    from training.render.layered import LayeredConfig
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF, RayTracedPSF

    src = RayTracedPSF(lens) if cfg.psf == "trace" else OnnxPSF(cfg.psf, lens, threads=1)
    return Simulator(lens, src, fx.parse(["aberrations"]), LayeredConfig(cell_px=32))


def renderable_diopters(cfg: CalibrationConfig) -> tuple[tuple[float, float], tuple[float, float]]:
    """((lo, hi) object diopters, (lo, hi) frame focus diopters) the PSFs render as they are: a surrogate's depth
    and focus ranges (it clamps beyond them), everything for real rays."""
    if cfg.psf == "trace":
        return (0.0, np.inf), (0.0, np.inf)
    from aat_deploy.psf.surrogate import PSFSurrogate

    m = PSFSurrogate(cfg.psf, threads=1)
    (dn, df), (fn, ff) = m.depth_range_m, m.focus_range_m
    return (1.0 / df, 1.0 / dn), (1.0 / ff, 1.0 / fn)


def _peak_log(x: np.ndarray, m: np.ndarray) -> float:
    """Peak of a sampled curve: the vertex of the parabola through log m at the best sample and its neighbours."""
    k = int(np.argmax(m))
    if k == 0 or k == len(m) - 1:
        return float("nan")  # the peak is outside the sweep
    y = np.log(m[k - 1:k + 2])
    x0, x1, x2 = x[k - 1:k + 2]
    den = (x1 - x0) * (y[1] - y[2]) - (x1 - x2) * (y[1] - y[0])
    num = (x1 - x0) ** 2 * (y[1] - y[2]) - (x1 - x2) ** 2 * (y[1] - y[0])
    return float(x1 - 0.5 * num / den) if den != 0 else float(x1)


def measure_point(lens, fmap: BestFocusMap, r: float, focus_m: float, cfg: CalibrationConfig, sim=None,
                  ranges=None) -> dict:
    """One (r, F): the traced D*, the sweep's measure curve and the peak; offset in object diopters. ranges: the
    renderable diopters (`renderable_diopters`; None: from cfg)."""
    import torch

    from training.data.textures import photo_texture

    sim = sim or _simulator(lens, cfg)
    d_star = float(fmap.frame_diopters([focus_m], [r], calibrated=False)[0, 0])
    out = {"r": float(r), "focus_m": float(focus_m), "traced_object_diopters": d_star}
    if d_star <= 0.02:
        return {**out, "offset_diopters": float("nan"), "note": "traced best focus beyond 50 m: not rendered"}
    (dlo, dhi), (flo, fhi) = renderable_diopters(cfg) if ranges is None else ranges
    if not dlo <= d_star <= dhi:
        return {**out, "offset_diopters": float("nan"),
                "note": f"traced best focus {1 / d_star:.4g} m: outside the PSFs' depth range, not rendered"}
    s = lens.sensor
    n = cfg.crop_px + 2 * cfg.margin_px
    col = (1 + r) / 2 * s.width_px - n / 2
    row = (1 - r) / 2 * s.height_px - n / 2  # y up
    fd = 1.0 / focus_m + np.linspace(-cfg.sweep_d, cfg.sweep_d, cfg.n_sweep)
    fd = fd[(fd > 0) & (fd >= flo - 1e-9) & (fd <= fhi + 1e-9)]
    rng = np.random.default_rng([cfg.seed, int(r * 1000), int(focus_m * 1000)])
    curve = np.zeros(fd.size)
    for _ in range(cfg.n_textures):
        tex = photo_texture(rng, n, n, "train").astype(np.float32)
        img = torch.from_numpy(np.ascontiguousarray(tex.transpose(2, 0, 1)))
        depth = torch.full((n, n), 1.0 / d_star)
        st = sim.render_stack(img, depth, 1.0 / fd, origin=(int(round(row)), int(round(col))))
        frames = st.frames.numpy()
        vol = focus_volume(frames / max(float(frames.max()), 1e-12), cfg.measure, cfg.window_px,
                           prefilter_px=cfg.prefilter_px)
        m = cfg.margin_px
        curve += vol[:, m:m + cfg.crop_px, m:m + cfg.crop_px].mean((1, 2))
    f_peak = _peak_log(fd, curve)
    if not np.isfinite(f_peak):
        return {**out, "offset_diopters": float("nan"), "note": "measure peak outside the sweep"}
    d_at_peak = float(fmap.frame_diopters([1.0 / f_peak], [r], calibrated=False)[0, 0])
    return {**out, "measure_peak_focus_diopters": f_peak, "traced_focus_diopters": 1.0 / focus_m,
            "peak_minus_traced_focus_diopters": f_peak - 1.0 / focus_m,
            "offset_diopters": d_star - d_at_peak}


def offset_grid(fmap: BestFocusMap, points: list[dict]) -> np.ndarray:
    """(R, F) offset_diopters on the map's grid from calibration points (`measure_point`'s dicts).

    A point rendered at frame focus F has its object (the traced D*(r, F)) in focus, by the measure, in the frame
    F_peak; its offset D*(r, F) - D*(r, F_peak) is what the map must add **at F_peak** (there the calibrated map
    then gives the object). It is placed there, not at F: where the measure and the traced min-RMS focus disagree
    by diopters (a phone lens's outer field, where the sagittal and tangential foci lie 2.7 D apart and the
    measure follows one or the other: up to 3.7 D), a point placed at F put its offset on the wrong frames
    (docs/calibration.md). Per calibration radius the offsets are interpolated along F_peak onto the map's focus
    grid (held beyond the points); radii without points take their neighbours' (held beyond the measured radii);
    then onto the map's radii, linearly in r^2."""
    ok = [p for p in points if np.isfinite(p.get("offset_diopters", np.nan))]
    radii = np.array(sorted({float(p["r"]) for p in points}), np.float64)
    fgrid = np.asarray(fmap.focus_diopters, np.float64)
    per_r = np.full((radii.size, fgrid.size), np.nan)
    for i, r in enumerate(radii):
        pts = sorted((p["measure_peak_focus_diopters"], p["offset_diopters"]) for p in ok if float(p["r"]) == r)
        if pts:
            x, y = np.array(pts).T
            per_r[i] = np.interp(fgrid, x, y)
    have = np.isfinite(per_r[:, 0])
    if not have.any():
        return np.zeros_like(np.asarray(fmap.object_diopters, np.float64))
    for j in range(fgrid.size):  # radii without a point: along r (held beyond the measured radii)
        per_r[~have, j] = np.interp(radii[~have], radii[have], per_r[have, j])
    return np.stack([np.interp(fmap.radius ** 2, radii ** 2, per_r[:, j]) for j in range(fgrid.size)], 1)


def calibrate(lens, fmap: BestFocusMap, cfg: CalibrationConfig = CalibrationConfig(), progress: bool = True
              ) -> tuple[BestFocusMap, list[dict]]:
    """The map with `offset_diopters` measured on rendered stacks, and the per-point measurements."""
    sim = _simulator(lens, cfg)
    ranges = renderable_diopters(cfg)
    points = []
    it = [(r, f) for f in cfg.focus_m for r in cfg.radii]
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="calibrating the focus measure's peak", unit="point")
    for r, f in it:
        points.append(measure_point(lens, fmap, r, f, cfg, sim, ranges))
    offset = offset_grid(fmap, points)
    notes = dict(fmap.notes)
    notes["calibration"] = {"what": "offset_diopters = traced object diopters minus those the map gives the frame "
                                    "where the focus measure peaks, on rendered stacks, placed at that frame "
                                    "(training.render.focus_calibration.offset_grid)",
                            "placed_at": "measure_peak",
                            **{k: (list(v) if isinstance(v, tuple) else v) for k, v in cfg.__dict__.items()}}
    return replace(fmap, offset_diopters=offset, notes=notes), points


def make_focus_map(lens_path, calibrate_map: bool = True, psf: str = "trace", progress: bool = True,
                   near_m: float | None = None, calibrate_at_m=None, sweep_d: float | None = None,
                   radii=None, traced: BestFocusMap | None = None, textures: int | None = None,
                   measure: str | None = None, prefilter_px: float | None = None, crop_px: int | None = None
                   ) -> tuple[BestFocusMap, list[dict]]:
    """A lens file's best-focus map as `aat-lens focus-map` stores it: traced (training.optics.field_focus), then
    calibrated on rendered stacks (PSFs: "trace" or a surrogate .onnx), the lens file and the calibration points in
    its notes. Returns (map, calibration points).

    near_m: the map's nearest frame focus (m; None: the focus table's default, 0.2 m); calibrate_at_m / sweep_d:
    the calibration's frame focus settings and sweep (None: CalibrationConfig's, made for 50 mm lenses: a phone
    lens blurs ~30x less per diopter and needs a ~30x wider sweep); radii: the calibration's field radii (None:
    CalibrationConfig's; a lens whose best focus changes steeply at the edge needs them closer there); traced: a
    stored map of this lens whose traced part is kept (its calibration is made again) instead of tracing anew;
    textures: photo textures per point (None: CalibrationConfig's); measure / prefilter_px: the focus measure
    whose peak is calibrated and its pre-filter (None: the runtime's, `aat_deploy.focus.FocusConfig`); crop_px:
    the side of each point's measured patch (None: CalibrationConfig's 64 px; where best focus is curved over the
    patch, its peak is the curve's average over it, not the point's: a phone lens's middle field)."""
    from aat_deploy.lens.io import load_lens
    from training.optics.field_focus import best_focus_map
    from training.psf.geometry import focus_table_reaching

    lens = load_lens(lens_path)
    if traced is not None:
        if traced.lens_hash and traced.lens_hash != lens.prescription_hash():
            raise ValueError(f"the map to recalibrate is of lens {traced.lens_name!r}, not {lens.name!r}")
        notes = {k: v for k, v in traced.notes.items() if k not in ("calibration", "calibration_points")}
        fmap = replace(traced, offset_diopters=None, notes=notes)
    else:
        table = focus_table_reaching(lens, near_m) if near_m is not None else None
        fmap = best_focus_map(lens, table=table, progress=progress)
    points: list[dict] = []
    if calibrate_map:
        over = {k: v for k, v in (("focus_m", tuple(calibrate_at_m) if calibrate_at_m else None),
                                  ("sweep_d", sweep_d), ("radii", tuple(radii) if radii else None),
                                  ("n_textures", textures), ("measure", measure), ("prefilter_px", prefilter_px),
                                  ("crop_px", crop_px))
                if v is not None}
        fmap, points = calibrate(lens, fmap, CalibrationConfig(psf=psf, **over), progress=progress)
    notes = dict(fmap.notes)
    notes["lens_file"] = str(lens_path)
    notes["calibration_points"] = points
    return replace(fmap, notes=notes), points
