"""The camera of an output image: pinhole intrinsics, where depth is measured from, and points from depth.

Depth everywhere in aat is metres from the **sensor plane** along the optical axis (a camera's focus scale).
The pinhole that maps pixels to rays sits at the lens's projection centre (entrance pupil), `pupil_to_sensor_mm`
in front of the sensor; a DfF model carries no pupil position, so it is the focal length there (a thin lens
focused at infinity), as `aat-gt` assumes (docs/contracts.md). A pixel (u, v) (OpenCV convention: the centre of
the top-left pixel is (0, 0)) with depth d metres is the point, in the camera frame (origin at the pinhole, x right,
y down, z forward, metres):

    z = d - pupil_to_sensor_mm / 1000,   x = (u - cx) / fx * z,   y = (v - cy) / fy * z

`camera_json` writes these intrinsics as `camera.json`, in the keys `aat-gt render --lens` reads.
"""

from __future__ import annotations

import numpy as np

from .eval.raycast import Intrinsics, intrinsics_from_dict

DEPTH_ORIGIN = "sensor plane"
POINT_FROM_PIXEL = ("z = depth_m - pupil_to_sensor_mm / 1000; x = (u - cx_px) / fx_px * z; "
                    "y = (v - cy_px) / fy_px * z")
CAMERA_FRAME = "origin at the pinhole (projection centre), x right, y down, z forward along the optical axis, metres"
PIXEL_CONVENTION = "OpenCV: (u, v) = (column, row), the centre of the top-left pixel is (0, 0)"


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
