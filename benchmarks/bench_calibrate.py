"""Calibrating a camera from chart sweeps (aat-calibrate, aat_deploy/calibrate) against the truth of a rendered copy.

    OMP_WAIT_POLICY=PASSIVE flock /work/heavy.lock nice -n 10 python -m benchmarks.bench_calibrate \
        [--lenses rf50,paper50,ef50] [--n 24] [--parts map,depth,needs] [--boot 100]

Lenses: rf50, paper50, ef50 (the 50 mm lenses with PSF surrogates and best-focus maps), cellphone (the phone lens,
lenses/cellphone_asphere.json, in its working range: surrogate models/psf_cellphone.onnx over 0.05-2 m, charts at
7-18 cm, depth stacks 0.07-0.5 m) and z35 (the phone-sized Z35 as DiffOptics scaled it, 0.84 px of blur per
diopter: its sweeps are refused, since its surrogate's 0.2-5 m focus range lets them reach under 4 px of blur beyond
the chart; the table says so). The phone-sized lenses' sweeps are designed from their blur per diopter
(`sweep_diopters`).

Setup, per lens (its PSF surrogate, its best-focus map in lenses/best_focus/, its tolerance table):
- **nominal**: the lens as its prescription says, sensor noise on (8000 e- full well);
- **a real copy**: one element decentred (`lens_tolerance`), the sensor tilted (`sensor_tilt`), the reported focus
  distance 1.1 x the true one (`focus_metadata` scale), noise on.
The virtual camera (`aat_deploy.capture.virtual.shoot`, torch-free) shoots the chart (`aat-calibrate chart`'s
dead leaves + ArUco) at three distances, each chart filling the frame (1.3 x its width), tilted 8-12 deg, in a
sweep 0.04 D apart from 0.3 D beyond the chart on either side. The chart distances given to the fit are the
true ones plus a tape-measure error (2 mm SD, seeded); the entrance pupil is not given (the fit assumes a focal
length, as for a user without a prescription). Fit: `aat_deploy.calibrate.fit` as `aat-calibrate fit` runs it.

The truth: a frame truly focused at F has in best focus, at field (x, y), what the nominal lens's calibrated
best-focus map (the focus measure's peak: docs/focus_method.md) gives for the focus the copy's sensor shifts make
there (`effects.focus_at`): the renderer's own PSFs are the nominal lens's at that focus.

a) **map**: the calibration's in-focus diopters against the truth over every pixel, RMS and 95th percentile of
   |error|, over reported focus settings inside the calibrated range and over the depth schedule (8 frames,
   0.5-10 m; the phone 0.07-0.5 m); beside it the nominal prescription's map and the thin lens (both fed the
   reported focus).
b) **depth**: held-out scenes (`training.train.testsets`: procedural scenes with test-split photographs, their own
   seed, and Middlebury Motorcycle; the phone: procedural only, 0.07-0.5 m) rendered through the copy, 8 frames
   even in diopters over the schedule, the classical
   method (`aat_deploy.focus.classical_depth`, its defaults) with four mappings of the reported focus: thin lens,
   the nominal prescription's map, the calibration, the oracle (the copy's truth per pixel). MAE over all valid
   pixels and in the outer field (normalised radius > 0.66), and in diopters (|1/z - 1/z_true|, which weighs near
   and far alike), mean over scenes with 95 % bootstrap intervals;
   paired ratios calibration / oracle and calibration / prescription (scenes resampled).
c) **needs**: the map's RMS error with fewer chart distances and sparser sweeps (the same renders, subsets).
d) **blind** (`aat-calibrate fit --from-scenes`): wide procedural worlds (test-split photographs, their own seed),
   each seen by the copy turned by -6, 0 and +6 deg in yaw and pitch (9 captures per world, 8 frames 0.5-10 m);
   the field term (in focus at (x, y) minus at the centre) against the truth's over the schedule, RMS, as the
   number of captures grows; beside it the chart calibration's, the prescription map's and none (thin lens).

Renders are cached under cache/calibrate/ (sweeps) and cache/heldout/ (test stacks, by content).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from aat_deploy.eval.stats import N_BOOT, bootstrap_mean, field_radius, paired_ratio, zone_masks  # every DfF table's
from aat_deploy.eval.stats import fmt_interval as fmt
from aat_deploy.optics.focus_table import diopter_grid  # the one even-in-diopters schedule
from benchmarks import RESULTS

ROOT = Path(__file__).resolve().parents[1]

CACHE = ROOT / "cache" / "calibrate"
SOFT_SENSOR_PX = 0.7  # = aat_deploy.calibrate.chart.SOFT_SENSOR_PX (tests/test_bench_calibrate.py checks it)
SCALE = 1.1  # the copy's reported distance / true distance
TAPE_SD_MM = 2.0
# field-radius bins of the map's error by radius (finer than the zones where the phone's outer field is steep)
RADIUS_EDGES = (0.0, 0.33, 0.5, 0.66, 0.75, 0.84, 0.9, 1.0)


@dataclasses.dataclass(frozen=True)
class LensSetup:
    key: str
    lens: str
    psf: str
    distances_m: tuple
    tilts: tuple  # per distance (tilt_x, tilt_y) deg
    copy_effects: tuple
    tolerance_table: str | None = None  # None: next to the surrogate (models/)
    step_d: float | None = 0.04  # the chart sweeps' focus step and how far they reach beyond the chart (D);
    margin_d: float | None = 0.3  # None: from the lens's blur per diopter (`sweep_diopters`)
    marker_frac: float | None = None  # marker side / grid spacing (None: the chart's default, a quarter)
    schedule_m: tuple = (0.5, 10.0)  # the depth stacks' 8 frames (even in diopters) and their scenes' range (m)
    middlebury: bool = True  # Middlebury Motorcycle among the held-out stacks (its depths are 1-2 m)
    cell_px: int = 64  # the renderer's PSF anchor spacing (px) for the chart sweeps and the held-out stacks (--cell-px)
    copy_name: str = "copy"  # the copy's chart sweeps' cache name (random copies, --copies: benchmarks/calibrate_copies)
    inside_m: tuple | None = None  # part a's "inside" range (m; None: the charts' nearest and farthest distance)
    sweep_key: str | None = None  # the sweeps' cache name (None: key): a setup that adds charts reuses the others'
    fit_distance: tuple = ()  # indices of the charts whose distance the fit takes as an unknown (the tape's only a start)
    step_px: float | None = None  # the sweeps' step in px of thin-lens blur where designed from it (None: SWEEP_STEP_PX)
    chart_texture: str = "dead leaves"  # the chart's texture: `aat-calibrate chart`'s, or a probe's
    # (benchmarks/probes/chart_texture.texture_for: sweeps cached under their own name)
    # the texture's softening in sensor px at the chart (`aat-calibrate chart --frame-px`'s; 0: the sharp dead
    # leaves of the sweeps before 2026-11-27 05:00 UTC, cached without the `_soft` suffix)
    chart_soften_px: float = SOFT_SENSOR_PX

    def inside(self) -> np.ndarray:
        """Part a's 10 reported-focus settings "inside" (true focus, m, near to far: even in diopters)."""
        lo, hi = self.inside_m or (min(self.distances_m), max(self.distances_m))
        return diopter_grid(hi, lo, 10)

    def schedule(self) -> np.ndarray:
        """The depth stacks' 8 true focus distances (m, near to far)."""
        return diopter_grid(self.schedule_m[1], self.schedule_m[0], 8)


LENSES = {
    "rf50": LensSetup("rf50", "lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", (0.6, 1.2, 3.0),
                      ((12, 4), (-9, -3), (8, 0)),
                      ("lens_tolerance:element=2:decentre_x_mm=0.1", "sensor_tilt:tilt_x_deg=0.5:tilt_y_deg=-0.3",
                       f"focus_metadata:bias_d=0:scale={SCALE}", "noise")),
    "paper50": LensSetup("paper50", "lenses/paper_50mm_f2.8.json", "models/psf_paper50.onnx", (0.6, 1.2, 3.0),
                         ((12, 4), (-9, -3), (8, 0)),
                         ("lens_tolerance:element=1:decentre_x_mm=0.1", "sensor_tilt:tilt_x_deg=0.5:tilt_y_deg=-0.3",
                          f"focus_metadata:bias_d=0:scale={SCALE}", "noise"),
                         tolerance_table="cache/tolerance/auto"),
    "ef50": LensSetup("ef50", "lenses/canon_ef50mm_f1.8.json", "models/psf_ef50.onnx", (0.6, 1.2, 3.0),
                      ((12, 4), (-9, -3), (8, 0)),
                      ("lens_tolerance:element=2:decentre_x_mm=0.1", "sensor_tilt:tilt_x_deg=0.5:tilt_y_deg=-0.3",
                       f"focus_metadata:bias_d=0:scale={SCALE}", "noise"),
                      tolerance_table="cache/tolerance/auto"),
    # the phone-sized Z35 (EFL 1.57 mm, 0.84 px of blur per diopter; its aspheres were misread until 2026-11-26);
    # its tolerances scaled to its size (3 um decentre, 0.1 deg tilt: each about 0.3-0.5 D at the edge; the table:
    # `python -m scripts.lens_tolerance_table lenses/nikon_z35_f1.8_diffoptics.json --out cache/tolerance
    # --focus-m 0.2,0.6,5`), the charts nearer and the sweeps designed in pixels of blur (a 0.04 D step would move
    # its blur by 0.03 px). Still refused: its surrogate's focus range (0.2-5 m) holds only 4 px of blur in all, so
    # no sweep reaches the RF50's half-fall (HALF_FALL_PX) on both sides of a chart; it needs a surrogate and charts
    # nearer (as the phone lens's: 0.05-2 m, charts at 7-18 cm)
    "z35": LensSetup("z35", "lenses/nikon_z35_f1.8_diffoptics.json", "models/psf_z35.onnx", (0.3, 0.6, 1.5),
                     ((12, 4), (-9, -3), (8, 0)),
                     ("lens_tolerance:element=3:decentre_x_mm=0.003", "sensor_tilt:tilt_x_deg=0.1:tilt_y_deg=-0.06",
                      f"focus_metadata:bias_d=0:scale={SCALE}", "noise"),
                     tolerance_table="cache/tolerance/auto", step_d=None, margin_d=None, marker_frac=0.45),
    # the phone lens (EFL 5.6 mm f/2.8, 640 x 480 at 8.9 um: 1.26 px of blur per diopter) in its working range: its
    # surrogate (configs/psf_cellphone.json) covers 0.05-2 m, its map was calibrated with sweeps widened to its blur
    # (aat-lens focus-map --recalibrate ... --sweep-d 5.5: models/README.md); charts at 7-18 cm, sweeps
    # designed in pixels of blur, depth stacks 0.07-0.5 m (no Middlebury: its scene lies at 1-2 m); a copy with a
    # phone's tolerances (the second element decentred 5 um: about 0.6 D at the edge; the sensor tilted 0.3 deg: 0.5 D)
    "cellphone": LensSetup("cellphone", "lenses/cellphone_asphere.json", "models/psf_cellphone.onnx",
                           (0.07, 0.1, 0.18), ((12, 4), (-9, -3), (8, 0)),
                           ("lens_tolerance:element=1:decentre_x_mm=0.005",
                            "sensor_tilt:tilt_x_deg=0.3:tilt_y_deg=-0.2",
                            f"focus_metadata:bias_d=0:scale={SCALE}", "noise"),
                           step_d=None, margin_d=None, schedule_m=(0.07, 0.5), middlebury=False),
}
# The phone with a fourth chart nearer than its working range (5.5 cm, appended so the other three keep their
# sweeps, seeds and tape errors; part a scored over the same 7-18 cm): under its field curvature the edge of a frame
# focused at 7 cm has objects at 4.5-5.5 cm in focus, which no chart at 7 cm or farther shows there
# (benchmarks/probes/phone_map_budget.py); a chart at 5.5 cm is sharp at the edge for frames focused at 7-9 cm.
# Its distance is an unknown of the fit (`aat-calibrate fit --distance-m ...,~0.055`): the tape's 2 mm would put it
# 0.6 D off (its draw here is -1.8 mm), and the fit finds it from the sweeps' consistency. Its sweeps are twice as
# dense (0.7 px of blur per step, 0.55 D: 21-33 frames): with the near chart that took part a from 0.153-0.166 to
# 0.130-0.138 D on the hand-chosen copy and the three random ones (without it, 0.155-0.188 to 0.191-0.209 D);
# BENCHMARKS.md, "The phone's near chart".
LENSES["cellphone_near"] = dataclasses.replace(
    LENSES["cellphone"], key="cellphone_near", distances_m=(0.07, 0.1, 0.18, 0.055),
    tilts=((12, 4), (-9, -3), (8, 0), (6, 3)), inside_m=(0.07, 0.18), sweep_key="cellphone", fit_distance=(3,),
    step_px=0.7)
NOMINAL = ("noise",)
# Sweeps designed in pixels of blur (setups without step_d / margin_d): the RF50's sweeps are 1.4 px of thin-lens
# blur per step and reach 10 px beyond the chart; their tiles' focus curves fall to half 3.4-4.0 px from the peak
# (90 % within 4.1-4.8 px, all within 6.1 px). At least MIN_SWEEP_FRAMES frames; never beyond the PSF surrogate's
# focus range (it clamps there: the frame would be rendered at another focus than its metadata says).
SWEEP_STEP_PX, SWEEP_MARGIN_PX, MIN_SWEEP_FRAMES = 1.4, 10.0, 15
HALF_FALL_PX = (3.4, 4.0)  # where the RF50's tile curves fall to half (px of blur from the peak)


def sweep_diopters(rig, near_d: float, far_d: float) -> np.ndarray:
    """The sweep's true focus settings (diopters, ascending) for a chart spanning far_d..near_d diopters: the
    setup's step and margin, or, without them, SWEEP_STEP_PX and SWEEP_MARGIN_PX of the lens's thin-lens blur per
    diopter, clipped to the surrogate's focus range (a sweep clipped there keeps MIN_SWEEP_FRAMES frames)."""
    s = rig.setup
    if s.step_d is not None:
        return np.arange(far_d - s.margin_d, near_d + s.margin_d + 1e-9, s.step_d)
    flo, fhi = rig.src.model.focus_range_m
    lo, hi = max(far_d - SWEEP_MARGIN_PX / rig.blur_px_per_d, 1.0 / fhi), \
        min(near_d + SWEEP_MARGIN_PX / rig.blur_px_per_d, 1.0 / flo)
    step = min((s.step_px or SWEEP_STEP_PX) / rig.blur_px_per_d, (hi - lo) / (MIN_SWEEP_FRAMES - 1))
    return np.linspace(lo, hi, int(np.ceil((hi - lo) / step - 1e-9)) + 1)


def effects_for(setup: LensSetup, variant: str) -> list[str]:
    if variant == "nominal":
        return list(NOMINAL)
    out = []
    for e in setup.copy_effects:
        if e.startswith("lens_tolerance") and setup.tolerance_table:
            out.append(f"{e}:table={tolerance_path(setup)}")
        else:
            out.append(e)
    return out


def tolerance_path(setup: LensSetup) -> Path:
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import table_name

    folder = ROOT / Path(setup.tolerance_table).parent
    return folder / table_name(load_lens(ROOT / setup.lens))


def _repo_relative(path: Path) -> Path:
    return path.relative_to(ROOT) if path.is_relative_to(ROOT) else path


def check_tolerance_table(setup: LensSetup) -> None:
    """SystemExit (one line, with the command that makes it) when the copy's tolerance table is not there: its
    name carries the lens's optics key, so a corrected lens file (the Z35, 2026-11-26) needs a new one, and the
    copy's renders would otherwise stop after the nominal sweeps."""
    if not setup.tolerance_table:
        return
    t = tolerance_path(setup)
    if not t.is_file():
        raise SystemExit(f"{t}: no tolerance table for {setup.lens} (its optics key); make it with `python -m "
                         f"scripts.lens_tolerance_table {setup.lens} --out {_repo_relative(t.parent)}` "
                         "(add --focus-m for a lens not focused at 0.5-20 m)")


class Rig:
    """A lens with its surrogate, map, geometry and the effects' context. truth_map: the best-focus map that is the
    truth and the prescription's map (default lenses/best_focus/<lens stem>.json); measure / prefilter_px: the focus
    measure the chart fit uses (default the runtime's), which must be the one truth_map was calibrated with."""

    def __init__(self, setup: LensSetup, truth_map: str | None = None, measure: str | None = None,
                 prefilter_px: float | None = None, truth: str | None = None):
        from aat_deploy.focus.bestfocus import load_json
        from aat_deploy.lens.io import load_lens
        from aat_deploy.optics.paraxial import paraxial_data
        from aat_deploy.render.sources import OnnxSource

        self.setup = setup
        self.lens = load_lens(ROOT / setup.lens)
        self.src = OnnxSource(ROOT / setup.psf, self.lens, threads=1)  # heavy jobs run single-threaded
        from aat_deploy.focus import FocusConfig

        self.fmap = load_json(ROOT / truth_map if truth_map else
                              ROOT / "lenses" / "best_focus" / f"{Path(setup.lens).stem}.json")
        # truth: a render-consistent truth map (benchmarks/render_truth_map.py) that replaces fmap as the truth only
        # (parts a and c); fmap stays the prescription's map. None: fmap is both (the benchmark's default)
        self.truth_map = None
        if truth is not None:
            from benchmarks.render_truth_map import TruthMapError, load

            try:
                self.truth_map = load(truth)
            except TruthMapError as e:
                raise SystemExit(f"bench_calibrate: --truth {e}") from None
        base = FocusConfig()
        self.measure = measure or base.measure
        self.prefilter_px = base.prefilter_px if prefilter_px is None else float(prefilter_px)
        cal = self.fmap.notes.get("calibration", {})
        made = (cal.get("measure", base.measure), float(cal.get("prefilter_px", base.prefilter_px)))
        if made != (self.measure, self.prefilter_px):
            raise SystemExit(f"bench_calibrate: the truth map was calibrated for measure {made[0]} with a "
                             f"{made[1]:g} px pre-filter, the fit would use {self.measure} with "
                             f"{self.prefilter_px:g} px: give --truth-map a map of that measure")
        p = paraxial_data(self.lens)
        s = self.lens.sensor
        self.w, self.h = s.width_px, s.height_px
        self.f_px = p.efl_mm / s.pixel_mm
        self.efl, self.fno = p.efl_mm, p.fno
        self.pupil = p.total_track_mm + p.bfl_mm - p.entrance_pupil_z_mm
        self.blur_px_per_d = p.entrance_pupil_mm * p.efl_mm / s.pixel_mm / 1000.0  # thin lens, far focus

    def with_setup(self, setup: LensSetup) -> "Rig":
        """The same rig (lens, surrogate, map, measure) for another setup of the same lens (a random copy)."""
        import copy

        if setup.lens != self.setup.lens or setup.psf != self.setup.psf:
            raise ValueError(f"Rig.with_setup: {setup.key} is another lens")
        out = copy.copy(self)
        out.setup = setup
        return out

    def ctx(self):
        from aat_deploy.render import effects as fx

        return fx.SimContext(self.lens, (self.h, self.w), (0, 0), self.src, self.src.focus_table(),
                             self.src.exit_pupil_z_mm())

    def truth(self, effects: list[str], true_focus_m, h: int | None = None, w: int | None = None) -> np.ndarray:
        """(S, H, W) diopters in best focus (the measure's peak) for frames truly focused at true_focus_m."""
        from aat_deploy.calibrate.format import field_grid
        from aat_deploy.render import effects as fx

        h, w = h or self.h, w or self.w
        fn = fx.focus_at(fx.parse(effects), self.ctx())
        x, y = field_grid(h, w)
        if self.truth_map is not None:  # the render-consistent truth, per pixel at its own focus
            r = self.fmap.radius_px(h, w).astype(np.float64).ravel()
            out = []
            for f in np.ravel(true_focus_m):
                fd = 1.0 / (fn(x, y, float(f)) if fn is not None else np.full((h, w), float(f)))
                out.append(self.truth_map.object_d(r, np.asarray(fd, np.float64).ravel()).reshape(h, w))
            return np.stack(out).astype(np.float32)
        r2 = (self.fmap.radius_px(h, w).astype(np.float64)) ** 2
        shift = self.fmap.shift_diopters(calibrated=True)  # (R, F)
        out = []
        for f in np.ravel(true_focus_m):
            fd = 1.0 / (fn(x, y, float(f)) if fn is not None else np.full((h, w), float(f)))
            per_r = np.stack([np.interp(fd.ravel(), self.fmap.focus_diopters, row) for row in shift])  # (R, N)
            rr = self.fmap.radius ** 2
            i = np.clip(np.searchsorted(rr, r2.ravel()) - 1, 0, len(rr) - 2)
            t = np.clip((r2.ravel() - rr[i]) / (rr[i + 1] - rr[i]), 0, 1)
            n = np.arange(r2.size)
            sh = per_r[i, n] * (1 - t) + per_r[i + 1, n] * t
            out.append((sh.reshape(h, w) + fd))
        return np.stack(out).astype(np.float32)

    def truth_measured(self, effects: list[str], true_focus_m) -> np.ndarray | None:
        """(S, H, W) bool: where the render-consistent truth (--truth) is between its points, not extrapolated
        (None without one)."""
        if self.truth_map is None:
            return None
        from aat_deploy.calibrate.format import field_grid
        from aat_deploy.render import effects as fx

        fn = fx.focus_at(fx.parse(effects), self.ctx())
        x, y = field_grid(self.h, self.w)
        r = self.fmap.radius_px(self.h, self.w).astype(np.float64).ravel()
        out = []
        for f in np.ravel(true_focus_m):
            fd = 1.0 / (fn(x, y, float(f)) if fn is not None else np.full((self.h, self.w), float(f)))
            out.append(self.truth_map.evaluate(r, np.asarray(fd, np.float64).ravel())[1].reshape(self.h, self.w))
        return np.stack(out)

    def truth_at(self, effects: list[str], x, y, true_focus_m) -> np.ndarray:
        """(S, N) float64: `truth` at normalised field points x, y (N,) (x right, y up, -1..1 from edge to edge)
        instead of every pixel: what a tile at (x, y) should see (benchmarks/probes/phone_map_budget.py)."""
        from aat_deploy.render import effects as fx

        fn = fx.focus_at(fx.parse(effects), self.ctx())
        x, y = np.asarray(x, np.float64).ravel(), np.asarray(y, np.float64).ravel()
        sw, sh = (float(v) for v in self.fmap.sensor_mm)
        r2 = (np.hypot(x * sw / 2, y * sh / 2) / (0.5 * np.hypot(sw, sh))) ** 2
        shift = self.fmap.shift_diopters(calibrated=True)  # (R, F)
        rr = self.fmap.radius ** 2
        i = np.clip(np.searchsorted(rr, r2) - 1, 0, len(rr) - 2)
        t = np.clip((r2 - rr[i]) / (rr[i + 1] - rr[i]), 0, 1)
        n = np.arange(r2.size)
        out = []
        for f in np.ravel(true_focus_m):
            fd = 1.0 / (np.asarray(fn(x, y, float(f)), np.float64) * np.ones_like(x) if fn is not None
                        else np.full(x.shape, float(f)))
            if self.truth_map is not None:
                out.append(self.truth_map.object_d(np.sqrt(r2), fd))
                continue
            per_r = np.stack([np.interp(fd, self.fmap.focus_diopters, row) for row in shift])  # (R, N)
            out.append(per_r[i, n] * (1 - t) + per_r[i + 1, n] * t + fd)
        return np.stack(out)


# -- the chart sweeps ------------------------------------------------------------------------------------------------
def chart_for(rig: Rig, distance_m: float):
    from aat_deploy.calibrate.chart import ChartSpec, make_chart

    w_mm = 1.3 * rig.w / rig.f_px * 1000 * distance_m
    frac = rig.setup.marker_frac
    from aat_deploy.calibrate.chart import texture_sigma_for

    soften = rig.setup.chart_soften_px
    spec = ChartSpec(size_mm=(w_mm, w_mm * rig.h / rig.w), markers=(6, 4),
                     marker_mm=None if frac is None else frac * w_mm / 6,
                     dpi=25.4 * CHART_PX_PER_PX * rig.w / (w_mm / 1.3), seed=int(distance_m * 1000),
                     texture_sigma_mm=texture_sigma_for(w_mm / 1.3, rig.w, soften) if soften > 0 else 0.0)
    if rig.setup.chart_texture == "dead leaves":
        return make_chart(spec)
    from benchmarks.probes.chart_texture import texture_for

    name = rig.setup.chart_texture
    return make_chart(spec, texture_for(name, spec, CHART_PX_PER_PX), texture_name=name)


CHART_PX_PER_PX = 3  # the benchmark's chart image pixels per sensor pixel at the chart's distance (centre)


def sweep(rig: Rig, variant: str, i: int, progress=print, noise: bool = True) -> dict:
    """One chart sweep (cached): frames (S, 3, H, W) far to near, reported_m, true_m, layout, distance. noise=False:
    the same sweep (scene, frames, seed) with the variant's effects but `noise`, cached apart (`_noise0`;
    benchmarks/probes/outer_fit.py)."""
    from aat_deploy.calibrate.pose import ChartPose
    from aat_deploy.calibrate.scene import chart_scene
    from aat_deploy.capture.virtual import shoot

    s = rig.setup
    d, (tx, ty) = s.distances_m[i], s.tilts[i]
    effects = [e for e in effects_for(s, variant) if noise or e.split(":")[0] != "noise"]
    cells = "" if s.cell_px == 64 else f"_cells{s.cell_px}"
    cells += "" if s.step_px is None else f"_step{s.step_px:g}px"
    cells += "" if s.chart_texture == "dead leaves" else f"_tex-{s.chart_texture}"
    cells += f"_soft{s.chart_soften_px:g}px" if s.chart_soften_px > 0 else ""
    cells += "" if noise else "_noise0"
    f = CACHE / f"{s.sweep_key or s.key}_{variant if variant == 'nominal' else s.copy_name}_{d:g}m{cells}.npz"
    img, layout = chart_for(rig, d)
    sources = sweep_sources(s)
    if f.is_file():
        z = np.load(f)
        check_sweep_sources(f, z, sources)
        return {"frames": z["frames"].astype(np.float32), "reported_m": z["reported_m"], "true_m": z["true_m"],
                "layout": layout, "distance_m": d}
    rgb, depth = chart_scene(img, layout, ChartPose(d, tx, ty), rig.w, rig.h, rig.f_px, rig.pupil)
    dd = 1.0 / depth
    fd = sweep_diopters(rig, float(dd.max()), float(dd.min()))
    true_m = 1.0 / fd  # far to near (diopters ascending), as a sweep is read
    t0 = time.time()
    frames, reported = shoot(rig.lens, rgb * 0.6, depth, true_m, effects, rig.src, seed=1000 + i, workers=1,
                             cell_px=s.cell_px)
    progress(f"  {s.key} {variant} chart at {d:g} m: {len(fd)} frames in {time.time() - t0:.0f} s")
    CACHE.mkdir(parents=True, exist_ok=True)
    from aat_deploy.io.atomic import atomic_file

    with atomic_file(f) as tmp:
        np.savez(tmp, frames=frames.astype(np.float16), reported_m=reported, true_m=true_m,
                 sources=json.dumps(sources, sort_keys=True))
    return {"frames": frames.astype(np.float16).astype(np.float32), "reported_m": reported, "true_m": true_m,
            "layout": layout, "distance_m": d}


def sweep_sources(setup: LensSetup) -> dict:
    """{"lens": sha256, "psf": sha256} of the files a sweep is rendered from: its cache name holds the lens's key
    only, so a lens file corrected in place (the Z35, 2026-11-26) would otherwise be read from its old sweeps."""
    from training.data.cache import sha256_file_cached

    return {"lens": sha256_file_cached(ROOT / setup.lens), "psf": sha256_file_cached(ROOT / setup.psf)}


_UNVERIFIED: set[str] = set()


def check_sweep_sources(path: Path, z, sources: dict) -> None:
    """SystemExit (one line) when a cached sweep records other lens/PSF files than `sources`; a sweep cached before
    the record existed is read as unverified, with one warning line per file (nothing written or deleted)."""
    if "sources" not in z.files:
        if str(path) not in _UNVERIFIED:
            _UNVERIFIED.add(str(path))
            print(f"warning: {path}: cached before sweeps recorded their lens/PSF files: read as unverified",
                  file=sys.stderr, flush=True)
        return
    was = json.loads(str(z["sources"]))
    diff = [f"{k} {str(was.get(k))[:12]} then, {v[:12]} now" for k, v in sources.items() if was.get(k) != v]
    if diff:
        raise SystemExit(f"{path}: rendered from other files ({'; '.join(diff)}): move it aside to render the sweep "
                         "again (nothing was deleted)")


def measured_setup(rig: Rig, variant: str, progress=print) -> list:
    """Every chart of `rig`'s setup shot through `variant` and measured (what the probes start from)."""
    return measures(rig, [sweep(rig, variant, i, progress) for i in range(len(rig.setup.distances_m))], variant)


def measures(rig: Rig, sweeps: list[dict], variant: str, keep_every: int = 1, tiles_to_edges: bool = False,
             tile_px: int | None = None):
    """Measured sweeps as `aat-calibrate fit` measures them (tape-measured distances); tiles_to_edges: the tiles
    spread from edge to edge (`peaks.TileGrid`, benchmarks/probes/corner_tiles.py) instead of the fit's centred grid;
    tile_px: tiles of that size instead of the fit's (`sweep.tile_px_for`; benchmarks/probes/tile_size.py)."""
    from aat_deploy.calibrate.sweep import measure_sweep

    rng = np.random.default_rng(7)
    out = []
    for sw in sweeps:
        tape = sw["distance_m"] + rng.normal(0, TAPE_SD_MM / 1000)
        free = rig.setup.distances_m.index(sw["distance_m"]) in rig.setup.fit_distance
        out.append(measure_sweep(as_sweep(rig, sw, variant, keep_every), sw["layout"], distance_m=tape,
                                 measure=rig.measure, prefilter_px=rig.prefilter_px, fit_distance=free,
                                 tiles_to_edges=tiles_to_edges, tile_px=tile_px))
    return out


def as_sweep(rig: Rig, sw: dict, variant: str, keep_every: int = 1, first: int = 0):
    """One of `sweep`'s chart sweeps as `aat-calibrate fit` reads it from a folder (its EXIF: the virtual camera's
    make, model, lens, focal length and f-number); every keep_every-th frame from frame `first`."""
    from aat_deploy.calibrate.sweep import Sweep

    idx = np.arange(first, len(sw["reported_m"]), keep_every)
    ident = {"make": "aat", "model": "virtual camera", "lens": rig.lens.name,
             "focal_length_mm": round(rig.efl, 2), "f_number": round(rig.fno, 2)}
    return Sweep(Path(sweep_name(rig.setup, variant, sw["distance_m"])), sw["frames"][idx], sw["reported_m"][idx],
                 ident, (rig.w, rig.h), 1.0)


def sweep_name(setup: LensSetup, variant: str, distance_m: float) -> str:
    """A chart sweep's name as the fit reports it (its folder's): the setup, the copy (a random copy's own name,
    `copy_s2026_0`, not the variant's `copy`) and the chart's distance."""
    return f"{setup.key}_{variant if variant == 'nominal' else setup.copy_name}_{distance_m:g}m"


def sensor_mm(rig: Rig) -> tuple[float, float]:
    """The virtual camera's sensor size (mm, width and height), as a user gives it with --sensor-mm."""
    return (float(rig.lens.sensor.width_mm), float(rig.lens.sensor.height_mm))


def truth_family(rig: Rig, effects: list[str], true_m: np.ndarray) -> dict:
    """The reported-focus family the truth itself has: the fit's g is the in-focus diopters at the frame centre (its
    field term is 0 there), so the truth's g is the truth's centre pixel against the reported focus; the offset
    and the scale fitted to it by least squares over these frames (true_m), for comparison with the fit's."""
    rep_d = 1.0 / (true_m * (SCALE if any(e.startswith("focus_metadata") for e in effects) else 1.0))
    t = rig.truth(effects, true_m)[:, rig.h // 2, rig.w // 2].astype(np.float64)
    return {"scale": float(np.sum(t * rep_d) / np.sum(rep_d ** 2)), "bias_d": float(np.mean(rep_d - t)),
            "centre_minus_thin_lens_d": [float(v) for v in t - 1.0 / true_m]}


def map_errors(rig: Rig, cal, effects: list[str], true_m: np.ndarray) -> dict:
    """RMS and p95 |error| (D) of the calibration, the prescription's map and the thin lens against the truth."""
    from aat_deploy.calibrate import in_focus_diopters

    rep = true_m * (SCALE if any(e.startswith("focus_metadata") for e in effects) else 1.0)
    truth = rig.truth(effects, true_m)
    r = rig.fmap.radius_px(rig.h, rig.w)
    preds = {"calibration": in_focus_diopters(cal, rep, rig.h, rig.w) if cal is not None else None,
             "prescription map": np.stack([rig.fmap.frame_diopters([f], r.ravel())[0].reshape(rig.h, rig.w)
                                           for f in rep]),
             "thin lens": np.broadcast_to((1.0 / rep)[:, None, None], truth.shape)}
    out = {}
    zones = zone_masks(rig.h, rig.w)
    rad = field_radius(rig.h, rig.w)
    bins = {f"{lo:g}-{hi:g}": (rad >= lo) & (rad < hi if hi < 1 else rad <= hi)
            for lo, hi in zip(RADIUS_EDGES[:-1], RADIUS_EDGES[1:])}
    for k, p in preds.items():
        if p is None:
            continue
        e = np.abs(p - truth)
        d = p - truth
        out[k] = {"rms_d": float(np.sqrt(np.mean(e ** 2))), "p95_d": float(np.quantile(e, 0.95)),
                  "zone_rms_d": {z: float(np.sqrt(np.mean(e[:, m] ** 2))) for z, m in zones.items()},
                  "radius_rms_d": {b: float(np.sqrt(np.mean(e[:, m] ** 2))) for b, m in bins.items()},
                  "radius_mean_d": {b: float(np.mean(d[:, m])) for b, m in bins.items()}}
        if k == "calibration" and cal.best_focus.radius_max is not None:
            out[k].update(tile_coverage(d, cal.best_focus.radius_max, cal.best_focus.aspect))
        if k == "calibration":
            out[k].update(mask_scores(d, cal, rep, rig.truth_measured(effects, true_m), p))
    return out


def mask_scores(d: np.ndarray, cal, rep: np.ndarray, truth_ok: np.ndarray | None, pred: np.ndarray) -> dict:
    """The calibration's error d (S, H, W) by mask, RMS and p95 of |d| (D): within the farthest tile's radius,
    where the calibration measured (`measured_mask`) and where it flags extrapolation, and, with a render-consistent
    truth, where that truth is between its points (truth_ok) and where both hold."""
    from aat_deploy.calibrate import measured_mask
    from aat_deploy.calibrate.format import field_grid, field_radius_of

    def st(m):
        e = np.abs(d[m]) if m is not None else np.abs(d).ravel()
        return (None, None) if e.size == 0 else (float(np.sqrt(np.mean(e ** 2))), float(np.quantile(e, 0.95)))

    out = {}
    cal_ok = measured_mask(cal, rep, d.shape[1], d.shape[2], pred)
    masks = {"cal_measured": cal_ok, "cal_flagged": ~cal_ok}
    if cal.best_focus.radius_max is not None:
        x, y = field_grid(*d.shape[1:])
        within = np.broadcast_to(field_radius_of(x, y, cal.best_focus.aspect) <= cal.best_focus.radius_max,
                                 d.shape)
        masks["within_tiles"] = within
    if truth_ok is not None:
        masks["truth_measured"] = truth_ok
        masks["truth_and_cal_measured"] = truth_ok & cal_ok
        if "within_tiles" in masks:
            masks["within_tiles_truth_measured"] = masks["within_tiles"] & truth_ok
    for name, m in masks.items():
        rms, p95 = st(m)
        out[f"{name}_share"] = float(m.mean())
        out[f"{name}_rms_d"], out[f"{name}_p95_d"] = rms, p95
    return out


def tile_coverage(d: np.ndarray, radius_max: float, aspect: float) -> dict:
    """The map's error d (S, H, W) split where tiles measured the field and where not: RMS within the farthest
    counted tile's field radius (the calibration's `best_focus.radius_max`, with its frames' aspect) and beyond it,
    where the file holds its field term along the radius (no tile measured it), and the pixels' share beyond."""
    from aat_deploy.calibrate.format import field_grid, field_radius_of

    x, y = field_grid(*d.shape[1:])
    beyond = field_radius_of(x, y, aspect) > radius_max
    rms = lambda m: float(np.sqrt(np.mean(d[:, m] ** 2))) if m.any() else None
    return {"tiles_radius_max": float(radius_max), "within_tiles_rms_d": rms(~beyond),
            "beyond_tiles_rms_d": rms(beyond), "beyond_tiles_share": float(beyond.mean())}


def fit(rig: Rig, variant: str, sweeps: list[dict], n_boot: int, keep_every: int = 1):
    from aat_deploy.calibrate.fit import fit_calibration

    return fit_calibration(measures(rig, sweeps, variant, keep_every), n_boot=n_boot)


def psf_growth(rig: Rig, object_m: float) -> dict:
    """Why a sweep can be flat or unbracketed: the surrogate's PSF RMS radius (px, its second moment) on axis and at
    field x = 0.7 for an object at object_m, at the sweep's focus settings, beside the thin-lens defocus blur
    diameter (px); and the best-focus map's field curvature (D nearer than on axis) at radius 0.5 and 1 for a frame
    focused at object_m."""
    fd = sweep_diopters(rig, 1.0 / object_m, 1.0 / object_m)
    out = {"object_m": object_m, "focus_d": fd.tolist(),
           "defocus_blur_px": (rig.blur_px_per_d * np.abs(fd - 1.0 / object_m)).tolist()}
    shift = rig.fmap.shift_diopters(calibrated=True)  # (R, F)
    at = [float(np.interp(1.0 / object_m, rig.fmap.focus_diopters, row)) for row in shift]
    out["field_curvature_d"] = {f"r{r:g}": float(np.interp(r, rig.fmap.radius, at)) - at[0] for r in (0.5, 1.0)}
    for name, x in (("rms_radius_px_centre", 0.0), ("rms_radius_px_x0.7", 0.7)):
        k, sc = rig.src(np.full(fd.size, x), np.zeros(fd.size), np.full(fd.size, object_m), 1.0 / fd)
        g = np.arange(k.shape[-1]) - k.shape[-1] // 2
        p = k / k.sum((-1, -2), keepdims=True)
        out[name] = (np.sqrt((p * (g[:, None] ** 2 + g[None, :] ** 2)).sum((-1, -2))) * sc).tolist()
    out["reach_px"] = sweep_reach_px(rig)
    return out


def sweep_reach_px(rig: Rig) -> dict:
    """{chart distance (m): [far, near]}: the thin-lens blur (px) the sweep reaches beyond the chart's centre on
    its far and near side. A tile's focus curve must fall to half to count (`calibrate.peaks`), which on the RF50
    takes HALF_FALL_PX: a sweep that cannot reach that far (clipped to the surrogate's focus range) leaves the
    curves flat whatever the chart."""
    out = {}
    for d in rig.setup.distances_m:
        fd = sweep_diopters(rig, 1.0 / d, 1.0 / d)
        out[f"{d:g}"] = [float(rig.blur_px_per_d * (1.0 / d - fd[0])), float(rig.blur_px_per_d * (fd[-1] - 1.0 / d))]
    return out


# -- parts -----------------------------------------------------------------------------------------------------------
def part_map(rig: Rig, n_boot: int, log, variants: tuple = ("nominal", "copy")) -> tuple[list, dict]:
    from aat_deploy.calibrate.sweep import SweepError

    rows, fits = [], {}
    s = rig.setup
    inside = s.inside()
    schedule = s.schedule()
    for variant in variants:
        sw = [sweep(rig, variant, i, log) for i in range(len(s.distances_m))]
        t0 = time.time()
        try:
            res = fit(rig, variant, sw, n_boot)
        except SweepError as e:  # a lens whose sweeps cannot be calibrated is a row that says why
            why = psf_growth(rig, float(np.median(s.distances_m)))
            rows.append({"lens": s.key, "variant": variant, "refused": str(e).splitlines()[0], "psf": why})
            log(f"  {s.key} {variant}: refused: {e}; PSF RMS radius on axis "
                f"{min(why['rms_radius_px_centre']):.2f}-{max(why['rms_radius_px_centre']):.2f} px over the sweep, "
                f"defocus blur up to {max(why['defocus_blur_px']):.2f} px")
            continue
        cal = res.calibration
        fits[variant] = (cal, sw)
        eff = effects_for(s, variant)
        e_in, e_sched = map_errors(rig, cal, eff, inside), map_errors(rig, cal, eff, schedule)
        fe = cal.focus_error
        rows.append({"lens": s.key, "variant": variant, "fit_s": round(time.time() - t0, 1),
                     "family": fe.family, "scale": fe.scale, "scale_ci": fe.intervals.get("scale"),
                     "bias_d": fe.bias_d, "bias_ci": fe.intervals.get("bias_d"), "support": fe.support,
                     "tiles": cal.residuals["tiles"], "residual_rms_d": cal.residuals["rms_d"],
                     "inside": e_in, "schedule": e_sched, "degree": res.model.degree, "radial": res.model.radial,
                     "focus_degree": res.model.focus_degree, "low_focus_degree": res.model.low_focus_degree,
                     "edge_focus_cv": res.model.edge_cv, "warnings": res.warnings,
                     "truth_family": truth_family(rig, eff, inside), "measure": rig.measure,
                     "prefilter_px": rig.prefilter_px, "cell_px": s.cell_px,
                     "truth": "best-focus map" if rig.truth_map is None else rig.truth_map.source,
                     "fitted_distances": [{k: p.get(k) for k in ("chart_distance_m", "distance_given_m",
                                                                  "distance_ci_m")} | {"true_m": s.distances_m[i]}
                                          for i, p in enumerate(cal.residuals["per_sweep"])
                                          if "distance_given_m" in p]})
        log(f"  {s.key} {variant}: family {fe.family} scale {fe.scale:.4f} bias {fe.bias_d:+.4f}; map RMS "
            f"{e_in['calibration']['rms_d']:.4f} D inside, {e_sched['calibration']['rms_d']:.4f} D on the schedule")
    return rows, fits


def zone_scores(depth: np.ndarray, gt: np.ndarray) -> dict:
    valid = np.isfinite(gt) & (gt > 0)
    err = np.abs(depth - gt)
    outer = zone_masks(*gt.shape)["outer"] & valid
    err_d = np.abs(1.0 / np.maximum(depth[valid], 1e-6) - 1.0 / gt[valid])  # diopters: near and far weigh alike
    return {"mae": float(err[valid].mean()), "mae_outer": float(err[outer].mean()), "mae_d": float(err_d.mean())}


def part_depth(rig: Rig, cal, n: int, log, extra: dict | None = None) -> dict:
    """extra: more calibrations scored beside the four mappings ({name: CameraCalibration}, e.g. the blind fit's)."""
    from aat_deploy.focus import FocusConfig, classical_depth
    from aat_deploy.focus.measures import focus_volume
    from training.train.testsets import TestSetSpec, load_test_set

    s = rig.setup
    eff = tuple(effects_for(s, "copy"))
    near, far = s.schedule_m
    spec = TestSetSpec(s.lens, s.psf, 8, protocol="fixed", n_procedural=n, effects=eff, focus_near_m=near,
                       focus_far_m=far, scene_near_m=near, scene_far_m=far, middlebury=s.middlebury,
                       cell_px=s.cell_px)
    t0 = time.time()
    sets = load_test_set(spec, str(ROOT / "cache/heldout"))
    items = sets["procedural"] + sets.get("middlebury", [])
    log(f"  {s.key}: {len(items)} held-out stacks through the copy ({time.time() - t0:.0f} s)")
    cfg = FocusConfig()
    if (cfg.measure, cfg.prefilter_px) != (rig.measure, rig.prefilter_px):
        raise SystemExit(f"bench_calibrate: part depth runs the classical method with its own measure "
                         f"({cfg.measure}), not the fit's ({rig.measure}): run --parts map,needs")
    extra = extra or {}
    per = {k: [] for k in ("thin lens", "prescription map", "calibration", "oracle", *extra)}
    for it in items:
        vol = focus_volume(it.stack, cfg.measure, cfg.window_px, prefilter_px=cfg.prefilter_px)
        rep = np.asarray(it.focus_m, np.float64)
        true_m = rep / SCALE
        oracle = rig.truth(list(eff), true_m)
        runs = {"thin lens": dict(), "prescription map": dict(best_focus=rig.fmap),
                "calibration": dict(calibration=cal), "oracle": dict(frame_diopters=oracle),
                **{k: dict(calibration=c) for k, c in extra.items()}}
        for k, kw in runs.items():
            r = classical_depth(it.stack, rep, config=cfg, volume=vol, **kw)
            per[k].append({"scene": it.name, **zone_scores(r.depth_m, it.depth_m)})
    out = {"scenes": len(items), "per_scene": per}
    for k, v in per.items():
        out[k] = {z: list(bootstrap_mean([x[z] for x in v], n_boot=N_BOOT, seed=1))
                  for z in ("mae", "mae_outer", "mae_d")}
    for z in ("mae", "mae_outer", "mae_d"):
        out[f"cal/oracle {z}"] = paired_ratio(per["calibration"], per["oracle"], z)
        out[f"cal/prescription {z}"] = paired_ratio(per["calibration"], per["prescription map"], z)
        out[f"prescription/oracle {z}"] = paired_ratio(per["prescription map"], per["oracle"], z)
        for k in extra:
            out[f"{k}/prescription {z}"] = paired_ratio(per[k], per["prescription map"], z)
            out[f"{k}/calibration {z}"] = paired_ratio(per[k], per["calibration"], z)
    log(f"  {s.key}: MAE cal {out['calibration']['mae'][0]:.3f}, oracle {out['oracle']['mae'][0]:.3f}, "
        f"prescription {out['prescription map']['mae'][0]:.3f}, thin {out['thin lens']['mae'][0]:.3f} m")
    return out


def part_needs(rig: Rig, sweeps: list[dict], log) -> list[dict]:
    """Map RMS (inside the full calibrated range and on the schedule) with subsets of distances and frames."""
    s = rig.setup
    eff = effects_for(s, "copy")
    inside = s.inside()
    schedule = s.schedule()
    rows = []
    subsets = [(1,), (0, 2), (0, 1, 2)] + ([tuple(range(len(s.distances_m)))] if len(s.distances_m) > 3 else [])
    for sub in subsets:
        for every in (1, 2, 3):
            chosen = [sweeps[i] for i in sub]
            step_d = float(np.mean(np.diff(1.0 / chosen[0]["true_m"]))) * every  # the true focus step
            try:
                res = fit(rig, "copy", chosen, 20, every)
            except Exception as e:  # noqa: BLE001 (a subset too small to fit is a row that says so)
                rows.append({"distances_m": [s.distances_m[i] for i in sub], "step_d": step_d,
                             "error": str(e).splitlines()[0][:120]})
                continue
            e_in = map_errors(rig, res.calibration, eff, inside)["calibration"]
            e_s = map_errors(rig, res.calibration, eff, schedule)["calibration"]
            frames = sum(len(range(0, len(sw["reported_m"]), every)) for sw in chosen)
            rows.append({"distances_m": [s.distances_m[i] for i in sub], "step_d": step_d, "frames": frames,
                         "family": res.calibration.focus_error.family, "inside_rms_d": e_in["rms_d"],
                         "schedule_rms_d": e_s["rms_d"]})
            log(f"  needs {rows[-1]}")
    return rows


def world_views(rig: Rig, k: int, log) -> list[tuple[np.ndarray, np.ndarray]]:
    """World k seen from 9 turned views through the copy (cached): [(frames, reported_m)]."""
    from aat_deploy.calibrate.scene import turned_view
    from aat_deploy.capture.virtual import shoot
    from training.data.scenes import SceneConfig, procedural_scene

    s = rig.setup
    f = CACHE / f"{s.key}_blind_world{k}.npz"
    if f.is_file():
        z = np.load(f)
        return [(z[f"frames{i}"].astype(np.float32), z[f"reported{i}"]) for i in range(9)]
    hp, wp = int(rig.h * 1.45), int(rig.w * 1.45)
    near, far = s.schedule_m  # the worlds span the lens's depth schedule (the phone: 0.07-0.5 m)
    rgb, depth = procedural_scene(SceneConfig(height=hp, width=wp, near_m=near, far_m=far, photo_fraction=0.5,
                                              photo_split="test"), np.random.default_rng([424242, k]))
    z_mm = depth * 1000.0 - rig.pupil
    true_m = s.schedule()
    out = []
    t0 = time.time()
    for i, (yaw, pitch) in enumerate([(a, b) for a in (-6, 0, 6) for b in (-6, 0, 6)]):
        v_rgb, v_z = turned_view(rgb.transpose(2, 0, 1), z_mm, rig.f_px, yaw, pitch, rig.w, rig.h)
        out.append(shoot(rig.lens, v_rgb, v_z / 1000 + rig.pupil / 1000, true_m, effects_for(s, "copy"), rig.src,
                         seed=100 * k + i, workers=2))
    log(f"  {s.key} blind world {k}: 9 views in {time.time() - t0:.0f} s")
    from aat_deploy.io.atomic import atomic_file

    with atomic_file(f) as tmp:
        np.savez(tmp, **{f"frames{i}": fr.astype(np.float16) for i, (fr, _) in enumerate(out)},
                 **{f"reported{i}": rep for i, (_, rep) in enumerate(out)})
    # as the cache holds them (float16), so that a run that renders and one that reads the cache fit the same frames
    return [(fr.astype(np.float16).astype(np.float32), rep) for fr, rep in out]


def field_error(rig: Rig, pred: np.ndarray, truth: np.ndarray) -> float:
    """RMS (D) of the field terms (in focus minus at the frame centre) over frames and pixels."""
    c = (rig.h // 2, rig.w // 2)
    fp = pred - pred[:, c[0], c[1]][:, None, None]
    ft = truth - truth[:, c[0], c[1]][:, None, None]
    return float(np.sqrt(np.mean((fp - ft) ** 2)))


def part_blind(rig: Rig, chart_cal, n_worlds: int, log) -> tuple[list[dict], object]:
    """(rows, the blind calibration from every capture or None)."""
    from aat_deploy.calibrate import in_focus_diopters
    from aat_deploy.calibrate.fit import camera_identity_of
    from aat_deploy.calibrate.scenes import estimate_scene, fit_from_scenes
    from aat_deploy.calibrate.sweep import Sweep

    s = rig.setup
    eff = effects_for(s, "copy")
    true_m = s.schedule()
    rep = true_m * SCALE
    truth = rig.truth(eff, true_m)
    r = rig.fmap.radius_px(rig.h, rig.w)
    base = {"chart calibration": field_error(rig, in_focus_diopters(chart_cal, rep, rig.h, rig.w), truth),
            "prescription map": field_error(rig, np.stack([rig.fmap.frame_diopters([f], r.ravel())[0].reshape(
                rig.h, rig.w) for f in rep]), truth),
            "none (thin lens)": field_error(rig, np.broadcast_to((1 / rep)[:, None, None], truth.shape), truth)}
    scenes = []
    for k in range(n_worlds):
        for i, (fr, rp) in enumerate(world_views(rig, k, log)):
            scenes.append(estimate_scene(f"world{k}_view{i}", fr, rp))
    ident = camera_identity_of(Sweep(Path("x"), np.zeros((1, 3, 2, 2)), np.ones(1),
                                     {"focal_length_mm": round(rig.efl, 2), "f_number": round(rig.fno, 2)},
                                     (rig.w, rig.h), 1.0))
    rows = [{"captures": 0, **base}]
    last = None
    for n in sorted({3, 9, 18, 27, len(scenes)}):
        if n > len(scenes):
            continue
        try:
            res = fit_from_scenes(scenes[:n], ident, (rig.w, rig.h), n_boot=20)
        except ValueError as e:
            rows.append({"captures": n, "blind": None, "error": str(e)[:120]})
            continue
        err = field_error(rig, in_focus_diopters(res.calibration, rep, rig.h, rig.w), truth)
        last = res.calibration if n == len(scenes) else last
        u = res.calibration.uncertainty  # the bootstrap's spread and the fit's own warning (scenes.spread_check)
        rows.append({"captures": n, "blind": err, "pairs": res.calibration.residuals["pairs"],
                     "samples": res.calibration.residuals["samples"], "sd_rms_d": u.get("sd_rms_d"),
                     "limit_d": u.get("limit_d"), "field_rms_d": u.get("field_rms_d"),
                     "warned": bool(u.get("warning"))})
        log(f"  blind {n} captures: field RMS {err:.4f} D ({rows[-1]['pairs']} pairs), bootstrap SD "
            f"{u.get('sd_rms_d')} D, limit {u.get('limit_d')} D, warned {rows[-1]['warned']}")
    return rows, last


# -- tables ----------------------------------------------------------------------------------------------------------
BLIND_MAPPINGS = ("blind calibration", "blind + chart focus error")  # part d's fit scored in part b (both parts run)


def reach_note(psf: dict) -> str:
    """The refused row's note on how far its sweeps reach (runs before 2026-11-26 did not record it)."""
    reach = psf.get("reach_px")
    if not reach:
        return ""
    sides = ", ".join(f"{d} m {f:.1f} / {n:.1f}" for d, (f, n) in reach.items())
    return (f"; the sweeps reach {sides} px of blur beyond the chart (far / near side), where the RF50's tile curves "
            f"fall to half {HALF_FALL_PX[0]:.1f}-{HALF_FALL_PX[1]:.1f} px from their peak")


def tables(res: dict) -> str:
    out = ["### a) The calibrated map against the copy's truth (diopters over every pixel)", "",
           "| lens | variant | focus error fitted | tiles | residual RMS | calibration RMS / p95, inside | "
           "prescription map RMS, inside | thin lens RMS, inside | calibration RMS / p95, depth schedule | "
           "prescription map RMS, schedule |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in res.get("map", []):
        if "refused" in r:
            p = r["psf"]
            out.append(f"| {r['lens']} | {r['variant']} | refused: {r['refused'].split(': ', 1)[-1]} (PSF RMS radius "
                       f"{min(p['rms_radius_px_centre']):.2f}-{max(p['rms_radius_px_centre']):.2f} px on axis, "
                       f"{min(p['rms_radius_px_x0.7']):.2f}-{max(p['rms_radius_px_x0.7']):.2f} px at x = 0.7 over "
                       f"the sweep's {p['focus_d'][0]:.2f}-{p['focus_d'][-1]:.2f} D, object at {p['object_m']:g} m;"
                       f" thin-lens defocus blur up to {max(p['defocus_blur_px']):.1f} px; best focus "
                       f"{p['field_curvature_d']['r0.5']:+.1f} D at radius 0.5, {p['field_curvature_d']['r1']:+.1f} D "
                       f"at the corner, from the axis's{reach_note(p)}) | | | | | | | |")
            continue
        fe = (f"{r['family']}" + (f" {r['scale']:.4f} [{r['scale_ci'][0]:.4f}, {r['scale_ci'][1]:.4f}]"
                                  if r["family"] == "scale" and r["scale_ci"] else "")
              + (f" {r['bias_d']:+.4f} D [{r['bias_ci'][0]:+.4f}, {r['bias_ci'][1]:+.4f}]"
                 if r["family"] == "offset" and r["bias_ci"] else ""))
        tf = r.get("truth_family")  # runs before 2026-11-26 did not record it
        if tf and r["family"] in ("scale", "offset"):
            fe += (f" (the truth's {tf['scale']:.4f})" if r["family"] == "scale" else
                   f" (the truth's {tf['bias_d']:+.4f} D)")
        i, s = r["inside"], r["schedule"]
        out.append(f"| {r['lens']} | {r['variant']} | {fe} | {r['tiles']} | {r['residual_rms_d']:.4f} | "
                   f"{i['calibration']['rms_d']:.4f} / {i['calibration']['p95_d']:.4f} | "
                   f"{i['prescription map']['rms_d']:.4f} | {i['thin lens']['rms_d']:.4f} | "
                   f"{s['calibration']['rms_d']:.4f} / {s['calibration']['p95_d']:.4f} | "
                   f"{s['prescription map']['rms_d']:.4f} |")
    fitted = [(r, f) for r in res.get("map", []) for f in r.get("fitted_distances", [])]
    if fitted:  # charts whose distance the fit found (runs before 2026-11-27 fitted none)
        out += ["", "Chart distances fitted (`--distance-m ...,~D`): " + "; ".join(
            f"{r['lens']} {r['variant']}: {f['chart_distance_m'] * 1000:.2f} mm (given {f['distance_given_m'] * 1000:.2f}, "
            f"true {f['true_m'] * 1000:.2f}" + (f", 95 % {f['distance_ci_m'][0] * 1000:.2f}-{f['distance_ci_m'][1] * 1000:.2f}"
                                               if f.get("distance_ci_m") else "") + ")" for r, f in fitted)]
    rad = [r for r in res.get("map", []) if "radius_rms_d" in r.get("inside", {}).get("calibration", {})]
    if rad:  # runs before 2026-11-26 15:30 kept the zones only
        bins = list(rad[0]["inside"]["calibration"]["radius_rms_d"])
        out += ["", "#### a) by field radius, inside: calibration RMS (mean signed error, calibration - truth), D", "",
                "| lens | variant | anchors (px) | " + " | ".join(bins) + " | within the tiles' radius / beyond (share) |",
                "|---|---|---|" + "---|" * len(bins) + "---|"]
        for r in rad:
            c = r["inside"]["calibration"]
            cov = (f"{c['within_tiles_rms_d']:.3f} / " + ("-" if c["beyond_tiles_rms_d"] is None else
                                                           f"{c['beyond_tiles_rms_d']:.3f}")
                   + f" ({100 * c['beyond_tiles_share']:.1f} % beyond radius {c['tiles_radius_max']:.3f})"
                   if "within_tiles_rms_d" in c else "-")  # runs before 2026-11-27 07:00 did not split it
            out.append(f"| {r['lens']} | {r['variant']} | {r.get('cell_px', 64)} | " + " | ".join(
                f"{c['radius_rms_d'][b]:.3f} ({c['radius_mean_d'][b]:+.3f})" for b in bins) + f" | {cov} |")
    if res.get("depth"):
        out += ["", "### b) Depth through the copy, classical method, four mappings of the reported focus", "",
                "| lens | scenes | mapping | MAE (m) | MAE outer (m) | MAE (D) |", "|---|---|---|---|---|---|"]
        for lens, d in res["depth"].items():
            for k in ("thin lens", "prescription map", "calibration", "oracle", *BLIND_MAPPINGS):
                if k not in d:
                    continue
                md = fmt(d[k]["mae_d"]) if "mae_d" in d[k] else "-"  # runs before 2026-11-26 kept metres only
                out.append(f"| {lens} | {d['scenes']} | {k} | {fmt(d[k]['mae'])} | {fmt(d[k]['mae_outer'])} | {md} |")
        out += ["", "| lens | calibration / oracle, MAE | outer | calibration / prescription map, MAE | outer | "
                    "prescription / oracle, MAE | outer | calibration / thin lens, MAE | outer | "
                    "calibration / prescription map, MAE in D | calibration / thin lens, MAE in D |",
                "|---|---|---|---|---|---|---|---|---|---|---|"]
        for lens, d in res["depth"].items():
            per = d["per_scene"]  # the thin-lens ratio from the stored scenes (the same paired bootstrap)
            thin = [fmt(paired_ratio(per["calibration"], per["thin lens"], z)) for z in ("mae", "mae_outer")]
            in_d = [fmt(paired_ratio(per["calibration"], per[b], "mae_d")) if "mae_d" in per["calibration"][0]
                    else "-" for b in ("prescription map", "thin lens")]
            out.append(f"| {lens} | {fmt(d['cal/oracle mae'])} | {fmt(d['cal/oracle mae_outer'])} | "
                       f"{fmt(d['cal/prescription mae'])} | {fmt(d['cal/prescription mae_outer'])} | "
                       f"{fmt(d['prescription/oracle mae'])} | {fmt(d['prescription/oracle mae_outer'])} | "
                       f"{thin[0]} | {thin[1]} | {in_d[0]} | {in_d[1]} |")
        # setups of one lens scored on the same scenes through the same copy (the oracle's MAE per scene equal: e.g.
        # cellphone and cellphone_near): their calibrations paired
        same = [(a, b) for i, a in enumerate(res["depth"]) for b in list(res["depth"])[i + 1:]
                if res["depth"][a]["per_scene"]["oracle"] == res["depth"][b]["per_scene"]["oracle"]]
        if same:
            out += ["", "| calibration of / calibration of (the same scenes and copy) | MAE | outer | MAE in D |",
                    "|---|---|---|---|"]
            for a, b in same:
                pa, pb = res["depth"][b]["per_scene"]["calibration"], res["depth"][a]["per_scene"]["calibration"]
                out.append(f"| {b} / {a} | " + " | ".join(fmt(paired_ratio(pa, pb, z)) for z in
                                                          ("mae", "mae_outer", "mae_d")) + " |")
        blind = [(lens, k, d) for lens, d in res["depth"].items() for k in BLIND_MAPPINGS if k in d]
        if blind:
            out += ["", "| lens | mapping | / prescription map, MAE | outer | MAE in D | / chart calibration, MAE | "
                        "outer | MAE in D |", "|---|---|---|---|---|---|---|---|"]
            for lens, k, d in blind:
                out.append(f"| {lens} | {k} | " + " | ".join(fmt(d[f"{k}/{b} {z}"]) for b in ("prescription", "calibration")
                                                             for z in ("mae", "mae_outer", "mae_d")) + " |")
    if res.get("needs"):
        out += ["", "### c) How many chart distances and frames (the copy)", "",
                "| lens | chart distances (m) | sweep step (D) | frames | family | map RMS inside (D) | "
                "map RMS, depth schedule (D) |", "|---|---|---|---|---|---|---|"]
        for lens, rows in res["needs"].items():
            for r in rows:
                if "error" in r:
                    out.append(f"| {lens} | {r['distances_m']} | {r['step_d']:.2f} | - | refused: {r['error']} | | |")
                else:
                    out.append(f"| {lens} | {r['distances_m']} | {r['step_d']:.2f} | {r['frames']} | {r['family']} | "
                               f"{r['inside_rms_d']:.4f} | {r['schedule_rms_d']:.4f} |")
    if res.get("blind"):
        out += ["", "### d) Blind calibration from scenes: the field term's error against the copy's truth", "",
                "| lens | captures (turned views) | overlapping pairs | field term RMS error (D), 8 frames over the "
                "schedule | bootstrap SD, RMS (D) | warning limit (D) | warns |", "|---|---|---|---|---|---|---|"]
        for lens, rows in res["blind"].items():
            base = rows[0]
            for k in ("none (thin lens)", "prescription map", "chart calibration"):
                out.append(f"| {lens} | {k} | - | {base[k]:.4f} | | | |")
            for r in rows[1:]:
                if r.get("blind") is None:
                    out.append(f"| {lens} | {r['captures']} | - | refused: {r['error']} | | | |")
                    continue
                sd = "-" if r.get("sd_rms_d") is None else f"{r['sd_rms_d']:.4f}"  # runs before 2026-11-26 13:10
                lim = "-" if r.get("limit_d") is None else f"{r['limit_d']:.4f}"
                warned = {True: "yes", False: "no"}.get(r.get("warned"), "-")
                out.append(f"| {lens} | {r['captures']} | {r['pairs']} | {r['blind']:.4f} | {sd} | {lim} | {warned} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lenses", default="rf50,paper50,ef50")
    ap.add_argument("--parts", default="map,depth,needs")
    ap.add_argument("--n", type=int, default=24, help="procedural held-out scenes per lens (plus Middlebury)")
    ap.add_argument("--boot", type=int, default=100)
    ap.add_argument("--worlds", type=int, default=3, help="blind: worlds of 9 turned views each")
    ap.add_argument("--out", default=str(RESULTS / "calibrate.json"))
    ap.add_argument("--measure", default=None, help="the focus measure of the chart fit (default the runtime's; "
                    "aat_deploy.focus.measures); needs --truth-map calibrated with it")
    ap.add_argument("--prefilter-px", type=float, default=None, help="that measure's pre-filter (px)")
    ap.add_argument("--truth-map", default=None, help="the truth and prescription best-focus map (a path in the "
                    "repo; default lenses/best_focus/<lens>.json), calibrated for --measure")
    ap.add_argument("--truth", default=None, metavar="RENDER_TRUTH.json",
                    help="a render-consistent truth map (aat-render-truth-map-v1, benchmarks/render_truth_map.py; a "
                         "path in the repo) as part a's (and c's) truth instead of the best-focus map, which stays the "
                         "prescription's map; only with --parts map and/or needs")
    ap.add_argument("--cell-px", type=int, default=None,
                    help="the renderer's PSF anchor spacing (px) for the sweeps and held-out stacks (default 64; a "
                         "phone's best focus moves by diopters over 64 px: benchmarks/probes/phone_outer_field.py); "
                         "renders cached apart")
    ap.add_argument("--copies", type=int, default=0, metavar="K",
                    help="instead of the parts: parts a and b on K random copies per lens (benchmarks/calibrate_copies:"
                         " their distribution), resumed copy by copy from --out; with --parts departures only each "
                         "copy's field departure from the prescription (seconds per copy, no renders)")
    ap.add_argument("--copy-seed", type=int, default=2026, metavar="S", help="the random copies' seed")
    ap.add_argument("--tables", nargs="+", metavar="RESULT.json",
                    help="only print the tables of earlier runs' results, merged (BENCHMARKS.md's)")
    ap.add_argument("--figure", metavar="PNG", help="with --tables: also draw the random copies' gain against their "
                    "departure, every lens, the hand-chosen copies among them where the merged results hold them")
    a = ap.parse_args(argv)
    if a.tables:
        from benchmarks import calibrate_copies

        merged: dict = {"map": [], "depth": {}, "needs": {}, "blind": {}, "copies": {}, "departures": {}}
        for f in a.tables:
            r = json.loads(Path(f).read_text())
            merged["map"] += r.get("map", [])
            for k in ("depth", "needs", "blind", "copies", "departures"):
                merged[k].update(r.get(k, {}))
        print(tables(merged))
        if merged["copies"]:
            print("\n### Random copies\n\n" + calibrate_copies.tables(merged))
        if merged["departures"]:
            print("\n" + calibrate_copies.departure_table(merged))
        if a.figure:
            calibrate_copies.figure(merged, Path(a.figure))
        return 0
    parts = set(a.parts.split(","))
    log = lambda m: print(m, file=sys.stderr, flush=True)
    if a.truth is not None:
        if not parts <= {"map", "needs"} or a.copies:
            ap.error("--truth: only with --parts map and/or needs, without --copies (part b's oracle and depth keep "
                     "the best-focus map)")
        from benchmarks.render_truth_map import TruthMapError, load

        try:  # refused before any render
            tm = load(a.truth)
        except TruthMapError as e:
            raise SystemExit(f"bench_calibrate: --truth {e}") from None
        # a render truth is one lens's: scoring another lens against it would be silently wrong
        other = [k for k in a.lenses.split(",") if k in LENSES and LENSES[k].lens != tm.meta.get("lens")]
        if other:
            raise SystemExit(f"bench_calibrate: --truth {a.truth}: the render truth of {tm.meta.get('lens')}, not of "
                             f"{', '.join(f'{k} ({LENSES[k].lens})' for k in other)}")
    if a.copies:
        from benchmarks import calibrate_copies

        if a.parts == "departures":  # only each copy's field departure from the prescription (no renders)
            out = Path(a.out)
            res = json.loads(out.read_text()) if out.is_file() else {}
            for key in a.lenses.split(","):
                check_tolerance_table(LENSES[key])
                res.setdefault("departures", {})[key] = calibrate_copies.departures(
                    LENSES[key], Rig(LENSES[key]), a.copies, a.copy_seed, log)
                save(res, out)
            print(calibrate_copies.departure_table(res))
            return 0
        for key in a.lenses.split(","):
            setup = LENSES[key] if a.cell_px is None else dataclasses.replace(LENSES[key], cell_px=a.cell_px)
            check_tolerance_table(setup)
            rig = Rig(setup, a.truth_map, a.measure, a.prefilter_px)
            calibrate_copies.run(setup, rig, a.copies, a.copy_seed, a.n, a.boot, Path(a.out), log, save)
        done = json.loads(Path(a.out).read_text())
        calibrate_copies.figure(done, RESULTS / "figures" / f"{Path(a.out).stem}.png")
        print(calibrate_copies.tables(done))
        return 0
    res: dict = {"map": [], "depth": {}, "needs": {}, "blind": {}}
    for key in a.lenses.split(","):
        setup = LENSES[key] if a.cell_px is None else dataclasses.replace(LENSES[key], cell_px=a.cell_px)
        check_tolerance_table(setup)
        rig = Rig(setup, a.truth_map, a.measure, a.prefilter_px, a.truth)
        log(f"{key}: {rig.lens.name}")
        rows, fits = part_map(rig, a.boot, log)
        if "map" in parts:
            res["map"] += rows
        if "copy" not in fits:
            log(f"  {key}: the copy's sweeps were refused: no depth, needs or blind parts")
            save(res, Path(a.out))
            continue
        extra = {}
        if "blind" in parts:  # before depth, which then scores the blind fit from every capture as two more mappings
            res["blind"][key], blind = part_blind(rig, fits["copy"][0], a.worlds, log)
            if blind is not None:
                # as fitted (the reported focus kept), and with the chart's reported-focus error (one known distance)
                extra = {"blind calibration": blind,
                         "blind + chart focus error": dataclasses.replace(blind, focus_error=fits["copy"][0].focus_error)}
            save(res, Path(a.out))
        if "depth" in parts:
            res["depth"][key] = part_depth(rig, fits["copy"][0], a.n, log, extra)
        if "needs" in parts:
            res["needs"][key] = part_needs(rig, fits["copy"][1], log)
        save(res, Path(a.out))  # after every lens: a long run's finished lenses are kept
    print(tables(res))
    return 0


def save(res: dict, out: Path) -> None:
    from aat_deploy.io.atomic import write_text_atomic

    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps(res, indent=1, default=float))


if __name__ == "__main__":
    sys.exit(main())
