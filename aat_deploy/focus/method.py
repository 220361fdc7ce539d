"""Depth from focus without a trained model: `classical_depth(stack (S, 3, H, W), focus_m) -> FocusResult`, numpy
only (the capture-level method is `aat_deploy.focus.runner.FocusMethod`; frames as (S, H, W, 3): the Python API's
`aat_deploy.api.depth_from_focus(..., method="focus")`).

Steps (each a module of this package): focus measure per frame (`measures`) -> frames with equal reported focus
placed from the images (`placement`) -> per-pixel peak of the focus curve in diopters with a confidence
(`estimate`), on the nominal focus distances (thin-lens mapping) or, given a `BestFocusMap`, on the object distance
each frame has in best focus at the pixel's field radius (aberration-aware mapping, `bestfocus`) -> all-in-focus
blend and the focus weights' spread (`aif`) -> unconfident pixels filled along the all-in-focus image (`fill`).

Defaults were chosen by measurement (benchmarks/bench_focus.py, BENCHMARKS.md; docs/focus_method.md).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ..confidence import Calibration, agreement, focus_calibration
from .aif import AIF_MODES, blend, blend_at, focus_weights, spread_m
from .bestfocus import BestFocusMap
from .estimate import ESTIMATORS, estimate_peak
from .fill import fill_with_support
from .measures import MEASURES, focus_volume
from .placement import place_equal_focus, tied_groups

MIN_DIOPTERS = 1e-3  # 1 km: estimates past infinity (a far frame's field shift) are clamped here
FILL_MODES = ("none", "fill")
CONFIDENCE_MODES = ("calibrated", "raw")


@dataclass(frozen=True)
class FocusConfig:
    """measure / window_px: focus measure and its window (px); prefilter_px: Gaussian blur of each grey frame
    before the measure (standard deviation, px; 0 = none), against sensor noise; estimator: peak refinement
    (gamma: the `ratio` estimator's tail exponent, None = per measure, see `tail_exponent`); aif: blending mode and
    power; fill: "fill" (edge-aware filling of unconfident pixels) or "none", with the domain transform's spatial
    sigma (px at full size), range sigma (guide units, sqrt of the normalised AiF) and the confidence at which a
    pixel keeps its own estimate; radius_bins: resolution of the aberration-aware lookup; calibrated: add the
    best-focus map's measured offset (if it has one); confidence: "calibrated" (the chance that the depth is within
    10 % of the truth, `aat_deploy.confidence`) or "raw" (the focus-curve contrast, as before the calibration
    existed). The fill weighs by the raw contrast either way (c_full on its scale): the calibration changes what
    the confidence says, not the depth."""

    measure: str = "mlap2"
    window_px: float = 15.0
    prefilter_px: float = 1.0  # chosen on validation stacks, clean and noisy (benchmarks/select_focus_noise.py)
    estimator: str = "ratio"
    gamma: float | None = None
    aif: str = "weights"
    aif_power: float = 4.0
    fill: str = "fill"
    sigma_s_px: float = 40.0
    sigma_r: float = 0.1
    c_full: float = 0.5
    fill_downscale: int = 2
    radius_bins: int = 256
    calibrated: bool = True
    confidence: str = "calibrated"

    @property
    def tail_exponent(self) -> float:
        """gamma of the `ratio` estimator: 1 for the squared measures, 0.5 for `sml` (a rectified, unsquared
        response falls off half as fast in log)."""
        return self.gamma if self.gamma is not None else MEASURES[self.measure].tail_exponent

    def __post_init__(self):
        for name, v, allowed in (("measure", self.measure, MEASURES), ("estimator", self.estimator, ESTIMATORS),
                                 ("aif", self.aif, AIF_MODES), ("fill", self.fill, FILL_MODES),
                                 ("confidence", self.confidence, CONFIDENCE_MODES)):
            if v not in allowed:
                raise ValueError(f"unknown {name} {v!r} (one of {', '.join(allowed)})")
        if not self.window_px > 0 or self.radius_bins < 2 or not self.prefilter_px >= 0:
            raise ValueError("window_px must be > 0, prefilter_px >= 0 and radius_bins >= 2")


@dataclass
class FocusResult:
    """depth_m (H, W) metres from the sensor; aif (3, H, W) in the stack's units; std_m (H, W) spread of the focus
    weights (m); confidence (H, W) in [0, 1] (calibrated: the chance that depth_m is within the calibration's
    tolerance; a filled pixel's is the fill's); diopters (H, W) the estimate before filling; focus_m (S,) the
    frames' focus distances as used (sorted near to far, tied frames placed); order (S,) input index of each;
    warnings (one line each); info: settings, mapping, placements, timings; score (H, W) the score the confidence
    calibration reads (`aat_deploy.confidence.agreement`, or the raw confidence without a calibration); fill_support
    (H, W) the fill's support and filled (H, W) bool the pixels whose depth and confidence come (partly) from the
    fill (both None without filling)."""

    depth_m: np.ndarray
    aif: np.ndarray
    std_m: np.ndarray
    confidence: np.ndarray
    diopters: np.ndarray
    focus_m: np.ndarray
    order: np.ndarray
    warnings: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)
    score: np.ndarray | None = None
    fill_support: np.ndarray | None = None
    filled: np.ndarray | None = None


def calibration_mismatch(best_focus: BestFocusMap, config: FocusConfig) -> str:
    """Where `config`'s measure settings differ from those the map's calibration was measured with ("" if none, or
    if the map does not say). The calibration is where that measure peaks: another measure peaks elsewhere."""
    cal = best_focus.notes.get("calibration") if isinstance(best_focus.notes, dict) else None
    if not isinstance(cal, dict) or "measure" not in cal:
        return ""
    made = {"measure": cal.get("measure"), "window_px": cal.get("window_px"),
            "prefilter_px": cal.get("prefilter_px", 0.0)}  # maps made before the pre-filter existed: none
    diffs = []
    for k, v in made.items():
        now = getattr(config, k)
        same = v == now if k == "measure" else isinstance(v, (int, float)) and abs(float(v) - float(now)) < 1e-9
        if not same:
            diffs.append(f"{k} {v} in the map, {now} here")
    return "; ".join(diffs)


def calibration_settings_mismatch(cal, config: FocusConfig) -> str:
    """Where `config`'s measure settings differ from those a camera calibration was fitted with ("" if none or
    unknown): the calibration is where that measure peaks."""
    fit = cal.fit if isinstance(cal.fit, dict) else {}
    diffs = []
    for k in ("measure", "window_px", "prefilter_px"):
        if k not in fit:
            continue
        v, now = fit[k], getattr(config, k)
        same = v == now if k == "measure" else isinstance(v, (int, float)) and abs(float(v) - float(now)) < 1e-9
        if not same:
            diffs.append(f"{k} {v} in the calibration, {now} here")
    return "; ".join(diffs)


def classical_depth(stack: np.ndarray, focus_m, best_focus: BestFocusMap | None = None,
                     config: FocusConfig = FocusConfig(), volume: np.ndarray | None = None,
                     calibration=None, frame_diopters: np.ndarray | None = None,
                     confidence_calibration: Calibration | None = None) -> FocusResult:
    """Depth, all-in-focus image and confidence from a focal stack.

    stack: (S, 3, H, W) linear RGB (any scale: the runtime's normalised stacks or raw linear values), S >= 3 (2 with
    the `ratio` estimator: a depth-from-defocus pair), any frame order; focus_m: (S,) reported focus distances, metres from the sensor (> 0). best_focus: the lens's
    map for the aberration-aware mapping (frames spanning its sensor), None = thin-lens mapping.
    volume: a precomputed focus volume (S, H, W) of `stack` with config's measure (benchmarks reuse it).
    calibration: a camera calibration (`aat_deploy.calibrate.CameraCalibration`, frames spanning its field): each
    frame's reported focus mapped to the diopters in focus at every pixel (`in_focus_diopters`), instead of the
    nominal focus and the radial map (not with best_focus).
    frame_diopters: (S, H, W) the diopters each frame (input order) has in focus at each pixel, from anywhere (a
    simulator's truth, another mapping): used as given (no tied-frame placement), instead of all the above.
    confidence_calibration: the confidence calibration (curves `estimate`, `fill`; `aat_deploy.confidence`) when
    config.confidence is "calibrated"; None = the shipped one (aat_deploy/focus/data/confidence.json).
    """
    t0 = time.perf_counter()
    timings: dict[str, float] = {}

    def lap(name):
        nonlocal t0
        now = time.perf_counter()
        timings[name] = round(now - t0, 4)
        t0 = now

    stack = np.asarray(stack, np.float32)
    f = np.asarray(focus_m, np.float64).ravel()
    if stack.ndim != 4 or stack.shape[1] != 3 or stack.shape[0] != f.size:
        raise ValueError(f"stack must be (S, 3, H, W) with S focus distances, got {stack.shape} and {f.size}")
    if f.size < 3 and not (f.size == 2 and config.estimator == "ratio"):
        raise ValueError(f"depth from focus needs at least 3 frames (2 with the ratio estimator), got {f.size}")
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError(f"focus distances must be finite and > 0 m, got {f.tolist()}")
    warnings: list[str] = []
    if f.size == 2:
        warnings.append("two frames (depth from defocus): depth is measured only between their focus distances; "
                        "a point beyond them is placed between them, near the sharper frame's")
    vol = (focus_volume(stack, config.measure, config.window_px, prefilter_px=config.prefilter_px)
           if volume is None else volume)
    lap("measure")

    placements: list[dict] = []
    if tied_groups(f) and frame_diopters is None:
        f, placements = place_equal_focus(vol, f)
        desc = ", ".join(f"frame {p['frame']} {p['reported_m']:g} -> {p['placed_m']:.4g} m" for p in placements)
        warnings.append(f"frames with equal reported focus distances placed from the images: {desc}")
        if any(p["method"] != "images" for p in placements):
            warnings.append("some tied frames could not be placed from the images and were spread evenly")
    order = np.argsort(f, kind="stable")
    if np.any(order != np.arange(f.size)):  # (copies of the stack cost time: only when the order changes)
        f, stack, vol = f[order], stack[order], vol[order]
        if frame_diopters is not None:
            frame_diopters = np.asarray(frame_diopters)[order]
    lap("placement")

    s, _, h, w = stack.shape
    if sum(v is not None for v in (calibration, best_focus, frame_diopters)) > 1:
        raise ValueError("give one of a best-focus map, a camera calibration or per-pixel frame diopters")
    if frame_diopters is not None:
        fd = np.asarray(frame_diopters, np.float32)
        if fd.shape != (s, h, w) or not np.isfinite(fd).all():
            raise ValueError(f"frame_diopters must be finite (S, H, W) = {(s, h, w)}, got {fd.shape}")
        # per frame and pixel: the flat take of `estimate.positions_at` with one "radius bin" per pixel
        x, rbin, mapping = fd.reshape(s, h * w), np.arange(h * w, dtype=np.int64).reshape(h, w), "per_pixel"
    elif calibration is not None:
        from ..calibrate.format import in_focus_diopters, measured_mask, on_axis_diopters

        x = in_focus_diopters(calibration, f, h, w).reshape(s, h * w)  # per pixel, as frame_diopters
        rbin = np.arange(h * w, dtype=np.int64).reshape(h, w)
        mapping = "calibration"
        for msg in (calibration.aspect_warning(h, w), ):
            if msg:
                warnings.append(msg)
        mismatch = calibration_settings_mismatch(calibration, config)
        if mismatch:
            warnings.append(f"the camera calibration was fitted with another focus measure ({mismatch}): where "
                            "the measure peaks may differ")
        lo, hi = calibration.best_focus.focus_range_d
        t = on_axis_diopters(calibration, f)
        margin = 0.1 * (hi - lo) + 0.05
        out = [v for v, d in zip(f, t) if not lo - margin <= d <= hi + margin]
        if out:
            near, far = calibration.focus_range_m
            warnings.append(f"focus distances {', '.join(f'{v:g}' for v in out)} m lie outside the calibrated "
                            f"{near:.3g}..{far:.3g} m: its field term is held, the focus error extrapolated")
        unmeasured = 1.0 - float(measured_mask(calibration, f, h, w, x.reshape(s, h, w)).mean())
        if unmeasured > 0.01:  # beyond the farthest tile, the focus range or the charts' objects: extrapolated
            warnings.append(f"{100 * unmeasured:.0f} % of the pixel-frames lie where the calibration measured "
                            "nothing (beyond its farthest chart tile's field radius, its focus range or the objects "
                            "its charts showed): its map is extrapolated there (aat_deploy.calibrate.measured_mask)")
    elif best_focus is None:
        x, rbin, mapping = (1.0 / f).astype(np.float32), None, "thin_lens"
    else:
        x = best_focus.radial_lut(f, config.radius_bins, config.calibrated)
        r = best_focus.radius_px(h, w)
        rbin = np.minimum((r * config.radius_bins).astype(np.int32), config.radius_bins - 1)
        mapping = "aberration_aware"
        if config.calibrated and best_focus.offset_diopters is not None:
            mismatch = calibration_mismatch(best_focus, config)
            if mismatch:
                warnings.append(f"the best-focus map was calibrated with another focus measure ({mismatch}): its "
                                "offsets may not fit these settings (remake it with aat-lens focus-map LENS --force)")
        near, far = best_focus.focus_range_m
        out = [v for v in f if not near * 0.999 <= v <= far * 1.001]
        if out:
            warnings.append(f"focus distances {', '.join(f'{v:g}' for v in out)} m lie outside the best-focus "
                            f"map's {near:g}..{far:g} m: its edge values are used")
    peak = estimate_peak(vol, x, rbin, config.estimator, gamma=config.tail_exponent)
    lap("estimate")

    weights = focus_weights(vol, config.aif_power)
    aif = blend(stack, weights) if config.aif == "weights" else blend_at(stack, peak.frac)
    lap("aif")

    cal = (confidence_calibration or focus_calibration()) if config.confidence == "calibrated" else None
    if config.confidence == "calibrated" and cal is None:
        warnings.append("no confidence calibration installed (aat_deploy/focus/data/confidence.json): the "
                        "confidence is the raw focus-curve contrast")
    elif cal is not None:
        made = {k: cal.notes.get("focus_config", {}).get(k) for k in ("prefilter_px", "window_px", "measure")}
        diff = [f"{k} {v} there, {getattr(config, k)} here" for k, v in made.items()
                if v is not None and v != getattr(config, k)]
        if diff:
            warnings.append(f"the confidence calibration was made with other settings ({'; '.join(diff)}): the "
                            "confidence may not mean what it says (rerun benchmarks/calibrate_confidence.py)")
    d, conf, support, filled = peak.diopters, peak.confidence, None, None
    score = peak.confidence
    if cal is not None:  # the score the calibration was fitted on (the contrast, or the estimates' agreement)
        if cal.notes.get("estimate_score") == "agreement":
            score = agreement(peak.diopters, f, config.window_px)
        conf = cal.probability("estimate", score, peak.diopters, f)
    if config.fill == "fill":
        guide = np.sqrt(np.clip(aif / max(float(np.percentile(aif, 99.5)), 1e-12), 0, 1))
        d, support = fill_with_support(d, peak.confidence, guide, config.sigma_s_px, config.sigma_r, config.c_full,
                                       config.fill_downscale)
        filled = peak.confidence < config.c_full  # these take part (or all) of their depth from the fill
        if cal is not None:
            conf = np.where(filled, cal.probability("fill", support, d, f), conf).astype(np.float32)
    depth = (1.0 / np.maximum(d, MIN_DIOPTERS)).astype(np.float32)
    lap("fill")
    frame_m = (1.0 / np.maximum(x, MIN_DIOPTERS)).astype(np.float32)  # per frame (and radius bin), metres
    std = spread_m(weights, frame_m if rbin is None else np.take(frame_m, rbin, axis=1), depth)
    lap("spread")
    info = {"config": asdict(config), "mapping": mapping, "frames": int(s), "size_px": [int(w), int(h)],
            "focus_m_used": [float(v) for v in f], "placements": placements, "timings_s": timings}
    if calibration is not None:
        c = calibration.camera
        info["calibration"] = {"camera": f"{c.make} {c.model}".strip(), "lens": c.lens,
                               "focus_error": calibration.focus_error.family,
                               "focus_range_m": [round(v, 4) for v in calibration.focus_range_m]}
    info["confidence"] = {"calibrated": cal is not None,
                          **({"tolerance_rel": cal.tolerance_rel} if cal is not None else {}),
                          "filled_share": None if filled is None else float(filled.mean())}
    if best_focus is not None:
        info["best_focus_map"] = {"lens_name": best_focus.lens_name, "lens_hash": best_focus.lens_hash,
                                  "calibrated": bool(config.calibrated and best_focus.offset_diopters is not None)}
    return FocusResult(depth, aif, std, conf, peak.diopters, f.astype(np.float32), order, warnings, info,
                       score, support, filled)
