"""Why the phone's chart tiles and its truth map disagreed in the outer field (issue 33): astigmatism, and where the
map's calibration put its offsets.

    OMP_NUM_THREADS=1 python -m benchmarks.probes.phone_outer_field [--maps A.json,B.json] [--region middle] \
        [--tiles [--tile-cells 64,16]] [--out results/phone_outer_field.json]    # ~1 min, nothing cached

For a flat object at each chart distance of the benchmark (7, 10, 18 cm), by field radius (corner = 1), four
candidates at once:

1. **astigmatism**: the frame focus (D) in which the object's traced sagittal focus, tangential focus and smallest
   RMS spot (the traced map's definition) lie on the sensor (`sagittal_tangential_foci`: the ray spread along the
   azimuthal and the radial direction minimised separately, design wavelength, the tracer's pupil sampling),
   beside where the runtime's focus measure (`mlap2`, its window and pre-filter) peaks on a rendered patch, and
   where a second derivative along the radial and along the azimuthal direction alone peaks;
2. **the truth map** (`--maps`: by default the phone's map made before the fix, as stored and with its own
   calibration points placed at the frame where the measure peaked, `focus_calibration.offset_grid`, and the map
   made now): the frame focus in which each map puts the object in focus, against the measure's peak;
3. **the tile and the renderer's cell**: the patch's 16 px tiles with the renderer's anchors 16 px apart, 32 px
   (the map calibration's) and 64 px (the chart sweeps' default), and the measure averaged over 32 px tiles;
4. **relative illumination**: not a candidate here. Neither the chart sweeps (`bench_calibrate`: `noise` only, the
   `aberrations` PSFs) nor the map's calibration renders use the `vignetting` effect, and the PSFs are unit-energy
   (`UnitEnergy`); a tile's brightness does not change across the sweep, so it cannot move the peak.

The patch: the top right of the frame (rows 0-192, columns 448-640: field radius 0.45-1, azimuths 8-62 deg), the
chart's dead leaves at the sweeps' scale, grey, noise-free, rendered through the lens's surrogate over a dense sweep
(0.2 D) with the torch-free renderer the sweeps use. Then (`--tiles`) the benchmark's nominal chart sweeps: every
counted tile's peak minus each map's peak for its object, by chart and field zone (`calibrate_phone_offset`),
for the sweeps rendered with each of `--tile-cells` anchor spacings.

`--region middle` (or `middle_diagonal`) puts the patch at field radius 0.2-0.8, where the phone's best focus is
curved between the map's calibration radii 0.3, 0.5 and 0.6; `--renderer torch` renders it with the map
calibration's simulator. `--map-points R,...` runs instead the map's own calibration procedure
(`focus_calibration.measure_point`) at those radii, with the map's photographs or the chart's dead leaves
(`--map-points-texture`), its sweep or a denser one (`--map-points-sweep`), its 64 px crop or another
(`--map-points-crop`), against the map: BENCHMARKS.md, "The anchors against the 48-photograph map".
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks import RESULTS
from benchmarks import bench_calibrate as bc
from benchmarks.bench_calibrate import ROOT

OBJECTS_M = (0.07, 0.1, 0.18)
BINS = ((0.5, 0.6), (0.6, 0.66), (0.66, 0.72), (0.72, 0.78), (0.78, 0.84), (0.84, 0.9), (0.9, 1.0))
REGION = (0, 448, 192)  # row, column, side (px)
# --region middle: a patch right of the centre (field radius 0.2-0.72, azimuths -20 to +20 deg), where the phone's
# best focus swings from 0.9 D beyond the axis's (radius 0.3-0.4) to 0.5 D nearer (0.65), and its map's calibration
# points lie at radius 0.3, 0.5 and 0.6 only
REGIONS = {"outer": (REGION, BINS),
           "middle": ((144, 400, 192), ((0.3, 0.36), (0.36, 0.42), (0.42, 0.48), (0.48, 0.54), (0.54, 0.6),
                                        (0.6, 0.66))),
           # the same radii on the diagonal (azimuths 15-60 deg), where the map's calibration puts its crops
           "middle_diagonal": ((24, 384, 192), ((0.3, 0.36), (0.36, 0.42), (0.42, 0.48), (0.48, 0.54), (0.54, 0.6),
                                                (0.6, 0.66)))}
TILE = 16
# the phone's map as it was made before the fix (offsets placed at the rendering's focus; 5 focus settings; its
# command in models/README.md, of commit 47dfcaf) and as it is now (offsets placed at the measure's peak, 9 settings)
# --tiles: the chart tiles against each map by field radius (the zones split where the phone's field is steep)
TILE_ZONES = ((0.0, 0.33), (0.33, 0.5), (0.5, 0.66), (0.66, 0.75), (0.75, 0.84), (0.84, 0.9), (0.9, 1.01))
MAPS = ("results/cellphone_map_before_placement_fix.json", "lenses/best_focus/cellphone_asphere.json")


def sagittal_tangential_foci(lens, table, r: float, object_m: float, start_d: float) -> dict:
    """Frame focus (diopters) at which the object at object_m, field radius r on the diagonal, has its tangential
    focus (least ray spread along the radial direction), its sagittal focus (along the azimuthal direction) and
    its smallest RMS spot (`training.optics.field_focus`'s definition) on the sensor; secant method in diopters."""
    from training.optics.field_focus import N_RAYS, _pupil, image_shift_mm

    pupil = _pupil(lens, N_RAYS)
    s = lens.sensor
    radial = np.array([s.width_mm, s.height_mm]) / np.hypot(s.width_mm, s.height_mm)  # the diagonal x = y = r
    dirs = {"tangential": radial, "sagittal": np.array([-radial[1], radial[0]]), "min_rms": None}

    def shift(key, focus_d):
        return image_shift_mm(lens, r, object_m, float(table(1.0 / focus_d)), pupil, direction=dirs[key])

    out = {}
    for key in dirs:
        f0, f1 = start_d, start_d + 0.5
        g0, g1 = shift(key, f0), shift(key, f1)
        for _ in range(30):
            if g1 == g0:
                break
            f0, f1, g0 = f1, f1 - g1 * (f1 - f0) / (g1 - g0), g1
            g1 = shift(key, f1)
            if abs(g1) < 1e-6:
                break
        out[key] = float(f1)
    return out


def render_patch(rig, object_m: float, cell_px: int, region=REGION, renderer: str = "runtime"
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(fd (F,) frame focus diopters, frames (F, H, W) grey) of the region's patch of dead leaves at object_m.
    renderer: "runtime" (aat_deploy.render, the chart sweeps' and held-out stacks') or "torch" (training.render's
    Simulator, the best-focus map calibration's: `focus_calibration._simulator`)."""
    import cv2

    from aat_deploy.calibrate.chart import dead_leaves
    from aat_deploy.render import effects as fx
    from aat_deploy.render.layered import LayeredConfig
    from aat_deploy.render.optical import optical_stack
    from aat_deploy.render.sources import GaussianSource

    r0, c0, n = region
    # the chart's texture at the sweeps' scale: 3 chart pixels per sensor pixel, leaves 1.5 chart px to a tenth
    # of the chart's height (bench_calibrate.chart_for)
    tex = dead_leaves(3 * n, 3 * n, 1.5, 0.1 * 3 * rig.h * 1.3, np.random.default_rng(3))
    tex = cv2.resize(tex, (n, n), interpolation=cv2.INTER_AREA).astype(np.float32) / 255 * 0.6
    fd = np.arange(max(0.6, 1 / object_m - 8), min(19.9, 1 / object_m + 3), 0.2)
    if renderer == "torch":
        import torch

        from training.render.layered import LayeredConfig as TorchLayered
        from training.render.simulator import Simulator
        from training.render.sources import OnnxPSF

        torch.set_num_threads(1)
        sim = Simulator(rig.lens, OnnxPSF.from_source(rig.src), fx.parse(["aberrations"]),
                        TorchLayered(cell_px=cell_px))
        st = sim.render_stack(torch.from_numpy(np.repeat(tex[None], 3, 0)), torch.full((n, n), object_m), 1.0 / fd,
                              origin=(r0, c0), rng=np.random.default_rng(0))
        return fd, st.frames.numpy().mean(1)
    ctx = fx.SimContext(rig.lens, (rig.h, rig.w), (r0, c0), rig.src, rig.src.focus_table(),
                        rig.src.exit_pupil_z_mm())
    fr = optical_stack(fx.parse(["aberrations"]), GaussianSource(rig.lens), np.repeat(tex[None], 3, 0),
                       np.full((n, n), object_m, np.float32), 1.0 / fd, ctx, LayeredConfig(cell_px=cell_px), 1)
    return fd, fr.mean(1)


def directional_energy(frames: np.ndarray, radial: bool, window_px: float, prefilter_px: float,
                       hw: tuple[int, int], region=REGION) -> np.ndarray:
    """(F, H, W) windowed squared second derivative of each (pre-filtered) frame along each pixel's radial (or
    azimuthal) direction from the frame centre: the measure's energy for detail of one orientation."""
    import cv2

    from aat_deploy.focus.measures import _window

    r0, c0, n = region
    rows, cols = np.mgrid[r0:r0 + n, c0:c0 + n]
    x, y = cols + 0.5 - hw[1] / 2, -(rows + 0.5 - hw[0] / 2)  # from the frame centre, y up
    ux, uy = x / np.hypot(x, y), y / np.hypot(x, y)
    if not radial:
        ux, uy = -uy, ux
    out = []
    for f in frames:
        b = cv2.GaussianBlur(f, (0, 0), prefilter_px)
        ixx, iyy = cv2.Sobel(b, cv2.CV_32F, 2, 0, ksize=3), cv2.Sobel(b, cv2.CV_32F, 0, 2, ksize=3)
        ixy = -cv2.Sobel(b, cv2.CV_32F, 1, 1, ksize=3)  # d/dy with y up
        d = ux * ux * ixx + 2 * ux * uy * ixy + uy * uy * iyy
        out.append(_window(d * d, window_px))
    return np.stack(out)


def tile_peaks(fd: np.ndarray, vol: np.ndarray, tile: int) -> tuple[np.ndarray, np.ndarray]:
    """(peaks (ny, nx) frame focus D, bimodal (ny, nx) bool: a second local maximum above half the peak)."""
    from training.render.focus_calibration import _peak_log

    n = vol.shape[-1] // tile
    cur = vol[:, :n * tile, :n * tile].reshape(len(fd), n, tile, n, tile).mean((2, 4)).astype(np.float64)
    pk = np.array([[_peak_log(fd, cur[:, i, j]) for j in range(n)] for i in range(n)])
    c = cur / cur.max(0)
    loc = (c[1:-1] > c[:-2]) & (c[1:-1] >= c[2:]) & (c[1:-1] > 0.5)
    return pk, loc.sum(0) > 1


def truth_focus(fmap, object_m: float, radius: np.ndarray) -> np.ndarray:
    """Frame focus (D) in which the map puts object_m in focus at each radius (NaN where not monotone)."""
    fg = np.linspace(0.5, 20.0, 4000)
    t = fmap.frame_diopters(1.0 / fg, radius.ravel())
    out = np.array([np.interp(1 / object_m, t[:, j], fg) if np.all(np.diff(t[:, j]) > 0) else np.nan
                    for j in range(radius.size)])
    return out.reshape(radius.shape)


def replaced(fmap):
    """The stored map with its own calibration points placed at the frame where the measure peaked."""
    import dataclasses

    from training.render.focus_calibration import offset_grid

    return dataclasses.replace(fmap, offset_diopters=offset_grid(fmap, fmap.notes["calibration_points"]))


def chart_texture(rig):
    """A stand-in for `photo_texture` drawing the chart's dead leaves at the sweeps' scale instead (as `render_patch`):
    (n, n, 3) float32, a new draw per call."""
    import cv2

    from aat_deploy.calibrate.chart import dead_leaves

    def draw(rng, h, w, split="train"):
        tex = dead_leaves(3 * h, 3 * w, 1.5, 0.1 * 3 * rig.h * 1.3, rng)
        tex = cv2.resize(tex, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
        return np.repeat(tex[:, :, None], 3, 2)
    return draw


def map_points(fmap, radii: list[float], focus_m=(0.07, 0.1, 0.18), texture: str = "photos",
               n_sweep: int | None = None, crop_px: int | None = None) -> list[dict]:
    """The map's own calibration procedure (`focus_calibration.measure_point`: its photographs, seed, sweep, crop and
    32 px anchors, from the map's notes) at field radii between its points: where the measure peaks for the object
    the traced map puts in focus at each focus setting, against where the calibrated map (interpolated there) says.
    At the map's own radii the difference is its points' texture noise; between them, also the interpolation.
    texture "chart": the same with the chart's dead leaves instead of the photographs (`chart_texture`); n_sweep:
    frames over the same +-sweep_d (the map's 21 are 0.55 D apart on the phone); crop_px: the measured patch's side
    (the map's 64 px span field radius +-0.08 on the diagonal, over which the phone's best focus is curved)."""
    import dataclasses as dc
    from unittest import mock

    from training.render.focus_calibration import CalibrationConfig, _simulator, measure_point

    c = fmap.notes["calibration"]
    cfg = CalibrationConfig(**{f.name: (tuple(c[f.name]) if isinstance(c[f.name], list) else c[f.name])
                               for f in dc.fields(CalibrationConfig) if f.name in c})
    cfg = cfg if n_sweep is None else dc.replace(cfg, n_sweep=n_sweep)
    cfg = cfg if crop_px is None else dc.replace(cfg, crop_px=crop_px)
    rig = bc.Rig(bc.LENSES["cellphone"])
    sim = _simulator(rig.lens, cfg)
    out = []
    for f in focus_m:
        for r in radii:
            if texture == "chart":
                with mock.patch("training.data.textures.photo_texture", chart_texture(rig)):
                    p = measure_point(rig.lens, fmap, r, f, cfg, sim=sim)
            else:
                p = measure_point(rig.lens, fmap, r, f, cfg, sim=sim)
            if not np.isfinite(p.get("offset_diopters", np.nan)):
                continue
            d = p["traced_object_diopters"]
            mapped = float(truth_focus(fmap, 1.0 / d, np.array([r]))[0])
            out.append({"texture": texture, "n_sweep": cfg.n_sweep, "crop_px": cfg.crop_px, "focus_m": f, "r": r,
                        "object_d": d, "measure_peak_d": p["measure_peak_focus_diopters"], "map_peak_d": mapped,
                        "measure_minus_map_d": p["measure_peak_focus_diopters"] - mapped})
            print(f"  map point r {r:g}, focus {f:g} m: measure {p['measure_peak_focus_diopters']:.2f}, map "
                  f"{mapped:.2f} D", file=sys.stderr, flush=True)
    return out


def main(argv=None) -> int:
    from aat_deploy.focus import FocusConfig
    from aat_deploy.focus.bestfocus import load_json
    from aat_deploy.focus.measures import focus_volume

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--maps", default=",".join(MAPS), help="truth maps to compare, comma-separated (a map made "
                    "before the fix is also shown with its own points placed at the measure's peak)")
    ap.add_argument("--tiles", action="store_true", help="also the benchmark's nominal chart tiles against each map")
    ap.add_argument("--tile-cells", default="64", help="the chart sweeps' anchor spacings (px) for --tiles, "
                    "comma-separated (bench_calibrate --cell-px: 16 needs its sweeps rendered or cached)")
    ap.add_argument("--map-points", default=None, metavar="R,R,...",
                    help="only: the map's own calibration procedure at these field radii (`map_points`, ~10 s each "
                         "per focus setting), against the lens's map; written to --out")
    ap.add_argument("--map-points-texture", default="photos", help="photos (the map's), chart (the chart's dead "
                    "leaves) or both, comma-separated")
    ap.add_argument("--map-points-sweep", default="", help="frames of the map-point sweeps over the map's range, "
                    "comma-separated (empty: the map's own count)")
    ap.add_argument("--renderer", choices=("runtime", "torch"), default="runtime",
                    help="the patch's renderer: the sweeps' (runtime) or the map calibration's (torch)")
    ap.add_argument("--map-points-crop", default="", help="the map-point patches' side (px), comma-separated "
                    "(empty: the map's own)")
    ap.add_argument("--region", choices=sorted(REGIONS), default="outer",
                    help="the patch: the top right (outer, radius 0.45-1), right of the centre (middle, 0.2-0.72) "
                         "or on the diagonal (middle_diagonal, 0.2-0.8)")
    ap.add_argument("--out", default=None, help="default results/phone_outer_field.json (results/phone_"
                    "middle_field.json with --region middle)")
    a = ap.parse_args(argv)
    region, bins = REGIONS[a.region]
    a.out = a.out or str(RESULTS / ("phone_outer_field.json" if a.region == "outer"
                                    else f"phone_{a.region}_field.json"))
    if a.map_points:
        from aat_deploy.io.atomic import write_text_atomic

        fm, radii = bc.Rig(bc.LENSES["cellphone"]).fmap, [float(r) for r in a.map_points.split(",")]
        pts = [q for t in a.map_points_texture.split(",") for n in a.map_points_sweep.split(",")
               for c in a.map_points_crop.split(",")
               for q in map_points(fm, radii, texture=t, n_sweep=int(n) if n else None,
                                   crop_px=int(c) if c else None)]
        write_text_atomic(Path(a.out), json.dumps({"map_points": pts}, indent=1))
        print("| texture | sweep frames | crop (px) | focus (m) | field radius | object (D) | measure's peak (D) | "
              "the map's (D) | measure - map (D) |\n|---|---|---|---|---|---|---|---|---|")
        for q in pts:
            print(f"| {q['texture']} | {q['n_sweep']} | {q['crop_px']} | {q['focus_m']:g} | {q['r']:g} | "
                  f"{q['object_d']:.2f} | {q['measure_peak_d']:.2f} | {q['map_peak_d']:.2f} | "
                  f"{q['measure_minus_map_d']:+.2f} |")
        return 0
    rig = bc.Rig(bc.LENSES["cellphone"])
    maps = {}
    for p in a.maps.split(","):
        m = load_json(ROOT / p)
        maps[Path(p).name] = m
        if m.notes.get("calibration", {}).get("placed_at") != "measure_peak":  # made before the fix
            maps[f"{Path(p).name}, its points placed at F_peak"] = replaced(m)
    cfg = FocusConfig()
    r0, c0, n = region
    rt = rig.fmap.radius_px(rig.h, rig.w)[r0:r0 + n, c0:c0 + n]
    rows = []
    for obj in OBJECTS_M:
        fd, fr = render_patch(rig, obj, 16, region, a.renderer)
        _, fr64 = render_patch(rig, obj, 64, region, a.renderer)
        _, fr32 = render_patch(rig, obj, 32, region, a.renderer)
        peak, bimodal = tile_peaks(fd, focus_volume(fr, cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px),
                                   TILE)
        peak64, _ = tile_peaks(fd, focus_volume(fr64, cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px),
                               TILE)
        peak32, _ = tile_peaks(fd, focus_volume(fr, cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px), 32)
        peak_c32, _ = tile_peaks(fd, focus_volume(fr32, cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px),
                                 TILE)
        rad, _ = tile_peaks(fd, directional_energy(fr, True, cfg.window_px, cfg.prefilter_px, (rig.h, rig.w),
                                                   region), TILE)
        azi, _ = tile_peaks(fd, directional_energy(fr, False, cfg.window_px, cfg.prefilter_px, (rig.h, rig.w),
                                                   region), TILE)
        m = n // TILE
        r16 = rt[:m * TILE, :m * TILE].reshape(m, TILE, m, TILE).mean((1, 3))
        m32 = n // 32
        r32 = rt[:m32 * 32, :m32 * 32].reshape(m32, 32, m32, 32).mean((1, 3))
        truths = {k: truth_focus(v, obj, r16) for k, v in maps.items()}
        for lo, hi in bins:
            z, z32 = (r16 >= lo) & (r16 < hi), (r32 >= lo) & (r32 < hi)
            foci = sagittal_tangential_foci(rig.lens, rig.src.focus_table(), float(r16[z].mean()), obj,
                                            float(np.nanmean(peak[z])))
            row = {"object_m": obj, "radius": [lo, hi], "tiles": int(z.sum()), "radius_mean": float(r16[z].mean()),
                   "traced_focus_d": foci, "mlap2_peak_d": float(np.nanmean(peak[z])),
                   "mlap2_peak_sd_d": float(np.nanstd(peak[z])),
                   "radial_peak_d": float(np.nanmean(rad[z])), "azimuthal_peak_d": float(np.nanmean(azi[z])),
                   "bimodal_frac": float(bimodal[z].mean()),
                   "cells64_minus_cells16_d": float(np.nanmean(peak64[z] - peak[z])),
                   "cells32_minus_cells16_d": float(np.nanmean(peak_c32[z] - peak[z])),
                   "tile32_minus_tile16_d": (float(np.nanmean(peak32[z32])) - float(np.nanmean(peak[z]))
                                             if z32.any() else None),
                   "maps_focus_d": {k: float(np.nanmean(v[z])) for k, v in truths.items()}}
            rows.append(row)
            print(f"  {obj:g} m, radius {lo:g}-{hi:g}: mlap2 {row['mlap2_peak_d']:.2f}, traced S "
                  f"{foci['sagittal']:.2f} T {foci['tangential']:.2f}", file=sys.stderr, flush=True)
    tiles = []
    if a.tiles:
        from benchmarks.probes.calibrate_phone_offset import part_tiles_vs_truth

        for cells in (int(c) for c in a.tile_cells.split(",")):
            rc = bc.Rig(dataclasses.replace(bc.LENSES["cellphone"], cell_px=cells))
            sw = [bc.sweep(rc, "nominal", i, lambda m: None) for i in range(3)]
            ms = bc.measures(rc, sw, "nominal")
            for k, v in maps.items():
                rc.fmap = v
                tiles += [{"map": k, "cell_px": cells, **t} for t in part_tiles_vs_truth(rc, ms, TILE_ZONES)]
    from aat_deploy.io.atomic import write_text_atomic

    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(a.out), json.dumps({"maps": list(maps), "rows": rows, "tiles": tiles}, indent=1))
    print(table(rows, list(maps)))
    if tiles:
        print("\n| map | anchors (px) | chart (m) | field radius | tiles | tile peak - map's peak: mean (SD) (D) |\n"
              "|---|---|---|---|---|---|")
        for t in tiles:
            print(f"| {t['map']} | {t.get('cell_px', 64)} | {t['chart_m']:g} | "
                  f"{t['zone'][0]:g}-{min(t['zone'][1], 1):g} | {t['tiles']} | {t['mean_d']:+.3f} ({t['sd_d']:.3f}) |")
    return 0


def table(rows: list[dict], maps: list[str]) -> str:
    out = ["| object (m) | field radius | traced focus: tangential / min RMS / sagittal (D) | measure's peak: radial "
           "detail / mlap2 (SD) / azimuthal detail (D) | two peaks | " + " | ".join(f"{m} (D)" for m in maps)
           + " | anchors 64 px - 16 px (D) | anchors 32 px - 16 px (D) | 32 px tiles - 16 px (D) |",
           "|---|---|---|---|---|" + "---|" * len(maps) + "---|---|---|"]
    for r in rows:
        t = r["traced_focus_d"]
        t32 = "" if r["tile32_minus_tile16_d"] is None else f"{r['tile32_minus_tile16_d']:+.2f}"
        out.append(f"| {r['object_m']:g} | {r['radius'][0]:g}-{r['radius'][1]:g} | {t['tangential']:.2f} / "
                   f"{t['min_rms']:.2f} / {t['sagittal']:.2f} | {r['radial_peak_d']:.2f} / {r['mlap2_peak_d']:.2f} "
                   f"({r['mlap2_peak_sd_d']:.2f}) / {r['azimuthal_peak_d']:.2f} | {r['bimodal_frac']:.0%} | "
                   + " | ".join(f"{r['maps_focus_d'][m]:.2f}" for m in maps)
                   + f" | {r['cells64_minus_cells16_d']:+.2f} | {r['cells32_minus_cells16_d']:+.2f} | {t32} |")
    return "\n".join(out)


if __name__ == "__main__":
    raise SystemExit(main())
