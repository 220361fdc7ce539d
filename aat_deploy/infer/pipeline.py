"""One capture folder → depth, all-in-focus, uncertainty, summary and a rerun recording.

Stages (each timed in summary.json): metadata (focus distances, identity check), decode (RAW/images to linear
RGB, each frame fitted to the working size as it is decoded: aat_deploy.infer.process.fitted_frames), geometry (the
working size's checks), align (optional), normalise, infer (onnxruntime, padded,
tiled if asked), native (--native-res: depth and all-in-focus at the capture's resolution, aat_deploy.infer.upsample),
write (files, aat_deploy.infer.outputs: the one writer every depth method uses), record (.rrd). The output folder is checked before any work
(aat_deploy.io.guard) and written to a temporary sibling renamed into place at the end (aat_deploy.io.atomic), so a
failed run never leaves a half-written output folder.
"""

from __future__ import annotations

import importlib
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..capture.folder import Capture, read_capture
from ..confidence import MIN_CONFIDENCE, mark_unknown
from ..errors import CaptureError
from ..gt.read import check_units, find_gt, load_ground_truth, to_sensor
from ..io.atomic import atomic_folder, writing
from ..io.guard import check_output_dir
from ..progress import say
from .frames import FrameReader
from .method import DepthMethod
from .normalise import DESCRIPTION as NORMALISATION
from .outputs import DESCRIPTIONS, DepthMaps, RecordingInputs, summary_fields, write_outputs, write_summary
from .process import depth_from_frames

# every capture's files (confidence.* only from methods that give one)
OUTPUT_FILES = tuple(k for k in DESCRIPTIONS if not k.startswith("confidence")) + ("summary.json",)
FOCAL_TOLERANCE = 0.02  # relative difference of focal length that counts as another lens
FNUMBER_TOLERANCE = 0.05


@dataclass
class Options:
    """Runtime switches (see `aat-infer --help`)."""

    tile: int | None = None
    align: bool = False
    strict: bool = False
    force: bool = False
    use_exiftool: bool = True
    focus_m: list[float] | None = None  # --focus-m: focus distances (m) of the frames in file-name order
    record: bool = True
    quiet: bool = False
    native: bool = False  # depth and all-in-focus at the capture's resolution (aat_deploy.infer.upsample)
    max_megapixels: float | None = None  # the pixel limit of frame headers (None: $AAT_MAX_MEGAPIXELS or 200)
    allow_outside_links: bool = False  # follow symlinks leading out of the capture folder
    min_confidence: float = MIN_CONFIDENCE  # below it depth is unknown (NaN; aat_deploy.confidence)
    warnings: list[str] = field(default_factory=list)


def _import_in_background(module: str) -> None:
    """Start importing `module` in a thread (Python's import lock makes a later import wait for it to finish);
    a failure here is left to that later import to report."""
    def work():
        try:
            importlib.import_module(module)
        except Exception:  # noqa: BLE001 (reported where the module is really needed)
            pass

    threading.Thread(target=work, name=f"import {module}", daemon=True).start()


def identity_warnings(capture: Capture, model: DepthMethod) -> list[str]:
    """Differences between the capture's camera/lens (EXIF) and the lens the model was trained for."""
    out = []
    lenses = {f.meta.lens for f in capture.frames if f.meta.lens}
    focals = {round(f.meta.focal_length_mm, 3) for f in capture.frames if f.meta.focal_length_mm}
    fnums = {round(f.meta.f_number, 3) for f in capture.frames if f.meta.f_number}
    where = capture.path
    for what, values in (("lens", lenses), ("focal length", focals), ("F-number", fnums)):
        if len(values) > 1:
            out.append(f"{where}: frames disagree on the {what}: {sorted(values)}")
    if model.lens_name is None:  # the classical method without a lens: nothing to compare with
        return out
    for lens in sorted(lenses):
        if lens != model.lens_name:
            out.append(f"{where}: lens {lens!r} is not the model's lens {model.lens_name!r}")
    for fl in sorted(focals):
        if model.focal_length_mm and abs(fl - model.focal_length_mm) > FOCAL_TOLERANCE * model.focal_length_mm:
            out.append(f"{where}: focal length {fl:g} mm differs from the model's {model.focal_length_mm:g} mm")
    for fn in sorted(fnums):
        if model.f_number and abs(fn - model.f_number) > FNUMBER_TOLERANCE * model.f_number:
            out.append(f"{where}: F-number {fn:g} differs from the model's F/{model.f_number:g}")
    return out


def output_dir_for(capture_dir: Path, out: Path | None, single: bool) -> Path:
    """Where a capture's results go: --out itself for a single capture, else --out/<capture name>;
    without --out, ./aat_out/<capture name>."""
    if out is None:
        return Path("aat_out") / capture_dir.resolve().name
    return out if single else out / capture_dir.resolve().name


def output_dirs(captures: list[Path], out: Path | None) -> list[Path]:
    """output_dir_for each capture of a batch; captures with the same folder name (x/cap, y/cap) get distinct
    folders in batch order: cap, cap_2, cap_3, ..."""
    single = len(captures) == 1
    dirs: list[Path] = []
    taken: set[str] = set()
    for c in captures:
        d = output_dir_for(Path(c), out, single)
        base, k = d, 2
        while d.name in taken:
            d, k = base.with_name(f"{base.name}_{k}"), k + 1
        taken.add(d.name)
        dirs.append(d)
    return dirs


def check_output(out_dir: Path, force: bool, inputs: list[Path] = ()) -> None:
    """Fail before any work if the output folder may not be written (aat_deploy.io.guard): it is, contains or
    lies inside an input, is the current folder, exists without --force (or, with it, is not an earlier
    aat-infer output), or its location is not writable."""
    check_output_dir(out_dir, inputs, force, tool="aat-infer")


@dataclass
class CaptureRun:
    """What one capture's run made: summary (as written to summary.json); maps at the output size, as written
    (depth_m NaN where unknown, aif (3, H, W) linear, std_m, confidence); working: the method's maps at its working
    size; geometry: the frames' crop and scale (fit_to_sensor's); ground_truth (h, w) at the working size or None,
    and the warnings about it (also in summary["warnings"])."""

    summary: dict
    maps: DepthMaps
    working: DepthMaps
    geometry: dict
    ground_truth: np.ndarray | None
    ground_truth_warnings: list[str]


def run_capture(capture_dir: str | Path, model: DepthMethod, out_dir: str | Path, opts: Options) -> dict:
    """Process one capture folder; returns the summary written to out_dir/summary.json (`infer_capture`: the
    maps too)."""
    return infer_capture(capture_dir, model, out_dir, opts).summary


def infer_capture(capture_dir: str | Path, model: DepthMethod, out_dir: str | Path, opts: Options) -> CaptureRun:
    """Process one capture folder into out_dir; returns the summary and the maps (`CaptureRun`)."""
    t_all = time.perf_counter()
    capture_dir, out_dir = Path(capture_dir), Path(out_dir)
    check_output(out_dir, opts.force, [capture_dir])
    if opts.record:
        _import_in_background("aat_deploy.infer.recording")  # rerun takes ~1 s to import: meanwhile frames decode
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[stage] = round(now - clock, 4)
        clock = now

    cap = read_capture(capture_dir, use_exiftool=opts.use_exiftool, focus_m=opts.focus_m,
                       equal_focus_ok=model.places_tied_frames,
                       max_megapixels=opts.max_megapixels, allow_outside_links=opts.allow_outside_links)
    warnings = list(cap.warnings)
    ident = identity_warnings(cap, model)
    if ident and opts.strict:
        raise CaptureError(ident[0] + " (--strict)")
    warnings += ident
    frames = sorted(cap.frames, key=lambda f: f.focus_m)
    focus = np.array([f.focus_m for f in frames], np.float32)
    lo, hi = model.stack_range
    if not lo <= len(frames) <= hi:
        raise CaptureError(f"{capture_dir}: {len(frames)} frames, the {model.noun} takes {lo}..{hi}")
    near, far = model.focus_range_m
    outside = [f"{f.path.name} ({f.focus_m:g} m)" for f in frames if not near * 0.999 <= f.focus_m <= far * 1.001]
    if outside:
        warnings.append(f"{capture_dir}: focus distances outside the model's range {near:g}..{far:g} m: "
                        + ", ".join(outside))
    lap("metadata")

    reader = FrameReader([f.path for f in frames], opts.max_megapixels)  # decodes on demand, sizes checked
    model = model.for_capture(cap, reader.first_hw)  # e.g. the any-camera model told this capture's camera
    res = depth_from_frames(reader.decoders(), focus, model, align=opts.align,
                            tile=opts.tile, native=opts.native, name=cap.name, where=str(capture_dir),
                            labels=[f.path.name for f in frames], quiet=opts.quiet, lap=lap)
    size0 = reader.first_hw()
    warnings += res.warnings
    maps, camera, stack = res.maps, res.camera, res.stack
    depth_known, unknown = mark_unknown(maps.depth_m, maps.confidence, opts.min_confidence)
    maps = DepthMaps(depth_known, maps.aif, maps.std_m, maps.confidence)
    w_px, h_px = res.working_size

    with writing(out_dir), atomic_folder(out_dir, opts.force, "aat-infer") as tmp:  # OSError: one line, no tmp
        gt, gt_warnings = ground_truth_at(capture_dir, size0, res.geometry["crop_xywh"], (w_px, h_px),
                                          model.focus_range_m, opts)
        warnings += gt_warnings
        rec = RecordingInputs(stack, focus, gt, cap.name) if opts.record else None
        say(opts.quiet, f"{cap.name}: writing outputs" + (" and the recording" if rec else ""))
        written = write_outputs(tmp, maps, camera, rec)
        timings.update(written["timings_s"])
        summary = {
            "capture": str(capture_dir),
            "frames": [{"file": f.path.name, "focus_m": float(f.focus_m), "focus_source": f.focus_source,
                        "make": f.meta.make, "model": f.meta.model, "lens": f.meta.lens,
                        "focal_length_mm": f.meta.focal_length_mm, "f_number": f.meta.f_number,
                        **({"decode": reader.info[i]} if reader.info.get(i) else {})} for i, f in enumerate(frames)],
            **summary_fields(written, camera, [f.focus_m for f in frames], model.summary(), unknown, warnings),
            "input_size_px": [int(size0[1]), int(size0[0])],
            "working_size_px": [int(w_px), int(h_px)],
            "native_resolution": (camera.width, camera.height) != (w_px, h_px),
            "geometry": res.geometry,
            "align": res.align_info,
            "normalisation": NORMALISATION,
            "tile": opts.tile,
            "depth_m_range": ([float(np.nanmin(maps.depth_m)), float(np.nanmax(maps.depth_m))]
                              if np.isfinite(maps.depth_m).any() else None),
            "ground_truth": _gt_stats(gt, res.working.depth_m),  # at the model's size, as the GT is
            **({"method_info": res.info} if res.info else {}),
            "timings_s": timings,
        }
        summary["timings_s"]["total"] = round(time.perf_counter() - t_all, 4)
        write_summary(tmp, summary)
    return CaptureRun(summary, maps, res.working, res.geometry, gt, gt_warnings)


def ground_truth_at(capture_dir: Path, frame_hw: tuple[int, int], crop_xywh, size_wh: tuple[int, int],
                    focus_range_m: tuple[float, float], opts: Options) -> tuple[np.ndarray | None, list[str]]:
    """The capture's ground truth in any form `aat_deploy.gt.read` reads (gt.json, gt_depth_m.npy/.pfm/.tif,
    gt_depth_mm.png, a mask), brought to the working size as the frames were (`to_sensor`: crop_xywh of the
    frames' (H, W) = frame_hw, nearest samples), NaN = unknown; and warnings. Ground truth that cannot be used here
    (unreadable, another aspect ratio, wrong units for the method's focus range) is ignored with a warning:
    aat-infer does not score, aat-eval refuses it."""
    try:
        src = find_gt(capture_dir, opts.allow_outside_links)
        if src is None:
            return None, []
        truth = load_ground_truth(src, opts.max_megapixels)
        check_units(truth, focus_range_m)
        gt = to_sensor(truth.depth_m, (frame_hw[1], frame_hw[0]), tuple(crop_xywh), size_wh, src.depth)
    except CaptureError as e:
        return None, [f"{e}; ground truth ignored"]
    return gt.astype(np.float32), list(truth.warnings)


def _gt_stats(gt: np.ndarray | None, depth_m: np.ndarray) -> dict | None:
    if gt is None:
        return None
    ok = np.isfinite(gt) & (gt > 0)
    if not ok.any():
        return None
    err = depth_m[ok] - gt[ok]
    return {"pixels": int(ok.sum()), "mae_m": float(np.mean(np.abs(err))),
            "abs_rel": float(np.mean(np.abs(err) / gt[ok])), "rmse_m": float(math.sqrt(np.mean(err ** 2)))}
