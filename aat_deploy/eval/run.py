"""`aat-eval`'s batch: find the capture folders with ground truth under a root, run every model on each through
the runtime pipeline (`aat_deploy.infer.pipeline.infer_capture`, the same code as `aat-infer`; its maps are scored
in memory), score the predictions with the shared metrics and write the tables, maps, plots and a rerun recording into one output folder.

Output folder (written to a temporary sibling and renamed at the end; an existing one is replaced only with
force):
  metrics.csv, metrics.json, metrics.md      per (capture, model) and overall per model
  error_vs_radius.png, error_vs_depth.png    MAE and bias per bin of field radius / ground-truth depth
  eval.rrd                                   GT, prediction and |error| side by side, a row per model
  maps/<capture>.png                         panel: GT, prediction, |error| per model (shared scales)
  maps/<model>/<capture>_abs_error.png       |error| at the sensor's resolution (TURBO, 0..error_map_max_m)
  maps/<model>/mean_abs_error.png, .npy      mean |error| per pixel over the captures
  runs/<model>/<capture>/                    aat-infer's outputs, plus gt_sensor_m.npy and error_m.npy (pred − GT)
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..capture.raw import load_frame
from ..errors import CaptureError, one_line
from ..gt.read import (
    GroundTruth,
    GTError,
    check_units,
    find_gt,
    load_ground_truth,
    to_sensor,
)
from ..infer.geometry import fit_to_sensor
from ..infer.model import DfFModel
from ..infer.outputs import to_srgb8
from ..infer.pipeline import Options, infer_capture
from ..io.atomic import atomic_folder, writing
from ..io.colorize import colorize
from ..io.guard import check_no_overlap, check_output_dir
from ..metrics import MetricAccumulator, valid_mask
from . import plots, report
from .batch import Progress, capture_name, find_captures, model_labels
from .score import (
    ErrorProfile,
    aif_pair,
    depth_profile,
    fit_alignment,
    radius_profile,
)
from .stats import field_radius

ERROR_PERCENTILE = 99.0  # error maps of a capture share the scale 0..this percentile of |error| over the models


@dataclass
class EvalOptions:
    """Switches of `aat-eval` (see its --help)."""

    align: str | None = None
    align_frames: bool = False
    focus_range_mask: bool = False
    force: bool = False
    use_exiftool: bool = True
    record: bool = True
    panels: bool = True
    quiet: bool = False
    max_megapixels: float | None = None  # the pixel limit of frame and ground-truth headers
    allow_outside_links: bool = False
    messages: list[str] = field(default_factory=list)


@dataclass
class _Scored:
    row: dict
    pred: np.ndarray
    gt: np.ndarray
    err: np.ndarray


def _score_one(cap: Path, gt: GroundTruth, model: DfFModel, label: str, run_dir: Path, opts: EvalOptions,
               acc: MetricAccumulator, profiles: dict[str, ErrorProfile], radius: np.ndarray) -> _Scored:
    """Run one model on one capture and score it. CaptureError (incl. GTError) on failure."""
    check_units(gt, model.focus_range_m)
    # every pixel is scored (min_confidence 0: no depth marked unknown), as before the confidence was calibrated
    run = infer_capture(cap, model, run_dir, Options(align=opts.align_frames, quiet=True, record=False,
                                                     use_exiftool=opts.use_exiftool,
                                                     max_megapixels=opts.max_megapixels,
                                                     allow_outside_links=opts.allow_outside_links,
                                                     min_confidence=0.0))
    summary = run.summary
    pred = np.asarray(run.maps.depth_m, np.float32).astype(np.float64)  # the values depth_m.npy holds
    frame_wh = tuple(summary["input_size_px"])
    crop = tuple(summary["geometry"]["crop_xywh"])
    gt_s = to_sensor(gt.depth_m, frame_wh, crop, model.sensor_px, gt.source.depth).astype(np.float64)
    focus = np.asarray(summary["focus_m"])
    rng = (float(focus.min()), float(focus.max())) if opts.focus_range_mask else None
    mask = valid_mask(gt_s, rng)
    if not mask.any():
        raise GTError(f"{gt.source.depth}: no valid ground-truth pixel inside the sensor crop"
                      + (" and the focus range" if rng else ""))
    scale, shift = fit_alignment(pred, np.where(mask, gt_s, np.nan), opts.align) if opts.align else (1.0, 0.0)
    pred_a = scale * pred + shift
    aif_p = aif_r = None
    gain = None
    warnings = [w for w in summary["warnings"] if w not in run.ground_truth_warnings]  # scored here, not there
    if gt.source.aif is not None:
        ref, _ = load_frame(gt.source.aif, opts.max_megapixels)
        rh, rw = ref.shape[:2]
        if abs((rw / rh) / (frame_wh[0] / frame_wh[1]) - 1) > 0.01:
            warnings.append(f"{gt.source.aif}: {rw}x{rh} px, the frames are {frame_wh[0]}x{frame_wh[1]}: "
                            "a different aspect ratio; AiF not scored")
        else:
            ref_fit, _ = fit_to_sensor(ref, model.sensor_px)
            aif8 = to_srgb8(run.maps.aif)  # the pixels aif.png holds
            aif_p, aif_r, gain = aif_pair(aif8, ref_fit)
    row = acc.add(pred_a, gt_s, aif_p, aif_r, focus_m=focus)
    err = np.where(mask, pred_a - np.where(mask, gt_s, 0), np.nan)
    profiles["field_radius"].add(radius, err)
    profiles["depth"].add(gt_s, err)
    np.save(run_dir / "gt_sensor_m.npy", gt_s.astype(np.float32))
    np.save(run_dir / "error_m.npy", err.astype(np.float32))
    row = {"capture": None, "model": label, "status": "ok", **row,
           "align_scale": scale if opts.align else None, "align_shift": shift if opts.align else None,
           "aif_gain": gain, "gt_valid_fraction": float(mask.mean()), "focus_m": summary["focus_m"],
           "warnings": gt.warnings + warnings, "seconds": summary["timings_s"].get("total")}
    return _Scored(row, pred_a, np.where(mask, gt_s, np.nan), err)


def evaluate(root: str | Path, model_paths: list[str | Path], out_dir: str | Path, opts: EvalOptions,
             threads: int | None = None) -> dict:
    """Evaluate the models on every capture with ground truth under root; returns the report (metrics.json).

    Raises CaptureError/OutputError for problems of the whole batch (no captures, bad model, existing output);
    a failing capture is reported (opts.messages, report['per_capture'] with status 'failed') and skipped."""
    root, out_dir = Path(root), Path(out_dir)
    # the output may sit under ROOT (it is skipped when searching), never be or hold ROOT, a model or a capture
    check_output_dir(out_dir, [root, *model_paths], opts.force, tool="aat-eval",
                     nest_ok=[root])
    caps, without = find_captures(root, exclude=[out_dir])
    check_no_overlap(out_dir, caps + without)
    models = [DfFModel(p, threads=threads) for p in model_paths]
    labels = model_labels([Path(p) for p in model_paths])
    if not caps:
        raise CaptureError(f"{root}: no capture folder with ground truth (gt.json, gt_depth_m.npy/.pfm/.tif, "
                           "gt_depth_mm.png) under it")
    t0 = time.perf_counter()
    with writing(out_dir), atomic_folder(out_dir, opts.force, "aat-eval") as tmp:
        (tmp / "maps").mkdir()
        result = _evaluate_into(tmp, root, caps, without, models, labels, opts)
        result["seconds"] = round(time.perf_counter() - t0, 2)
        report.write_json(tmp / "metrics.json", result)
    return result


def _evaluate_into(tmp: Path, root: Path, caps: list[Path], without: list[Path], models: list[DfFModel],
                   labels: list[str], opts: EvalOptions) -> dict:
    accs = {lb: MetricAccumulator(focus_range_mask=opts.focus_range_mask, data_range=255.0) for lb in labels}
    near = min(m.focus_range_m[0] for m in models)
    far = max(m.focus_range_m[1] for m in models)
    profiles = {lb: {"field_radius": radius_profile(), "depth": depth_profile(near, far)} for lb in labels}
    radii = {lb: field_radius(m.sensor_px[1], m.sensor_px[0]) for lb, m in zip(labels, models)}
    for lb in labels:
        (tmp / "maps" / lb).mkdir()
    rec = None
    if opts.record:
        from .rrd import EvalRecording

        rec = EvalRecording(tmp / "eval.rrd", labels)
    rows: list[dict] = []
    cap_info: list[dict] = []
    bar = Progress(len(caps) * len(models), opts.quiet)

    def fail(name: str, label: str, msg: str) -> None:
        bar.fail(rows, opts.messages, name, label, msg)

    try:
        for ci, cap in enumerate(caps):
            name = capture_name(root, cap)
            info = {"name": name, "path": str(cap)}
            cap_info.append(info)
            try:
                src = find_gt(cap, opts.allow_outside_links)
                info["gt"] = src.describe()
                gt = load_ground_truth(src, opts.max_megapixels)
                info["gt_valid_fraction"] = gt.valid_fraction
            except Exception as e:  # noqa: BLE001 (a capture's ground truth never stops the batch)
                msg = str(e) if isinstance(e, CaptureError) else (
                    "out of memory reading its ground truth" if isinstance(e, MemoryError)
                    else f"unexpected {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}")
                for lb in labels:
                    fail(name, lb, msg)
                    bar.step(f"{name} ({lb})")
                continue
            scored: dict[str, _Scored] = {}
            for model, lb in zip(models, labels):
                run_dir = tmp / "runs" / lb / name
                run_dir.parent.mkdir(parents=True, exist_ok=True)
                try:
                    s = _score_one(cap, gt, model, lb, run_dir, opts, accs[lb], profiles[lb], radii[lb])
                except CaptureError as e:
                    fail(name, lb, str(e))
                except MemoryError:
                    fail(name, lb, "out of memory")
                except Exception as e:  # noqa: BLE001 (one capture's surprise must not stop the batch)
                    fail(name, lb, f"unexpected {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}")
                else:
                    s.row["capture"] = name
                    rows.append(s.row)
                    scored[lb] = s
                    for w in s.row["warnings"]:
                        bar.note(one_line(f"aat-eval: warning: {w}"))
                bar.step(f"{name} ({lb})")
            if scored:
                _capture_pictures(tmp, ci, name, scored, opts, rec)
    finally:
        bar.close()
        if rec is not None:
            rec.close()
    return _finish(tmp, root, caps, without, models, labels, rows, cap_info, accs, profiles, opts)


def _capture_pictures(tmp: Path, index: int, name: str, scored: dict, opts: EvalOptions, rec) -> None:
    """Error-map PNGs, the panel and the recording of one capture (one shared error scale over the models)."""
    all_err = np.concatenate([np.abs(s.err[np.isfinite(s.err)]) for s in scored.values()])
    err_max = float(np.percentile(all_err, ERROR_PERCENTILE)) if all_err.size else 1.0
    err_max = max(err_max, 1e-3)
    gts = np.concatenate([s.gt[np.isfinite(s.gt)] for s in scored.values()])
    depth_range = (float(np.percentile(gts, 1)), float(np.percentile(gts, 99)))
    if depth_range[1] <= depth_range[0]:
        depth_range = (depth_range[0] * 0.9, depth_range[0] * 1.1)
    for lb, s in scored.items():
        s.row["error_map_max_m"] = err_max
        plots.write_rgb_png(tmp / "maps" / lb / f"{name}_abs_error.png", colorize(np.abs(s.err), 0, err_max))
    first = next(iter(scored.values()))
    same_size = all(s.gt.shape == first.gt.shape for s in scored.values())
    if opts.panels and same_size:
        plots.capture_panel(tmp / "maps" / f"{name}.png", name, first.gt, {lb: s.pred for lb, s in scored.items()},
                            {lb: s.err for lb, s in scored.items()}, depth_range, err_max)
    if rec is not None:
        rec.log_capture(index, name, {lb: s.gt for lb, s in scored.items()}, {lb: s.pred for lb, s in scored.items()},
                        {lb: s.err for lb, s in scored.items()}, {lb: s.row for lb, s in scored.items()},
                        depth_range, err_max)


def _finish(tmp: Path, root: Path, caps, without, models, labels, rows, cap_info, accs, profiles,
            opts: EvalOptions) -> dict:
    overall, common = report.overall_means(rows, labels)
    for lb in labels:
        if accs[lb].rows:
            emap = accs[lb].error_map()
            np.save(tmp / "maps" / lb / "mean_abs_error.npy", emap.astype(np.float32))
            fin = emap[np.isfinite(emap)]
            vmax = max(float(np.percentile(fin, ERROR_PERCENTILE)), 1e-3) if fin.size else 1.0
            plots.write_rgb_png(tmp / "maps" / lb / "mean_abs_error.png", colorize(emap, 0, vmax))
            overall[lb]["mean_map_max_m"] = vmax
    prof = {lb: {k: p.as_dict() for k, p in profiles[lb].items()} for lb in labels}
    if any(accs[lb].rows for lb in labels):
        plots.profile_plot(tmp / "error_vs_radius.png", {lb: prof[lb]["field_radius"] for lb in labels},
                           "field radius (0 = centre, 1 = corner)", "depth error vs field radius")
        plots.profile_plot(tmp / "error_vs_depth.png", {lb: prof[lb]["depth"] for lb in labels},
                           "ground-truth depth (m from the sensor)", "depth error vs depth", log_x=True)
    result = {
        "root": str(root),
        "options": {"align": opts.align, "align_frames": opts.align_frames,
                    "focus_range_mask": opts.focus_range_mask},
        "units": "depth metrics in metres from the sensor plane (AbsRel, RMSE-log, delta unitless); "
                 "AiF PSNR (dB) / SSIM on 8-bit sRGB after an exposure gain fit (aif_gain)",
        "models": [{"label": lb, **m.summary()} for lb, m in zip(labels, models)],
        "captures": cap_info,
        "skipped_without_gt": [str(p) for p in without],
        "per_capture": rows,
        "overall": overall,
        "overall_captures": sorted(common),
        "profiles": prof,
        "failed": [f"{r['capture']} ({r['model']}): {r['error']}" for r in rows if r["status"] != "ok"],
    }
    report.write_csv(tmp / "metrics.csv", rows, overall)
    (tmp / "metrics.md").write_text(report.markdown(result))
    return result

