"""Fitting an effect's settings on the captures, continuously, at reduced resolution (docs/diagnosis.md, "Fitted
settings"). One function per effect with settings, registered in `FITTERS` by the effect's name; effects without
one are tried at their `candidates`. A fitter sees the captures and the twins with the effects named so far
(`FitState`) and returns the settings the images support (`Fitted.params`; None = the images do not support the
effect at all) with a report (intervals, the alternatives it weighed).

- focus-type effects (`focus_metadata`, `sensor_tilt`, and every effect with a sensor shift) fit on a focus sweep:
  the twin rendered at a ladder of focus distances, whose per-region focus measures are compared with the
  capture frames' (`focusfit`);
- `noise`: the full well whose twin's focus curves come closest (golden-section search in log electrons);
- geometric effects (`focus_breathing`, `misalignment`) from the capture-vs-twin shift of every region and frame
  (least squares on the response to the effect), `exposure` from the regions' brightness.

Torch-free and training-free: effects are made through `FitState.make` (the registry's `make`).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from statistics import NormalDist

import numpy as np

from aat_deploy.capture.raw import load_mosaic
from aat_deploy.diagnose import anchors, focusrobust, noisefloor, photon
from aat_deploy.diagnose import focusfit as ff
from aat_deploy.diagnose.binned import bin_frames, binned_capture
from aat_deploy.diagnose.compare import focus_curves, image_distances, region_brightness, region_index, region_shifts
from aat_deploy.diagnose.optimise import grid_then_golden
from aat_deploy.errors import CaptureError
from aat_deploy.infer.normalise import normalise_scale, normalise_stack, scaled
from aat_deploy.render.effects import NeedsTorch

SWEEP_STEP_D = 0.06  # focus sweep spacing (diopters); curves are interpolated between (Catmull-Rom)
SWEEP_MARGIN_D = ff.MAX_ERROR_D + 0.05
# whether the focus-metadata fit's sweep carries the twin's noise by its expectation (`noisefloor`) instead of a
# binned draw. Off: tried on scene 2038 (issue 32; docs/diagnosis.md, Limits, "Scene 2038"), not adopted.
NOISE_FLOOR = False
# whether the focus-metadata fit of RAW captures reads focus on its own twin with the capture's development,
# vignetting and noise by its expectation, the full well fitted against it (`focus_twin`; issue 32)
FOCUS_TWIN = True
FULL_WELL_RANGE_E = (300.0, 1e6)  # the full wells `full_well_on_floor` searches (electrons)
# whether the full well is fitted again on the sweep whose binning correction is anchored at the estimates too
# (`anchors.reanchored_sweep`), not only on the first sweep (anchored at the reported focus). Off: a probe of issue
# 32 after the eleventh round (docs/diagnosis.md, Limits; `benchmarks/probes/focus_start_invariance.py --mode refit`)
FULL_WELL_ON_FINAL_SWEEP = False
# whether the focus twin's full well is measured on the captures' RAW mosaics by photon transfer (`photon`, fixed
# before the focus fit) instead of fitted with the focus against the expected floor (`full_well_on_floor`, which
# absorbs the twin's curve misfit and moves with the metadata's error). Declared and scored on development sets
# (issue 32; docs/diagnosis.md, "The full well by photon transfer")
FULL_WELL_BY_PHOTON_TRANSFER = False
# whether, with the full well measured by photon transfer, the focus twin's floor is put at the capture's exposure:
# the twin is exposed by `TwinRenderer.linear`'s match of 99.5th percentiles (capture frames, all-in-focus image), which
# left the capture 1.03-1.35 x brighter than its twin in white-level units on the three development scenes measured,
# and the expected floor relative to the signal goes as one over it (`capture_exposure`; issue 32, docs/diagnosis.md,
# "The focus twin's misfit in the weak frames, noise off on both sides"). Declared, scored on development sets before
# it may be switched on
FLOOR_AT_CAPTURE_EXPOSURE = False
MIN_TEXTURE_LOG = 0.5  # a region whose twin focus measure varies less than this over the sweep says nothing


@dataclass
class Fitted:
    params: dict | None  # None: the images do not support the effect
    report: dict = field(default_factory=dict)


@dataclass
class FitState:
    """What the fitters see in one greedy round. twins: the full-resolution renderer; caps/aifs: the captures and
    the all-in-focus images the twins use; chain: the effects named so far (the current twin's extras); make:
    the registry's `make(name, **params)`; factor: binning of the search; n_boot, seed as the diagnosis's."""

    twins: object
    caps: list
    aifs: list
    chain: list
    make: Callable
    factor: int = 2
    n_boot: int = 200
    seed: int = 0
    sweep_cache: dict = field(default_factory=dict)  # shared between rounds (keyed by the chain's optics)
    full_curves: list | None = None  # per capture (R, S): fit_curves() of the full-resolution twin with the chain
    tb: object = None  # the binned renderer (made from twins if not given; pass one to keep its cache)

    def __post_init__(self):
        self.tb = self.tb if self.tb is not None else self.twins.binned(self.factor)
        self.caps_b = [binned_capture(c, self.factor) for c in self.caps]
        self.aifs_b = [bin_frames(a, self.factor) for a in self.aifs]
        self.real_b = [normalise_stack(c.frames) for c in self.caps_b]
        self.real_curves_b = [focus_curves(s) for s in self.real_b]
        self.base_b = [self.render_b(i, []) for i in range(len(self.caps))]

    def render_b(self, i: int, extra: list) -> np.ndarray:
        """Normalised binned twin of capture i with the chain plus `extra`."""
        return self.tb.render(self.caps_b[i], self.aifs_b[i], self.chain + list(extra), seed=self.seed + i)

    def image_distances_b(self, extra: list) -> list:
        """Per capture, the binned capture's image distances to the binned twin with the chain plus `extra`."""
        return [image_distances(r, c, self.render_b(i, extra))
                for i, (r, c) in enumerate(zip(self.real_b, self.real_curves_b))]


# --- focus sweep ------------------------------------------------------------------------------------------------
def focus_sweep(state: FitState, step_d: float = SWEEP_STEP_D, correct: bool = True,
                noise_floor: bool = False) -> ff.SweepData:
    """The twin with the chain's effects rendered (binned) at a ladder of focus distances covering every capture's
    reported and assumed focus +- SWEEP_MARGIN_D, its region focus measures against the capture frames'. Effects
    whose settings differ frame by frame (`stack` hooks) are left out of the sweep. Cached by the chain's
    effects (a later round that only adds noise re-applies it to the cached optics). correct: add the binning
    correction (when the full-resolution twin's curves are known). noise_floor: carry the chain's noise by its
    expected focus measure, scaled for a RAW development, instead of a draw (`noisefloor`; where it applies)."""
    tb = state.tb
    chain = [e for e in state.chain if not tb.has_stack_hook(e)]
    analytic = noise_floor and noisefloor.applies(chain)
    rep = [1.0 / c.focus_m for c in state.caps_b]
    base = [1.0 / tb.true_focus(c, state.chain, state.seed + i) for i, c in enumerate(state.caps_b)]
    allf = np.concatenate(rep + base)
    lo, hi = float(allf.min()) - SWEEP_MARGIN_D, float(allf.max()) + SWEEP_MARGIN_D
    fr = tb.focus_range_m()
    lo, hi = max(lo, 1.0 / fr[1], 0.011), min(hi, 1.0 / fr[0])
    grid = np.arange(lo, hi + 1e-9, step_d)
    key = (tuple(tb.spec(e) for e in chain), float(grid[0]), len(grid)) + (("noise_floor",) if analytic else ())
    if key not in state.sweep_cache:
        twin_curves, twin_lum, signal_c, floor_c, read_c = [], [], [], [], []
        factor_c = noisefloor.developed_factor(chain, state.factor) if analytic else None
        for i, (c, a) in enumerate(zip(state.caps_b, state.aifs_b)):
            if analytic:
                lin = np.clip(tb.linear(c, a, noisefloor.quiet(chain), state.seed + i, focus_true_m=1.0 / grid), 0, None)
                scale = float(normalise_scale(lin))
                stack = scaled(lin, scale)
                sig = focus_curves(stack, ff.FIT_GRID)  # (R, K, C) log
                nb = noisefloor.noise_of(chain).binned(state.factor)
                flo = noisefloor.floor(lin, scale, nb, factor_c, ff.FIT_GRID)
                signal_c.append(sig)
                floor_c.append(flo)
                read_c.append(np.broadcast_to(noisefloor.read_part(scale, nb, factor_c), flo.shape))
                twin_curves.append(noisefloor.compose(sig, flo))
            else:
                stack = normalise_stack(np.clip(tb.linear(c, a, chain, state.seed + i, focus_true_m=1.0 / grid), 0,
                                                None))
                twin_curves.append(focus_curves(stack, ff.FIT_GRID).mean(-1))
            twin_lum.append(region_brightness(stack, ff.FIT_GRID).mean(-1))
        state.sweep_cache[key] = (np.stack(twin_curves), np.stack(twin_lum),  # (n, R, K), (n, R)
                                  np.stack(signal_c) if analytic else None, np.stack(floor_c) if analytic else None,
                                  np.stack(read_c) if analytic else None)
    twin, twin_lum, signal_c, floor_c, read_c = state.sweep_cache[key]
    s_max = max(len(r) for r in rep)
    cap = np.full((len(rep), twin.shape[1], s_max), np.nan)
    cap_lum = np.full_like(cap, np.nan)
    rep_d, base_d = np.zeros((len(rep), s_max)), np.zeros((len(rep), s_max))
    for i, stack in enumerate(state.real_b):
        s = len(rep[i])
        cap[i, :, :s] = focus_curves(stack, ff.FIT_GRID).mean(-1)
        cap_lum[i, :, :s] = region_brightness(stack, ff.FIT_GRID)
        rep_d[i] = np.concatenate([rep[i], np.full(s_max - s, rep[i][-1])])
        base_d[i] = np.concatenate([base[i], np.full(s_max - s, base[i][-1])])
    weight = (twin.max(2) - twin.min(2) > MIN_TEXTURE_LOG).astype(np.float64)
    rows, cols = ff.FIT_GRID
    r, q = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    xy = np.stack([2 * (q.ravel() + 0.5) / cols - 1, 1 - 2 * (r.ravel() + 0.5) / rows], 1)
    data = ff.SweepData(grid, twin, cap, rep_d, base_d, xy, weight, cap_lum, twin_lum, signal_c, floor_c, read_c)
    if correct and state.full_curves is not None:
        data = data.with_correction(binning_correction(state, chain, grid, base, analytic))
    return data


def fit_curves(stack: np.ndarray, factor: int) -> np.ndarray:
    """(R, S) channel-mean log focus measures on the fitting grid of a normalised stack binned by `factor` (the
    full-resolution twin's, for `binning_correction`)."""
    return focus_curves(normalise_stack(bin_frames(stack, factor)), ff.FIT_GRID).mean(-1)


def binning_correction(state: FitState, chain: list, grid: np.ndarray, base: list,
                       noise_floor: bool = False) -> np.ndarray:
    """(n, R, K) what the binned renderer misses against the binned full-resolution twin, per region, as a
    function of focus: the difference of their focus measures at the twin's own frames (where both exist),
    interpolated in focus over the sweep (flat beyond). A binned render cannot reproduce a nearly sharp PSF's
    sub-pixel phases (binning averages four of them), which biases the focus of the frames whose content is
    nearly sharp by up to 0.03 D on the shipped sample; the full-resolution twin is rendered anyway. noise_floor:
    both without the noise (the sweep carries it by its expectation, `noisefloor`): the correction of the
    noiseless measure."""
    out = []
    for i, (c, a) in enumerate(zip(state.caps_b, state.aifs_b)):
        lin = state.tb.linear(c, a, noisefloor.quiet(chain) if noise_floor else chain, state.seed + i)
        own = focus_curves(normalise_stack(np.clip(lin, 0, None)), ff.FIT_GRID).mean(-1)  # (R, S)
        full = state.full_curves[i] if not noise_floor else fit_curves(
            state.twins.render(state.caps[i], state.aifs[i], noisefloor.quiet(chain), seed=state.seed + i), state.factor)
        delta = full - own
        order = np.argsort(base[i])
        out.append(np.stack([np.interp(grid, base[i][order], dr[order]) for dr in delta]))
    return np.stack(out)


def shifted_focus_d(table, focus_d: np.ndarray, dz_mm: np.ndarray) -> np.ndarray:
    """Focus (diopters) seen where the sensor sits dz_mm further from the lens than at axis focus focus_d,
    through the lens's focus table (clipped to it)."""
    z = np.interp(focus_d, table.diopters, table.sensor_z_mm) + dz_mm
    return np.interp(np.clip(z, table.sensor_z_mm[0], table.sensor_z_mm[-1]), table.sensor_z_mm, table.diopters)


def captures_raw(state: FitState) -> bool:
    """Whether every capture's frames are RAW files (developed by the runtime, as `raw_pipeline` develops a twin)."""
    from aat_deploy.capture.imagefile import frame_kind

    for c in state.caps:
        files = list(getattr(c, "files", []) or [])
        if not files:
            return False
        path = Path(c.path) / files[0]
        try:
            with path.open("rb") as f:
                if frame_kind(path, f.read(1 << 16)) != "raw":
                    return False
        except (OSError, ValueError, CaptureError):
            return False
    return True


def lighting_misfit(state: FitState, chain: list) -> float:
    """How differently the binned twin with `chain` (no noise drawn) is lit across the field from the captures: per
    capture, every region's median over the frames of the log luminance ratio (capture over twin), less its median
    over the regions, squared and summed (a global exposure counts nothing)."""
    total = 0.0
    for i, (c, a, real) in enumerate(zip(state.caps_b, state.aifs_b, state.real_b)):
        lin = np.clip(state.tb.linear(c, a, noisefloor.quiet(chain), state.seed + i), 0, None)
        res = region_brightness(real, ff.FIT_GRID) - region_brightness(normalise_stack(lin), ff.FIT_GRID)
        per = np.median(res, 1)
        total += float(np.sum((per - np.median(per)) ** 2))
    return total


def focus_twin(state: FitState) -> tuple[FitState, dict] | None:
    """The twin the focus-metadata fit reads focus on, when the captures are RAW files (`FOCUS_TWIN`; issue 32):
    the round's chain with the capture's own nuisances put in first, whatever the greedy search has named so far,
    so that the focus is fitted after them: the RAW development (`raw_pipeline`, the runtime's), vignetting when
    it brings the twin's lighting across the field closer to the captures' (`lighting_misfit`), and the noise
    carried by its expectation (`noisefloor`), at a reference full well that `fit_focus_metadata` then refits
    against the expected floor (`full_well_on_floor`; a noise the chain has, fitted on binned draws, is replaced).
    None (the chain as it is, noise drawn) for other captures (a phone's JPEG: its processing changes the noise
    the floor assumes), when an effect after the noise is not a development, or when the model's own simulator
    renders noise."""
    if not captures_raw(state):
        return None
    base = {e.name for e in getattr(state.twins, "base", [])}
    if "noise" in base:
        return None
    n = noisefloor.noise_of(state.chain)
    if n is not None and not noisefloor.applies(state.chain):
        return None
    chain = [e for e in state.chain if e.name != "noise"]
    names = base | {e.name for e in chain}
    rep: dict = {"added": []}
    if "raw_pipeline" not in names:
        chain.append(state.make("raw_pipeline"))
        rep["added"].append("raw_pipeline")
    if "vignetting" not in names:
        with_v = chain + [state.make("vignetting")]
        try:
            m0, m1 = lighting_misfit(state, chain), lighting_misfit(state, with_v)
        except NeedsTorch as e:  # no lens source to render it without torch: left out
            rep["lighting_misfit"] = {"skipped": str(e)}
        else:
            rep["lighting_misfit"] = {"without_vignetting": m0, "with_vignetting": m1}
            if m1 < m0:
                chain = with_v
                rep["added"].append("vignetting")
    chain.append(state.make("noise"))  # the reference full well: refitted on the expected floor
    twin = copy.copy(state)
    twin.chain = chain
    rep["chain"] = [e.name for e in chain]
    return twin, rep


def full_well_on_floor(data: ff.SweepData, full_well_e: float) -> tuple[float | None, dict]:
    """The full well (electrons) whose expected noise floor (`noisefloor`) makes the sweep `data` (made with
    `full_well_e`, its floor) fit the captures best, every frame's focus free (`focusfit.frame_focus`) and each
    frame's exposure corrected as `focusrobust.prepare` corrects it: grid then golden-section search in log
    electrons over FULL_WELL_RANGE_E. None when no floor fits better than none (or the best is at the noiseless
    end)."""
    base = dataclasses.replace(data, capture=data.capture - 2.0 * focusrobust.frame_gains_log(data)[:, None, :])
    seen: dict[float, float] = {}

    def cost(u: float) -> float:
        if u not in seen:
            d = base.with_full_well(full_well_e / math.exp(u) if math.isfinite(u) else 0.0)
            seen[u] = ff.residual_ss(d, ff.frame_focus(d, start=data.base_d))
        return seen[u]

    lo, hi = (math.log(x) for x in FULL_WELL_RANGE_E)
    u, v = grid_then_golden(cost, lo, hi, n=8, tol=0.05)
    none = cost(math.inf)
    rep = {"full_well_e": math.exp(u), "ss": v, "ss_without": none,
           "profile": {f"{math.exp(k):.0f}": val for k, val in sorted(seen.items()) if math.isfinite(k)}}
    if u > hi - 0.3 or v >= none:
        return None, rep
    return _sig(math.exp(u), 2), rep


def full_well_by_photon_transfer(caps: list) -> tuple[float | None, dict]:
    """The sensor's full well (electrons, in the developed frames' units) measured on the captures' own RAW mosaics
    (`photon.photon_transfer`, every frame of every capture pooled: one sensor), divided by the development's gain
    (the frames' channel means summed over the mosaics' colour means summed). None, with the reason, when a frame is
    not a RAW file with a 2 x 2 mosaic, when the frames were resampled to the model's sensor (that changes the noise
    per pixel), or when too few flat patches were found."""
    planes, dev, raw = [], 0.0, 0.0
    for c in caps:
        for name, frame in zip(getattr(c, "files", None) or [], c.frames):
            try:
                m, info = load_mosaic(Path(c.path) / name)
            except CaptureError as e:
                return None, {"skipped": str(e)}
            if np.shape(info["raw_pattern"]) != (2, 2):
                return None, {"skipped": f"{name}: not a 2 x 2 colour mosaic"}
            if m.shape != frame.shape[1:]:
                return None, {"skipped": f"{name}: frames resampled to the model's sensor ({m.shape} -> "
                                         f"{frame.shape[1:]}): their noise per pixel is not the mosaic's"}
            pl = photon.cfa_planes(m)
            planes += pl
            # the gain colour by colour: the mosaic holds twice as many greens as the developed frame weighs
            colour = [{0: 0, 1: 1, 2: 2, 3: 1}.get(int(k), -1) for k in np.ravel(info["raw_pattern"])]  # LibRaw: RGBG
            for ch in range(3):
                mine = [float(np.mean(q, dtype=np.float64)) for q, k in zip(pl, colour) if k == ch]
                if mine:
                    dev, raw = dev + float(np.mean(frame[ch], dtype=np.float64)), raw + float(np.mean(mine))
    if not planes or not raw > 0:
        return None, {"skipped": "no RAW frames"}
    got = photon.photon_transfer(planes)
    if got is None:
        return None, {"skipped": "too few flat patches for a photon-transfer curve"}
    gain = dev / raw
    return _sig(got["full_well_e"] / gain, 2), {**got, "mosaic_full_well_e": got["full_well_e"], "gain": gain}


def capture_exposure(state: FitState) -> tuple[np.ndarray, dict]:
    """(n,) per capture, its exposure over the twin's in white-level units: the median over its frames of the binned
    capture frame's mean over the binned twin's (the chain without its noise and without the effects that act frame by
    frame, at the twin's own focus; blur keeps a frame's mean light, the twin's vignetting is in its chain). The
    expected floor relative to the signal goes as one over the exposure (shot noise's variance as the signal, its
    Laplacian energy as the signal squared), so the floor in the capture's units is the twin's at a full well k times
    the capture's (`SweepData.with_full_well(fw0 / (fw k))`). And a report."""
    chain = noisefloor.quiet([e for e in state.chain if not state.tb.has_stack_hook(e)])
    out = []
    for i, (c, a) in enumerate(zip(state.caps_b, state.aifs_b)):
        lin = np.clip(state.tb.linear(c, a, chain, state.seed + i), 0, None)
        cap = np.asarray(c.frames, np.float64)
        per = cap.reshape(len(cap), -1).mean(1) / np.maximum(lin.reshape(len(lin), -1).mean(1, dtype=np.float64), 1e-12)
        out.append(float(np.median(per)))
    return np.array(out), {"exposure_ratio": [round(x, 4) for x in out]}


def fit_focus_metadata(state: FitState) -> Fitted:
    """The focus-metadata error family the images support (`focusfit.fit_metadata`, on the sweep made robust to
    the frames' exposure, the capture's noise floor and poorly matched regions: `focusrobust.prepare`) and the
    corrected focus distances of every capture (metres, with intervals). With RAW captures (`FOCUS_TWIN`) the sweep
    is the `focus_twin`'s: the development, vignetting and the noise by its expected floor, the full well fitted
    against that floor (`full_well_on_floor`). Frames whose expected measure is mostly noise there
    (`focusfit.noise_share` at their estimates, at least NOISE_DOMINATED_SHARE) are left out of the fit and reported
    undetermined, without an estimate."""
    made = focus_twin(state) if FOCUS_TWIN else None
    st, floor_on, twin_rep = (made[0], True, made[1]) if made is not None else (state, NOISE_FLOOR, {})
    fitted: dict = {}

    def with_noise(d: ff.SweepData) -> ff.SweepData:
        """The sweep at the full well fitted against its expected floor (fitted once, on the first sweep seen)."""
        if made is None or d.floor_c is None:
            return d
        if "ratio" not in fitted:
            fw0 = float(noisefloor.noise_of(st.chain).params["full_well_e"])
            fw, rep = full_well_by_photon_transfer(st.caps) if FULL_WELL_BY_PHOTON_TRANSFER else (None, {})
            k = 1.0
            if fw is not None:  # measured before the focus fit: the metadata's error cannot move it
                rep = {"photon_transfer": rep, "fitted_full_well_e": fw}
                if FLOOR_AT_CAPTURE_EXPOSURE:  # the floor at the capture's exposure, not the twin's
                    k, krep = capture_exposure(st)
                    rep["capture_exposure"] = {**krep, "effective_full_well_e": [round(fw * x) for x in k]}
            else:  # fitted against the floor: whatever the twin's exposure misses, the fitted value takes up
                fw, fit_rep = full_well_on_floor(d, fw0)
                rep = {**fit_rep, **({"photon_transfer": rep} if rep else {}), "fitted_full_well_e": fw}
            fitted.update(ratio=0.0 if fw is None else fw0 / (fw * k), report=rep)
        return d.with_full_well(fitted["ratio"])

    if st.full_curves is not None:  # the binning correction anchored at the frames' estimated focus too
        sweep, anchored = anchors.reanchored_sweep(
            st, focus_sweep(st, correct=False, noise_floor=floor_on),
            lambda d: np.asarray(focusrobust.prepare(with_noise(d))[1]["frame_focus_d"][-1]))
    else:
        sweep, anchored = focus_sweep(st, noise_floor=floor_on), {}
    if FULL_WELL_ON_FINAL_SWEEP and anchored.get("reanchored_d"):
        fitted.clear()  # the full well fitted again where the correction is anchored at the estimates too
    sweep = with_noise(sweep)
    fit, robust = focusrobust.fit_robust(sweep, n_boot=state.n_boot, seed=state.seed)
    if made is not None:
        twin_rep = {**twin_rep, "noise": fitted.get("report")}
    rep = {"focus_fit": {**fit.summary(), "robust": {**robust, **anchored},
                         **({"focus_twin": twin_rep} if made is not None else {})}, "corrected_focus": []}
    z = NormalDist().inv_cdf(0.975)
    for i, c in enumerate(state.caps):
        s = len(c.focus_m)
        rep["corrected_focus"].append({
            "capture": c.name, "files": list(getattr(c, "files", []) or []), "reported_m": c.focus_m.tolist(),
            "corrected_m": (1.0 / fit.best.true_d[i, :s]).tolist(),
            "ci_m": [[1.0 / hi, 1.0 / lo] for lo, hi in fit.true_d_ci[i, :s]],
            # the systematic part included (`focusfit.corrected_sd`): frames it leaves undetermined are flagged
            "total_ci_m": [[1.0 / (d + z * e), 1.0 / max(d - z * e, 1e-6)]
                           for d, e in zip(fit.best.true_d[i, :s], fit.true_d_sd[i, :s])],
            "undetermined": fit.undetermined[i, :s].tolist(),
            "noise_dominated": fit.noise_dominated[i, :s].tolist(),
            "left_out_on_bound": (fit.bound_left_out[i, :s] if fit.bound_left_out is not None
                                  else np.zeros(s, bool)).tolist()})
    return Fitted(None if fit.best.name == "none" else _rounded(fit.best.params), rep)


def shift_fit(state: FitState, name: str, keys: tuple[str, ...], step, lower, upper, fixed: dict | None = None,
              n_boot: int = 30) -> tuple[dict, ff.ShiftFit]:
    """Least-squares fit on the focus sweep of an effect that shifts the sensor across the field
    (`Effect.sensor_shift_mm`): the settings `keys` (others `fixed`) and the fit."""
    data = focus_sweep(state)
    table = state.tb.focus_table()
    ctx = state.tb.context()
    x, y = data.field_xy[:, 0], data.field_xy[:, 1]
    base_m = 1.0 / data.base_d
    fixed = fixed or {}

    def focus_of(theta):
        fn = state.make(name, **fixed, **dict(zip(keys, map(float, theta)))).sensor_shift_mm(ctx)
        if fn is None:
            return np.broadcast_to(data.base_d[:, None, :], data.capture.shape)
        dz = np.stack([np.asarray(fn(x[:, None], y[:, None], base_m[i][None, :]), np.float64)
                       * np.ones((len(x), base_m.shape[1])) for i in range(len(base_m))])  # (n, R, S)
        return shifted_focus_d(table, data.base_d[:, None, :], dz)

    fit = ff.fit_shift(data, focus_of, np.zeros(len(keys)), step, lower, upper, n_boot=n_boot, seed=state.seed)
    return {**fixed, **dict(zip(keys, (float(v) for v in fit.params)))}, fit


def _shift_report(params: dict, keys, fit: ff.ShiftFit) -> dict:
    return {"params": params, "params_ci": {k: fit.ci[j].tolist() for j, k in enumerate(keys)}, "bic": fit.bic,
            "bic_none": fit.bic_none, "ss": fit.ss, "ss_none": fit.ss_none}


def supported(fit: ff.ShiftFit) -> bool:
    """A field-dependent focus change the images support: some setting's bootstrap interval (regions and
    captures resampled) excludes 0. Not BIC with frames as observations: the change is read from the pattern
    across the regions of every frame, which one number per frame would hide."""
    return bool(np.any((fit.ci[:, 0] > 0) | (fit.ci[:, 1] < 0)))


def refine_amount(state: FitState, name: str, params: dict, keys: tuple[str, ...]) -> tuple[dict, float]:
    """The sweep reads a field-dependent focus as each region refocused; the renderer moves the focus anchor by
    anchor, and the two differ in size (a -0.85 deg tilt read as -0.54 before the renderer fix c9c07bd, -0.73
    after it: benchmarks/diagnose_tilt_refit.py). So the amount is refitted on binned twins with the effect: its
    settings scaled by one factor (golden-section search over 0.5..2.5, the direction kept), the factor whose
    twin's focus curves come closest."""
    seen: dict[float, float] = {}

    def cost(c):
        if c not in seen:
            e = state.make(name, **{**params, **{k: params[k] * c for k in keys}})
            seen[c] = float(np.mean([d.focus_curves for d in state.image_distances_b([e])]))
        return seen[c]

    c, _ = grid_then_golden(cost, 0.5, 2.5, n=5, tol=0.05)
    return {**params, **{k: params[k] * c for k in keys}}, c


def fit_sensor_shift(state: FitState, name: str, keys: tuple[str, ...], step, lower, upper) -> Fitted:
    """Settings of an effect that shifts the sensor across the field: by least squares on the focus sweep, the
    amount then refitted on binned renders (`refine_amount`); None when no setting's interval excludes 0
    (`supported`)."""
    params, fit = shift_fit(state, name, keys, step, lower, upper)
    rep = {"shift_fit": _shift_report(params, keys, fit)}
    if not supported(fit):
        return Fitted(None, rep)
    params, c = refine_amount(state, name, params, keys)
    rep["shift_fit"]["refined"] = {"params": params, "factor": c}
    return Fitted(_rounded(params), rep)


def fit_lens_tolerance(state: FitState) -> Fitted:
    """The single perturbation of the lens (one air gap, or one element decentred in x and y; `choices`) whose
    change of the focal surface fits the focus sweep best (each fitted by least squares, amounts up to +-0.5 mm;
    compared by BIC over every region and frame, a decentre paying for its second setting), with its interval;
    None when its interval includes 0 (`supported`)."""
    proto = state.make("lens_tolerance")
    results = []
    n = focus_sweep(state).n_frames * ff.FIT_GRID[0] * ff.FIT_GRID[1]
    for choice in proto.choices(state.tb.lens):
        keys = ("gap_mm",) if "gap" in choice else ("decentre_x_mm", "decentre_y_mm")
        params, fit = shift_fit(state, "lens_tolerance", keys, [0.1] * len(keys), [-0.5] * len(keys),
                                [0.5] * len(keys), fixed=choice, n_boot=0)
        results.append((n * math.log(max(fit.ss, 1e-300) / n) + len(keys) * math.log(n), choice, keys, params, fit))
    bic, choice, keys, _, _ = min(results, key=lambda r: r[0])
    params, fit = shift_fit(state, "lens_tolerance", keys, [0.1] * len(keys), [-0.5] * len(keys), [0.5] * len(keys),
                            fixed=choice, n_boot=20)
    rep = {"shift_fit": _shift_report(params, keys, fit),
           "alternatives": [{"choice": c, "params": p, "bic": b} for b, c, _, p, _ in sorted(results, key=lambda r: r[0])]}
    if not supported(fit):
        return Fitted(None, rep)
    params, c = refine_amount(state, "lens_tolerance", params, keys)
    rep["shift_fit"]["refined"] = {"params": params, "factor": c}
    return Fitted(_rounded(params), rep)


def fit_sensor_tilt(state: FitState) -> Fitted:
    return fit_sensor_shift(state, "sensor_tilt", ("tilt_x_deg", "tilt_y_deg"), [0.5, 0.5], [-3, -3], [3, 3])


# --- post-optics effects --------------------------------------------------------------------------------------
def fit_noise(state: FitState) -> Fitted:
    """The full well (electrons) whose binned twin's focus curves come closest to the captures' (golden-section
    search in log electrons over 50 .. 1e6); None when the best is at the noiseless end."""
    read = float(state.make("noise").params["read_noise_e"])
    lo, hi = math.log(50.0), math.log(1e6)
    seen: dict[float, float] = {}

    def cost(u):
        if u not in seen:
            e = state.make("noise", full_well_e=math.exp(u), read_noise_e=read)
            seen[u] = float(np.mean([d.focus_curves for d in state.image_distances_b([e])]))
        return seen[u]

    u, v = grid_then_golden(cost, lo, hi, n=8, tol=0.05)
    base = float(np.mean([np.mean(np.abs(c - focus_curves(b))) for c, b in zip(state.real_curves_b, state.base_b)]))
    rep = {"noise_fit": {"full_well_e": math.exp(u), "focus_curve_distance": v, "without": base,
                         "profile": {f"{math.exp(k):.0f}": val for k, val in sorted(seen.items())}}}
    if u > hi - 0.3 or v >= base:
        return Fitted(None, rep)
    return Fitted({"full_well_e": _sig(math.exp(u), 2), "read_noise_e": read}, rep)


def fit_breathing(state: FitState) -> Fitted:
    """The breathing coefficient k (1 = the lens's model) by least squares on the capture-vs-twin region shifts
    against the shifts k = 1 causes; None when k < 0.1."""
    num = den = 0.0
    for i, (real, base) in enumerate(zip(state.real_b, state.base_b)):
        # phase correlation: breathing moves the edges by pixels, beyond one Lucas-Kanade step; its low bias on
        # smooth content hits both measurements alike, so their ratio holds
        s_obs = region_shifts(real, base)  # twin against capture
        unit = region_shifts(base, state.render_b(i, [state.make("focus_breathing", coefficient=1.0)]))
        num -= float(np.sum(s_obs * unit))  # the capture is the twin with breathing: shifts oppose
        den += float(np.sum(unit * unit))
    k = num / den if den > 0 else 0.0
    rep = {"breathing_fit": {"coefficient": k}}
    return Fitted({"coefficient": _sig(min(k, 5.0), 2)} if k >= 0.1 else None, rep)


def fit_exposure(state: FitState) -> Fitted:
    """Every capture's per-frame gains from its regions' brightness against the twin's (`region_gains`); None
    when no frame differs by 0.5 %."""
    gains = {c.name: region_gains(r, b) for c, r, b in zip(state.caps, state.real_b, state.base_b)}
    worst = max(float(np.max(np.abs(np.log(g)))) for g in gains.values())
    rep = {"exposure_fit": {"gains": {k: v.tolist() for k, v in gains.items()}, "largest_log_gain": worst}}
    if worst < 0.005:
        return Fitted(None, rep)
    return Fitted({"by_capture": {k: [round(float(x), 4) for x in v] for k, v in gains.items()}}, rep)


def fit_focus_brightness(state: FitState) -> Fitted:
    """The coefficient k of `focus_brightness` (1 = the lens's geometry) by least squares of every capture's
    per-frame log gains against the twin (`region_gains`) on the log gains k = 1 makes (both less their mean over
    the frames: a common exposure is no focus effect); None when k < 0.1."""
    from aat_deploy.render.effects.focus_brightness import irradiance_gains

    num = den = 0.0
    ctx = state.tb.context()
    for c, real, base in zip(state.caps_b, state.real_b, state.base_b):
        g = np.log(region_gains(real, base))
        u = np.log(irradiance_gains(state.tb.true_focus(c, state.chain, state.seed), ctx))
        g, u = g - g.mean(), u - u.mean()
        num, den = num + float(g @ u), den + float(u @ u)
    k = num / den if den > 0 else 0.0
    rep = {"brightness_fit": {"coefficient": k}}
    return Fitted({"coefficient": _sig(min(k, 5.0), 2)} if k >= 0.1 else None, rep)


def frame_warps(shifts: np.ndarray, h: int, w: int, grid: tuple[int, int]) -> np.ndarray:
    """Per frame (dx, dy, scale) that moves the twin onto the capture, by least squares on region shifts (R, S, 2)
    of the twin against the capture (`region_shifts(capture, twin)`; x right, y down, pixels) on `grid` regions
    of an (h, w) image: capture = twin magnified by scale about the centre, then moved by (dx, dy). One pass of
    outlier rejection (regions more than 3 median deviations off)."""
    rows, cols = grid
    r, q = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    px = ((q.ravel() + 0.5) * w / cols - w / 2, (r.ravel() + 0.5) * h / rows - h / 2)
    a = np.zeros((2 * rows * cols, 3))
    a[0::2, 0], a[1::2, 1] = 1, 1
    a[0::2, 2], a[1::2, 2] = px
    out = []
    for i in range(shifts.shape[1]):
        u = -shifts[:, i, :].reshape(-1)  # capture content against the twin's
        keep = np.ones(len(u), bool)
        for _ in range(2):
            sol = np.linalg.lstsq(a[keep], u[keep], rcond=None)[0]
            res = np.abs(a @ sol - u)
            keep = res <= max(3 * np.median(res), 0.05)
        out.append((sol[0], sol[1], 1.0 + sol[2]))
    return np.array(out)


def region_shifts_lk(a: np.ndarray, b: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """(R, S, 2) shift (dx right, dy down; pixels) of stack b against stack a per region and frame, by one
    Lucas-Kanade step on the luminance (lightly smoothed): unbiased for sub-pixel shifts of smooth, defocused
    content, where phase correlation's estimate falls short; iterate (warp, measure again) for larger ones."""
    import cv2

    s, _, h, w = a.shape
    rows, cols = grid
    reg = region_index(h, w, grid).ravel()
    n_r = rows * cols
    out = np.zeros((n_r, s, 2))
    for i in range(s):
        la = cv2.GaussianBlur(a[i].mean(0).astype(np.float32), (0, 0), 1.0)
        lb = cv2.GaussianBlur(b[i].mean(0).astype(np.float32), (0, 0), 1.0)
        gy, gx = np.gradient(lb)
        diff = (la - lb).ravel()
        gx, gy = gx.ravel(), gy.ravel()
        sums = [np.bincount(reg, weights=v, minlength=n_r) for v in (gx * gx, gx * gy, gy * gy, gx * diff, gy * diff)]
        sxx, sxy, syy, bx, by = sums
        det = sxx * syy - sxy * sxy
        ok = det > 1e-12 * np.maximum(sxx + syy, 1e-30) ** 2
        dx = np.where(ok, (syy * bx - sxy * by) / np.where(ok, det, 1), 0.0)
        dy = np.where(ok, (sxx * by - sxy * bx) / np.where(ok, det, 1), 0.0)
        out[:, i] = np.stack([dx, dy], 1)  # a(q) = b(q + d): b is a moved by d
    return out


def refine_warps(state: FitState, real: np.ndarray, twin: np.ndarray, iterations: int = 4) -> np.ndarray:
    """(S, 3) per-frame dx, dy (binned pixels) and scale that move `twin` onto `real`: `frame_warps` on the region
    shifts (`region_shifts_lk`), then again on the twin warped so far, until the remaining shift is gone."""
    from aat_deploy.diagnose.bins import MAP_GRID

    h, w = real.shape[-2:]
    ctx = state.tb.context()
    acc = np.tile([0.0, 0.0, 1.0], (len(real), 1))
    moved = twin
    for _ in range(iterations):
        d = frame_warps(region_shifts_lk(real, moved, MAP_GRID), h, w, MAP_GRID)
        acc[:, :2] = d[:, 2:3] * acc[:, :2] + d[:, :2]  # p -> s2 (s1 p + t1) + t2
        acc[:, 2] *= d[:, 2]
        moved = state.make("misalignment", sigma_px=0.0, by_capture={"": acc.ravel().tolist()}).stack(
            twin, None, ctx, None)
    return acc


def fit_misalignment(state: FitState) -> Fitted:
    """Every capture's per-frame shifts and magnifications from the capture-vs-twin region shifts (`refine_warps`),
    at full-resolution pixels. The part of the magnification that focus breathing explains (least squares on the
    magnifications breathing of coefficient 1 would add) is left to `focus_breathing`. None when no frame moves by
    0.15 px nor scales by 5e-4."""
    by, worst = {}, (0.0, 0.0)
    for i, (c, real, base) in enumerate(zip(state.caps, state.real_b, state.base_b)):
        wp = refine_warps(state, real, base)
        unit = refine_warps(state, state.render_b(i, [state.make("focus_breathing", coefficient=1.0)]), base, 2)[:, 2] - 1
        m = wp[:, 2] - 1.0
        k = float(np.dot(m, unit) / np.dot(unit, unit)) if np.dot(unit, unit) > 0 else 0.0
        wp[:, 2] = 1.0 + m - max(k, 0.0) * unit
        wp[:, :2] *= state.factor
        by[c.name] = [round(float(x), 4) for x in wp.ravel()]
        worst = (max(worst[0], float(np.abs(wp[:, :2]).max())), max(worst[1], float(np.abs(wp[:, 2] - 1).max())))
    rep = {"misalignment_fit": {"by_capture": by, "largest_shift_px": worst[0], "largest_scale_change": worst[1]}}
    if worst[0] < 0.15 and worst[1] < 5e-4:
        return Fitted(None, rep)
    return Fitted({"sigma_px": 0.0, "by_capture": by}, rep)


FITTERS: dict[str, Callable[[FitState], Fitted]] = {
    "focus_metadata": fit_focus_metadata,
    "sensor_tilt": fit_sensor_tilt,
    "noise": fit_noise,
    "focus_breathing": fit_breathing,
    "focus_brightness": fit_focus_brightness,
    "exposure": fit_exposure,
    "misalignment": fit_misalignment,
    "lens_tolerance": fit_lens_tolerance,
}


def _sig(x: float, digits: int) -> float:
    """x to `digits` significant digits (fitted settings are rounded so later rounds reuse renders)."""
    if x == 0 or not math.isfinite(x):
        return x
    return float(f"{x:.{digits}g}")


def _rounded(params: dict) -> dict:
    """Fitted settings at the precision that matters (0.01 deg, 0.001 D, 4 significant digits): twins of later
    rounds with the same fit hit the render cache."""
    out = {}
    for k, v in params.items():
        if isinstance(v, list):
            out[k] = [round(float(x), 4) for x in v]
        elif isinstance(v, float) and k.endswith("_deg"):
            out[k] = round(v, 2)
        elif isinstance(v, float) and k.endswith("_d"):
            out[k] = round(v, 4)
        elif isinstance(v, float):
            out[k] = _sig(v, 4)
        else:
            out[k] = v
    return out


def region_gains(real: np.ndarray, twin: np.ndarray) -> np.ndarray:
    """Per frame, the capture's luminance over the twin's (median over regions of the log ratio, less the
    median over frames): (S,) gains."""
    d = region_brightness(real) - region_brightness(twin)  # (R, S)
    per = np.median(d, 0)
    return np.exp(per - np.median(per))


__all__ = ["FITTERS", "FitState", "Fitted", "focus_sweep", "region_gains", "region_index"]
