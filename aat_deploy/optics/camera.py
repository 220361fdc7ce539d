"""The camera of an output image: pinhole intrinsics, where depth is measured from, and points from depth.

Depth everywhere in aat is metres from the **sensor plane** along the optical axis (a camera's focus scale).
The pinhole that maps pixels to rays sits at the lens's projection centre (entrance pupil), `pupil_to_sensor_mm`
in front of the sensor; a DfF model carries no pupil position, so it is the focal length there (a thin lens
focused at infinity), as `aat-gt` assumes (docs/contracts.md). A pixel (u, v) (OpenCV convention: the centre of
the top-left pixel is (0, 0)) with depth d metres is the point, in the camera frame (origin at the pinhole, x right,
y down, z forward, metres):

    z = d - pupil_to_sensor_mm / 1000,   x = (u - cx) / fx * z,   y = (v - cy) / fy * z

`camera_json` writes these intrinsics as `camera.json`, in the keys `aat-gt render --lens` reads; `load_intrinsics`
reads them (or a DfF model's, or a lens's from `aat-lens info --json`) back.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import CaptureError
from ..io.files import load_json

DEPTH_ORIGIN = "sensor plane"
POINT_FROM_PIXEL = ("z = depth_m - pupil_to_sensor_mm / 1000; x = (u - cx_px) / fx_px * z; "
                    "y = (v - cy_px) / fy_px * z")
CAMERA_FRAME = "origin at the pinhole (projection centre), x right, y down, z forward along the optical axis, metres"
PIXEL_CONVENTION = "OpenCV: (u, v) = (column, row), the centre of the top-left pixel is (0, 0)"


class CameraError(CaptureError):
    """Bad camera intrinsics (a file or model metadata), reported as one line."""


@dataclass
class Intrinsics:
    """width, height in px; fx, fy focal lengths in px; cx, cy principal point (px, OpenCV convention);
    pupil_to_sensor_mm: entrance pupil (projection centre) to sensor plane along the axis; notes: approximations."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    pupil_to_sensor_mm: float
    source: str
    notes: list[str] = field(default_factory=list)

    def resized(self, width: int, height: int) -> Intrinsics:
        """The same field of view sampled on width x height px (same aspect ratio, within 1 %)."""
        if abs((width / height) / (self.width / self.height) - 1) > 0.01:
            raise CameraError(f"{self.source}: {width}x{height} px has another aspect ratio than the sensor's "
                                f"{self.width}x{self.height} px")
        sx, sy = width / self.width, height / self.height
        return replace(self, width=width, height=height, fx=self.fx * sx, fy=self.fy * sy,
                       cx=(self.cx + 0.5) * sx - 0.5, cy=(self.cy + 0.5) * sy - 0.5)

    def as_dict(self) -> dict:
        return {"width": self.width, "height": self.height, "fx_px": self.fx, "fy_px": self.fy, "cx_px": self.cx,
                "cy_px": self.cy, "pupil_to_sensor_mm": self.pupil_to_sensor_mm, "source": self.source,
                "notes": self.notes}


def _num(d: dict, key: str, where: str) -> float:
    v = d.get(key)
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v <= 0:
        raise CameraError(f"{where}: {key} must be a positive number, got {v!r}")
    return float(v)


def _pair(d: dict, key: str, where: str) -> tuple[float, float]:
    v = d.get(key)
    if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(x, (int, float)) and x > 0 for x in v)):
        raise CameraError(f"{where}: {key} must be [W, H] (positive), got {v!r}")
    return float(v[0]), float(v[1])


def intrinsics_from_dict(d: dict, where: str) -> Intrinsics:
    """Intrinsics from a dict (JSON file or ONNX metadata with the `aat.` prefix removed). Accepted keys:
    calibrated: width, height, fx_px, fy_px[, cx_px, cy_px]; or from the lens: focal_length_mm (or efl_mm),
    sensor_px [W, H], pixel_um (or sensor_mm [W, H]). Pupil: pupil_to_sensor_mm, else total_track_mm + bfl_mm −
    entrance_pupil_z_mm (`aat-lens info --json`, sensor focused at infinity), else the focal length (thin lens)."""
    notes: list[str] = []
    if "surfaces" in d:
        raise CameraError(f"{where}: a lens prescription; write its intrinsics with "
                            f"`aat-lens info {Path(where).name} --json > intrinsics.json`")
    if "fx_px" in d:
        w, h = int(_num(d, "width", where)), int(_num(d, "height", where))
        fx, fy = _num(d, "fx_px", where), _num(d, "fy_px", where)
        cx = float(d.get("cx_px", (w - 1) / 2))
        cy = float(d.get("cy_px", (h - 1) / 2))
        f_mm = d.get("focal_length_mm", d.get("efl_mm"))
    else:
        f_mm = d.get("focal_length_mm", d.get("efl_mm"))
        if f_mm is None:
            raise CameraError(f"{where}: needs fx_px/fy_px/width/height, or focal_length_mm (or efl_mm) with "
                                "sensor_px and pixel_um (or sensor_mm)")
        f_mm = _num({"f": f_mm}, "f", where)
        wf, hf = _pair(d, "sensor_px", where)
        w, h = int(wf), int(hf)
        if "pixel_um" in d:
            px = px_y = _num(d, "pixel_um", where) / 1000.0
        else:
            sw, sh = _pair(d, "sensor_mm", where)
            px, px_y = sw / w, sh / h
        fx, fy = f_mm / px, f_mm / px_y
        cx, cy = (w - 1) / 2, (h - 1) / 2
    if "pupil_to_sensor_mm" in d:
        pupil = float(d["pupil_to_sensor_mm"])
    elif all(k in d for k in ("total_track_mm", "bfl_mm", "entrance_pupil_z_mm")):
        pupil = float(d["total_track_mm"]) + float(d["bfl_mm"]) - float(d["entrance_pupil_z_mm"])
        notes.append("pupil_to_sensor_mm from the paraxial entrance pupil with the sensor focused at infinity")
    elif f_mm is not None:
        pupil = float(f_mm)
        notes.append("pupil_to_sensor_mm unknown: the focal length is used (thin lens focused at infinity); "
                     "give pupil_to_sensor_mm for a thick lens")
    else:
        pupil = 0.0
        notes.append("pupil_to_sensor_mm unknown: depth is measured from the projection centre")
    return Intrinsics(w, h, fx, fy, cx, cy, pupil, where, notes)


def load_intrinsics(path: str | Path, width: int | None = None, height: int | None = None,
                    pupil_to_sensor_mm: float | None = None) -> Intrinsics:
    """Intrinsics from a DfF model (.onnx) or a JSON file (see intrinsics_from_dict), optionally resampled to
    width x height (both or neither) and with the pupil offset overridden."""
    path = Path(path)
    if not path.is_file():
        raise CameraError(f"{path}: no such file")
    if path.suffix.lower() == ".onnx":
        import onnxruntime as ort

        try:
            sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        except Exception as e:  # noqa: BLE001 (onnxruntime's errors derive from Exception only)
            raise CameraError(f"{path}: not a loadable ONNX model ({str(e).splitlines()[0][:200]})") from None
        raw = sess.get_modelmeta().custom_metadata_map
        d = {}
        for k, v in raw.items():
            if k.startswith("aat."):
                try:
                    d[k[4:]] = json.loads(v)
                except json.JSONDecodeError:
                    d[k[4:]] = v
        intr = intrinsics_from_dict(d, str(path))
    else:
        d = load_json(path, CameraError)  # the one reader of users' JSON (BOM, depth, size limits)
        if not isinstance(d, dict):
            raise CameraError(f"{path}: expected a JSON object")
        intr = intrinsics_from_dict(d, str(path))
    if (width is None) != (height is None):
        raise CameraError("give both --width and --height, or neither")
    if width is not None:
        intr = intr.resized(int(width), int(height))
    if pupil_to_sensor_mm is not None:
        intr = replace(intr, pupil_to_sensor_mm=float(pupil_to_sensor_mm),
                       notes=[n for n in intr.notes if "pupil" not in n])
    return intr


def model_intrinsics(meta: dict, where: str) -> Intrinsics:
    """Intrinsics of a DfF model's sensor from its metadata (`aat.*` keys, decoded): focal length / pixel pitch,
    principal point at the centre, pupil at the focal length in front of the sensor (thin lens at infinity)."""
    return intrinsics_from_dict({k[4:]: v for k, v in meta.items() if k.startswith("aat.")}, where)


def points_from_depth(depth_m: np.ndarray, cam: Intrinsics, stride: int = 1
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Back-project depth_m (H, W) (metres from the sensor) through `cam` (the same H, W).

    Returns points (N, 3) float32 in the camera frame (module docstring) and the rows, cols (N,) they came from,
    every `stride`-th pixel; pixels with unknown depth (NaN, inf, <= 0) or in front of the pinhole are skipped."""
    h, w = depth_m.shape
    if (w, h) != (cam.width, cam.height):
        raise ValueError(f"depth is {w}x{h} px, the camera {cam.width}x{cam.height}")
    rows, cols = np.mgrid[0:h:stride, 0:w:stride]
    d = depth_m[rows, cols].astype(np.float64)
    with np.errstate(invalid="ignore"):
        z = d - cam.pupil_to_sensor_mm / 1000.0
        ok = np.isfinite(z) & (d > 0) & (z > 0)
    rows, cols, z = rows[ok], cols[ok], z[ok]
    x = (cols - cam.cx) / cam.fx * z
    y = (rows - cam.cy) / cam.fy * z
    return np.stack([x, y, z], -1).astype(np.float32), rows, cols


def camera_json(cam: Intrinsics) -> dict:
    """camera.json: intrinsics in output pixels, the 3x3 matrix K, where depth is measured from and how a pixel
    becomes a point. `aat-gt render --lens camera.json` reads it as it is."""
    return {
        "width": cam.width, "height": cam.height,
        "fx_px": cam.fx, "fy_px": cam.fy, "cx_px": cam.cx, "cy_px": cam.cy,
        "K": [[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]],
        "pixel_convention": PIXEL_CONVENTION,
        "distortion": "none modelled",
        "depth_measured_from": DEPTH_ORIGIN,
        "pupil_to_sensor_mm": cam.pupil_to_sensor_mm,
        "camera_frame": CAMERA_FRAME,
        "point_from_pixel": POINT_FROM_PIXEL,
        "source": cam.source,
        "notes": list(cam.notes),
    }
