"""The one place where a capture's results become files: every depth method (the DfF model, the classical focus
method) hands its arrays to `write_outputs`.

Files (all maps the same size H x W, the camera's; docs/contracts.md, "Runtime outputs"):
- `depth_m.npy` float32 metres from the sensor plane (NaN = unknown), `depth_m.tif` the same as a 32-bit float
  TIFF (tifffile, GDAL, ImageJ, OpenCV, Pillow read it), `depth_mm.png` uint16 millimetres (0 = unknown),
  `depth_color.png` a colour preview on an inverse-depth scale with the range on a colour bar;
- `aif.png` the all-in-focus image, 8-bit sRGB;
- `std_m.npy`, `std_mm.png`, `std_color.png` the uncertainty (metres; mm; colour preview), when given;
  `confidence.npy` / `confidence.png` a per-pixel confidence in [0, 1], when the method gives one;
- `points.ply` the depth as a coloured point cloud (binary PLY, metres, camera frame: aat_deploy.optics.camera);
- `camera.json` the intrinsics of these maps in pixels and where depth is measured from;
- `recording.rrd` a rerun recording with a default layout (aat_deploy.infer.recording), when asked.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..errors import OutputError
from ..io.color import linear_to_srgb
from ..io.colorize import depth_preview, depth_range, uncertainty_preview, uncertainty_range
from ..io.depth_png import encode_mm16
from ..io.images import imwrite
from ..io.ply import write_ply
from ..optics.camera import CAMERA_FRAME, POINT_FROM_PIXEL, Intrinsics, camera_json, points_from_depth

MAX_PLY_POINTS = 4_000_000   # every pixel up to this; more are subsampled on a regular grid (stride)
MAX_RRD_POINTS = 200_000
RECORDING_MAX_SIDE = 1280    # the recording is a preview: maps larger than this are resized for it

DESCRIPTIONS = {
    "depth_m.npy": "float32 depth in m from the sensor plane (NaN = unknown)",
    "depth_m.tif": "the same as a 32-bit float TIFF",
    "depth_mm.png": "uint16 depth in mm (0 = unknown)",
    "depth_color.png": "depth preview, inverse-depth colour scale with a labelled bar (range in summary.json)",
    "aif.png": "all-in-focus, 8-bit sRGB",
    "std_m.npy": "float32 uncertainty (standard deviation) in m",
    "std_mm.png": "uint16 uncertainty in mm",
    "std_color.png": "uncertainty preview, linear colour scale with a labelled bar",
    "confidence.npy": "float32 confidence in [0, 1]",
    "confidence.png": "8-bit confidence",
    "points.ply": "coloured point cloud (binary PLY), metres, camera frame (see camera.json)",
    "camera.json": "intrinsics of the output maps (px) and where depth is measured from",
    "recording.rrd": "rerun recording with a default layout (aat-view)",
}


@dataclass
class DepthMaps:
    """One capture's results at one size (H, W).

    depth_m (H, W) metres from the sensor plane (NaN = unknown); aif (3, H, W) linear RGB in the stack's
    normalised units (about [0, 1]); std_m (H, W) metres or None; confidence (H, W) in [0, 1] or None."""

    depth_m: np.ndarray
    aif: np.ndarray
    std_m: np.ndarray | None = None
    confidence: np.ndarray | None = None


@dataclass
class RecordingInputs:
    """What the recording shows besides the maps: the frames (S, 3, h, w) normalised linear RGB sorted near to
    far (any size with the maps' aspect), their focus distances (S,) in metres, ground truth depth (H, W) metres
    on the maps' grid or None, and the recording's name."""

    frames: np.ndarray
    focus_m: np.ndarray
    gt_depth_m: np.ndarray | None = None
    name: str = "aat"


def summary_fields(written: dict, camera: Intrinsics, focus_m, model: dict, unknown: dict | None,
                   warnings: list[str]) -> dict:
    """The summary.json keys of every depth run (aat-infer's per capture and the Python API's): written =
    write_outputs' result; focus_m (S,) metres as used; model: the method's summary; unknown: mark_unknown's."""
    return {"focus_m": [float(f) for f in focus_m], "model": model,
            "output_size_px": [int(camera.width), int(camera.height)], "camera": camera_json(camera),
            "color_scales": written["color_scales"], "points": written["points"],
            "outputs": {**written["outputs"], "summary.json": "this file"}, "unknown": unknown, "warnings": warnings}


def write_summary(folder: Path, summary: dict) -> None:
    """folder/summary.json (docs/contracts.md, "Runtime outputs"): the one writer of the file, for aat-infer's
    runs and the Python API's `DepthResult.save` (numpy scalars as numbers; NaN refused: absent values are null)."""
    (Path(folder) / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False, default=_json_default))


def _json_default(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")


def to_srgb8(linear: np.ndarray) -> np.ndarray:
    """(3, H, W) or (H, W, 3) linear RGB -> (H, W, 3) uint8 sRGB."""
    x = linear.transpose(1, 2, 0) if linear.ndim == 3 and linear.shape[0] == 3 else linear
    return np.rint(linear_to_srgb(x) * 255).astype(np.uint8)


def _png(path: Path, img: np.ndarray) -> None:
    if img.ndim == 3:
        img = img[..., ::-1]  # RGB -> BGR for OpenCV
    if not imwrite(path, np.ascontiguousarray(img)):
        raise OutputError(f"{path}: could not write the image")


def _stride(n_pixels: int, max_points: int) -> int:
    return max(1, math.ceil(math.sqrt(n_pixels / max_points)))


def write_outputs(folder: str | Path, maps: DepthMaps, camera: Intrinsics,
                  recording: RecordingInputs | None = None, max_points: int = MAX_PLY_POINTS) -> dict:
    """Write every output file of one capture into `folder` (which exists; the caller makes it atomic).

    camera: intrinsics of the maps' H x W (aat_deploy.optics.camera). Returns {"outputs": {file: description},
    "color_scales": {...}, "points": {...}, "timings_s": {"write": s, "record": s}} for summary.json; a *_mm.png
    that clipped values beyond 65.535 m says how many pixels in its description (aat_deploy.io.depth_png)."""
    t0 = time.perf_counter()
    folder = Path(folder)
    depth = np.asarray(maps.depth_m, np.float32)
    h, w = depth.shape
    if (w, h) != (camera.width, camera.height):
        raise ValueError(f"maps are {w}x{h} px, the camera {camera.width}x{camera.height}")
    with np.errstate(invalid="ignore"):
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
    aif8 = to_srgb8(maps.aif)
    written: list[str] = []

    np.save(folder / "depth_m.npy", depth)
    clipped: dict[str, int] = {}  # *_mm.png: pixels beyond 65.535 m
    depth_mm, clipped["depth_mm.png"] = encode_mm16(depth)
    _png(folder / "depth_mm.png", depth_mm)
    ok, enc = cv2.imencode(".tiff", depth)
    if not ok:
        raise OutputError(f"{folder / 'depth_m.tif'}: could not encode the TIFF")
    (folder / "depth_m.tif").write_bytes(enc.tobytes())
    near, far = depth_range(depth)
    preview, depth_scale = depth_preview(depth, near, far)
    _png(folder / "depth_color.png", preview)
    _png(folder / "aif.png", aif8)
    written += ["depth_m.npy", "depth_m.tif", "depth_mm.png", "depth_color.png", "aif.png"]
    scales = {"depth_color.png": depth_scale.as_json()}

    std_scale = None
    if maps.std_m is not None:
        std = np.asarray(maps.std_m, np.float32)
        np.save(folder / "std_m.npy", std)
        std_mm, clipped["std_mm.png"] = encode_mm16(std)
        _png(folder / "std_mm.png", std_mm)
        preview, std_scale = uncertainty_preview(std, uncertainty_range(std)[1])
        _png(folder / "std_color.png", preview)
        scales["std_color.png"] = std_scale.as_json()
        written += ["std_m.npy", "std_mm.png", "std_color.png"]
    if maps.confidence is not None:
        conf = np.asarray(maps.confidence, np.float32)
        np.save(folder / "confidence.npy", conf)
        _png(folder / "confidence.png", np.rint(np.clip(np.nan_to_num(conf), 0, 1) * 255).astype(np.uint8))
        written += ["confidence.npy", "confidence.png"]

    stride = _stride(h * w, max_points)
    pts, rows, cols = points_from_depth(depth, camera, stride)
    write_ply(folder / "points.ply", pts, aif8[rows, cols],
              [f"aat-dff point cloud: metres; camera frame: {CAMERA_FRAME}",
               f"depth is measured from the sensor plane, the pinhole {camera.pupil_to_sensor_mm:g} mm in front of it",
               f"from pixels: {POINT_FROM_PIXEL}; intrinsics in camera.json; every {stride}. pixel"])
    (folder / "camera.json").write_text(json.dumps(camera_json(camera), indent=2))
    written += ["points.ply", "camera.json"]
    timings = {"write": round(time.perf_counter() - t0, 4)}

    t1 = time.perf_counter()
    if recording is not None:
        _write_rrd(folder / "recording.rrd", depth, aif8, maps.std_m, camera, recording, depth_scale, std_scale)
        written.append("recording.rrd")
    timings["record"] = round(time.perf_counter() - t1, 4)
    described = {k: DESCRIPTIONS[k] + (f"; {clipped[k]} px beyond 65.535 m clipped to 65535" if clipped.get(k) else "")
                 for k in written}  # the PNG's policy: aat_deploy.io.depth_png
    return {"outputs": described, "color_scales": scales, "points": {"count": int(len(pts)), "stride_px": stride},
            "timings_s": timings}


def _write_rrd(path: Path, depth: np.ndarray, aif8: np.ndarray, std: np.ndarray | None, camera: Intrinsics,
               rec: RecordingInputs, depth_scale, std_scale) -> None:
    """The recording at most RECORDING_MAX_SIDE px on the longer side (maps resized, intrinsics scaled)."""
    from .recording import write_recording  # rerun is imported only when a recording is written

    h, w = depth.shape
    s = min(1.0, RECORDING_MAX_SIDE / max(h, w))
    rw, rh = max(1, round(w * s)), max(1, round(h * s))
    cam = camera if (rw, rh) == (w, h) else camera.resized(rw, rh)
    near = lambda a: a if a is None or a.shape == (rh, rw) else cv2.resize(a, (rw, rh), interpolation=cv2.INTER_NEAREST)
    area = lambda a: a if a.shape[:2] == (rh, rw) else cv2.resize(a, (rw, rh), interpolation=cv2.INTER_AREA)
    depth_r, std_r, gt_r = near(depth), near(None if std is None else np.asarray(std, np.float32)), \
        near(None if rec.gt_depth_m is None else np.asarray(rec.gt_depth_m, np.float32))
    aif_r = area(aif8)
    frames8 = [to_srgb8(area(np.ascontiguousarray(fr.transpose(1, 2, 0)))) for fr in rec.frames]  # small first
    pts, rows, cols = points_from_depth(depth_r, cam, _stride(rh * rw, MAX_RRD_POINTS))
    write_recording(path, frames_srgb8=frames8, focus_m=[float(f) for f in rec.focus_m], depth_m=depth_r,
                    aif_srgb8=aif_r, std_m=std_r, camera=cam, points=pts, point_colors=aif_r[rows, cols],
                    depth_scale=depth_scale, std_scale=std_scale, gt_depth_m=gt_r, name=rec.name)
