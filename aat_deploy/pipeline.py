"""One capture folder → depth, all-in-focus, uncertainty, summary and a rerun recording.

Stages (each timed in summary.json): metadata (focus distances, identity check), decode (RAW/images to linear
RGB), geometry (fit to the model's sensor px), align (optional), normalise, infer (onnxruntime, padded,
tiled if asked), native (--native-res: depth and all-in-focus at the capture's resolution, aat_deploy.upsample),
write (files, aat_deploy.outputs: the one writer every depth method uses), record (.rrd). The output folder is checked before any work
(aat_deploy.io.guard) and written to a temporary sibling renamed into place at the end (aat_deploy.io.atomic), so a
failed run never leaves a half-written output folder.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from .capture.folder import Capture, read_capture
from .capture.raw import load_frame
from .errors import CaptureError
from .eval.gt import READ_ERRORS, units_problem
from .geometry import align_stack, fit_to_sensor
from .io.atomic import atomic_folder
from .io.guard import check_output_dir
from .model import DfFModel
from .normalise import DESCRIPTION as NORMALISATION
from .normalise import normalise_scale, normalise_stack
from .outputs import DepthMaps, RecordingInputs, write_outputs
from .camera import camera_json
from .upsample import native_maps
from .io.images import imread
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
    record: bool = True
    quiet: bool = False
    native: bool = False  # depth and all-in-focus at the capture's resolution (aat_deploy.upsample)
    warnings: list[str] = field(default_factory=list)


def _progress(items, desc: str, quiet: bool):
    """A tqdm bar over items on stderr (nothing when quiet)."""
    items = list(items)
    if quiet:
        yield from items
        return
    yield from tqdm(items, desc=f"  {desc}", leave=False, file=sys.stderr)


class _TileBar:
    """progress(done, total) for DfFModel.infer's tiles as a tqdm bar (created at the first tile)."""

    def __init__(self, desc: str):
        self.desc, self.bar = desc, None

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            self.bar = tqdm(total=total, desc=f"  {self.desc}", unit="tile", leave=False, file=sys.stderr)
        self.bar.update(done - self.bar.n)
        if done >= total:
            self.bar.close()


def _say(quiet: bool, msg: str) -> None:
    """A progress line on stderr for a stage without steps to count (one onnxruntime call, writing files)."""
    if not quiet:
        print(f"  {msg}", file=sys.stderr, flush=True)


def identity_warnings(capture: Capture, model: DfFModel) -> list[str]:
    """Differences between the capture's camera/lens (EXIF) and the lens the model was trained for."""
    out = []
    lenses = {f.meta.lens for f in capture.frames if f.meta.lens}
    focals = {round(f.meta.focal_length_mm, 3) for f in capture.frames if f.meta.focal_length_mm}
    fnums = {round(f.meta.f_number, 3) for f in capture.frames if f.meta.f_number}
    where = capture.path
    for what, values in (("lens", lenses), ("focal length", focals), ("F-number", fnums)):
        if len(values) > 1:
            out.append(f"{where}: frames disagree on the {what}: {sorted(values)}")
    for lens in sorted(lenses):
        if lens != model.lens_name:
            out.append(f"{where}: lens {lens!r} is not the model's lens {model.lens_name!r}")
    for fl in sorted(focals):
        if abs(fl - model.focal_length_mm) > FOCAL_TOLERANCE * model.focal_length_mm:
            out.append(f"{where}: focal length {fl:g} mm differs from the model's {model.focal_length_mm:g} mm")
    for fn in sorted(fnums):
        if abs(fn - model.f_number) > FNUMBER_TOLERANCE * model.f_number:
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
    check_output_dir(out_dir, inputs, force, marker="summary.json", tool="aat-infer")


def run_capture(capture_dir: str | Path, model: DfFModel, out_dir: str | Path, opts: Options) -> dict:
    """Process one capture folder; returns the summary written to out_dir/summary.json."""
    t_all = time.perf_counter()
    capture_dir, out_dir = Path(capture_dir), Path(out_dir)
    check_output(out_dir, opts.force, [capture_dir])
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[stage] = round(now - clock, 4)
        clock = now

    cap = read_capture(capture_dir, use_exiftool=opts.use_exiftool)
    warnings = list(cap.warnings)
    ident = identity_warnings(cap, model)
    if ident and opts.strict:
        raise CaptureError(ident[0] + " (--strict)")
    warnings += ident
    frames = sorted(cap.frames, key=lambda f: f.focus_m)
    focus = np.array([f.focus_m for f in frames], np.float32)
    lo, hi = model.stack_range
    if not lo <= len(frames) <= hi:
        raise CaptureError(f"{capture_dir}: {len(frames)} frames, the model takes {lo}..{hi}")
    near, far = model.focus_range_m
    outside = [f"{f.path.name} ({f.focus_m:g} m)" for f in frames if not near * 0.999 <= f.focus_m <= far * 1.001]
    if outside:
        warnings.append(f"{capture_dir}: focus distances outside the model's range {near:g}..{far:g} m: "
                        + ", ".join(outside))
    lap("metadata")

    images, decode_info, size0 = [], [], None
    for f in _progress(frames, f"{cap.name}: decode", opts.quiet):
        img, info = load_frame(f.path)
        if size0 is None:
            size0 = img.shape[:2]
        elif img.shape[:2] != size0:
            raise CaptureError(f"{f.path}: frame is {img.shape[1]}x{img.shape[0]} px, "
                               f"{frames[0].path.name} is {size0[1]}x{size0[0]}: frames of different sizes")
        images.append(img)
        decode_info.append(info)
    lap("decode")

    w_px, h_px = model.sensor_px
    fitted = [fit_to_sensor(im, (w_px, h_px)) for im in images]
    geometry = fitted[0][1]
    # --native-res: keep the decoded frames for the native maps (nothing to do when they are the working size)
    native = images if opts.native and tuple(geometry["crop_xywh"][2:]) != (w_px, h_px) else None
    images = [im for im, _ in fitted]
    if abs(size0[1] / size0[0] - w_px / h_px) > 0.01 * (w_px / h_px):
        warnings.append(f"{capture_dir}: frames are {size0[1]}x{size0[0]} px, the model's sensor is {w_px}x{h_px}: "
                        "centre-cropped to its aspect ratio")
    lap("geometry")

    align_info = None
    if opts.align:
        images, align_info = align_stack(images, ref=len(images) // 2)
        bad = [frames[i].path.name for i, a in enumerate(align_info) if not a["converged"]]
        if bad:
            warnings.append(f"{capture_dir}: alignment did not converge for {', '.join(bad)} (left unaligned)")
    lap("align")

    raw_stack = np.stack([im.transpose(2, 0, 1) for im in images])
    normalise_scale_of = float(normalise_scale(raw_stack))
    stack = normalise_stack(raw_stack)
    del images, raw_stack
    lap("normalise")

    s_, _, h_, w_ = stack.shape
    tiled = bool(opts.tile) and max(h_, w_) > opts.tile
    _say(opts.quiet or tiled, f"{cap.name}: inference, {s_} frames of {w_}x{h_} px")
    tiles_bar = _TileBar(f"{cap.name}: inference in tiles of {opts.tile} px") if tiled and not opts.quiet else None
    res = model.infer(stack, focus, tile=opts.tile, progress=tiles_bar)
    lap("infer")

    maps = DepthMaps(res.depth_m, res.aif, res.std_m, getattr(res, "confidence", None))
    camera = model.intrinsics((w_px, h_px))
    if native is not None:
        _say(opts.quiet, f"{cap.name}: depth and all-in-focus at the capture's "
             f"{geometry['crop_xywh'][2]}x{geometry['crop_xywh'][3]} px")
        natives = native_frames(native, geometry, align_info, normalise_scale_of, (w_px, h_px))
        depth_n, aif_n, std_n = native_maps(res.depth_m, res.std_m, natives, focus)
        del natives
        maps = DepthMaps(depth_n, aif_n, std_n, None)
        camera = camera.resized(depth_n.shape[1], depth_n.shape[0])
    lap("native")

    with atomic_folder(out_dir, opts.force) as tmp:
        gt = _ground_truth(cap, size0, (w_px, h_px), warnings, model.focus_range_m)
        rec = RecordingInputs(stack, focus, gt, cap.name) if opts.record else None
        _say(opts.quiet, f"{cap.name}: writing outputs" + (" and the recording" if rec else ""))
        written = write_outputs(tmp, maps, camera, rec)
        timings.update(written["timings_s"])
        summary = {
            "capture": str(capture_dir),
            "frames": [{"file": f.path.name, "focus_m": float(f.focus_m), "focus_source": f.focus_source,
                        "make": f.meta.make, "model": f.meta.model, "lens": f.meta.lens,
                        "focal_length_mm": f.meta.focal_length_mm, "f_number": f.meta.f_number,
                        **({"decode": d} if d else {})} for f, d in zip(frames, decode_info)],
            "focus_m": [float(f.focus_m) for f in frames],
            "model": model.summary(),
            "input_size_px": [int(size0[1]), int(size0[0])],
            "working_size_px": [int(w_px), int(h_px)],
            "output_size_px": [int(camera.width), int(camera.height)],
            "native_resolution": native is not None,
            "geometry": geometry,
            "align": align_info,
            "normalisation": NORMALISATION,
            "tile": opts.tile,
            "depth_m_range": [float(np.nanmin(maps.depth_m)), float(np.nanmax(maps.depth_m))],
            "ground_truth": _gt_stats(gt, res.depth_m),
            "camera": camera_json(camera),
            "color_scales": written["color_scales"],
            "points": written["points"],
            "outputs": {**written["outputs"], "summary.json": "this file"},
            "timings_s": timings,
            "warnings": warnings,
        }
        summary["timings_s"]["total"] = round(time.perf_counter() - t_all, 4)
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False, default=_json_default))
    return summary


def native_frames(images: list[np.ndarray], geometry: dict, align_info: list[dict] | None, scale: float,
                  size_wh: tuple[int, int]) -> list[np.ndarray]:
    """The decoded frames (H0, W0, 3) cropped as fit_to_sensor cropped them, aligned with the working size's
    warps (scaled to the crop's pixels) if any, and normalised with the stack's divisor."""
    x0, y0, cw, ch = geometry["crop_xywh"]
    out = []
    for i, im in enumerate(images):
        crop = np.ascontiguousarray(im[y0:y0 + ch, x0:x0 + cw])
        if align_info is not None:
            m = native_warp(np.asarray(align_info[i]["matrix"], np.float64), (cw, ch), size_wh)
            crop = cv2.warpAffine(crop, m, (cw, ch), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_REFLECT)
        out.append(np.clip(crop / np.float32(scale), 0.0, 1.0).astype(np.float32))
    return out


def native_warp(m: np.ndarray, native_wh: tuple[int, int], work_wh: tuple[int, int]) -> np.ndarray:
    """A 2x3 affine warp in working-size pixels as the same warp in native pixels (pixel centres matched as
    cv2.resize matches them: x_work = sx (x_native + 0.5) - 0.5)."""
    sx, sy = work_wh[0] / native_wh[0], work_wh[1] / native_wh[1]
    a = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1]])
    full = np.vstack([m, [0, 0, 1]])
    return (np.linalg.inv(a) @ full @ a)[:2].astype(np.float32)


def _json_default(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")


def _ground_truth(cap: Capture, size0: tuple[int, int], size_wh: tuple[int, int], warnings: list[str],
                  focus_range_m: tuple[float, float]):
    """gt_depth_m.npy (or gt_depth_mm.png) brought to the output geometry (nearest), NaN = unknown; or None.
    Ground truth in the wrong units for the model's focus range (as aat-eval checks) is ignored with a warning."""
    gt = None
    try:
        if cap.gt_depth_m is not None:
            gt = np.load(cap.gt_depth_m, allow_pickle=False).astype(np.float32)
        elif cap.gt_depth_mm is not None:
            mm = imread(cap.gt_depth_mm, cv2.IMREAD_UNCHANGED)
            gt = None if mm is None else mm.astype(np.float32) / 1000.0
    except (*READ_ERRORS, TypeError) as e:
        warnings.append(f"{cap.path}: ground truth unreadable ({str(e).splitlines()[0][:120] if str(e) else type(e).__name__}); ignored")
        return None
    if gt is None:
        return None
    if gt.ndim != 2 or gt.shape != tuple(size0):
        warnings.append(f"{cap.path}: ground truth is {gt.shape}, frames are {tuple(size0)}; ignored")
        return None
    with np.errstate(invalid="ignore"):
        gt = np.where(np.isfinite(gt) & (gt > 0), gt, np.nan).astype(np.float32)
    if not np.isfinite(gt).any():
        return None
    src = cap.gt_depth_m if cap.gt_depth_m is not None else cap.gt_depth_mm
    why = units_problem(float(np.nanmedian(gt)), focus_range_m, src, 1.0 if cap.gt_depth_m is not None else 0.001)
    if why is not None:
        warnings.append(f"{why}; ground truth ignored")
        return None
    if (gt.shape[1], gt.shape[0]) != tuple(size_wh):
        tw, th = size_wh
        h, w = gt.shape
        target = tw / th
        cw, ch = (round(h * target), h) if w / h > target else (w, round(w / target))
        x0, y0 = (w - cw) // 2, (h - ch) // 2
        gt = cv2.resize(np.ascontiguousarray(gt[y0:y0 + ch, x0:x0 + cw]), (tw, th), interpolation=cv2.INTER_NEAREST)
    return gt


def _gt_stats(gt: np.ndarray | None, depth_m: np.ndarray) -> dict | None:
    if gt is None:
        return None
    ok = np.isfinite(gt) & (gt > 0)
    if not ok.any():
        return None
    err = depth_m[ok] - gt[ok]
    return {"pixels": int(ok.sum()), "mae_m": float(np.mean(np.abs(err))),
            "abs_rel": float(np.mean(np.abs(err) / gt[ok])), "rmse_m": float(math.sqrt(np.mean(err ** 2)))}
