"""The chart as a scene for the virtual camera: the all-in-focus image and the depth map (metres from the sensor
plane) of a printed chart at a pose, for a pinhole at the lens's entrance pupil (`pose.py` conventions). The
renderer (`aat_deploy.capture.virtual.shoot`, or `aat-render` with torch) then blurs it through any lens with any
effects; every later step is tested against this known truth."""

from __future__ import annotations

import cv2
import numpy as np

from ..capture.raw import srgb_to_linear
from .chart import ChartLayout
from .pose import ChartPose, homography_from_pose, intrinsics_matrix, plane_depth_mm

PAPER = (0.03, 0.85)  # linear reflectance of the print's black and white


def chart_scene(chart_u8: np.ndarray, layout: ChartLayout, pose: ChartPose, width: int, height: int, f_px: float,
                pupil_to_sensor_mm: float, background: float = 0.18, supersample: int = 3
                ) -> tuple[np.ndarray, np.ndarray]:
    """rgb (3, H, W) float32 linear reflectance (grey) and depth_m (H, W) float32 from the sensor plane of the chart
    image chart_u8 (its layout's pixels, sRGB-encoded) at `pose`, seen through a pinhole of focal length f_px
    (square pixels, principal point at the frame centre) at the entrance pupil, pupil_to_sensor_mm in front of the
    sensor. Off the chart the plane continues as a textureless wall of reflectance `background`. The chart is
    sampled with `supersample`^2 samples per pixel after an area pre-filter to that rate (no aliasing)."""
    k = intrinsics_matrix(f_px, width, height)
    r, t = pose.extrinsics(pupil_to_sensor_mm)
    if np.any(np.asarray([t[2]]) <= 0):
        raise ValueError(f"chart at {pose.distance_m} m is behind the pupil ({pupil_to_sensor_mm} mm in front of "
                         "the sensor)")
    uu, vv = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    z_mm = plane_depth_mm(r, t, k, uu, vv)
    if not np.all(z_mm > 0):
        raise ValueError("the chart's plane is behind the camera somewhere in the frame: tilt it less")
    depth_m = ((z_mm + pupil_to_sensor_mm) / 1000.0).astype(np.float32)
    # chart pixels per image pixel at the frame centre: pre-filter the chart to `supersample` samples per pixel
    px_mm = float(z_mm[height // 2, width // 2]) / f_px  # chart mm per image pixel (about; tilt aside)
    ratio = px_mm * layout.px_per_mm / supersample
    chart = chart_u8
    ppm = layout.px_per_mm
    if ratio > 1:
        new = (max(1, int(round(chart.shape[1] / ratio))), max(1, int(round(chart.shape[0] / ratio))))
        chart = cv2.resize(chart_u8, new, interpolation=cv2.INTER_AREA)
        ppm = new[0] / layout.size_mm[0]
    refl = PAPER[0] + (PAPER[1] - PAPER[0]) * srgb_to_linear(chart.astype(np.float32) / 255.0)
    w_mm, h_mm = layout.size_mm
    a = np.array([[1 / ppm, 0, 0.5 / ppm - w_mm / 2], [0, 1 / ppm, 0.5 / ppm - h_mm / 2], [0, 0, 1]])
    ss = int(supersample)
    s = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1]])
    hmat = s @ homography_from_pose(k, r, t) @ a
    big = cv2.warpPerspective(refl.astype(np.float32), hmat, (width * ss, height * ss), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=float(background))
    img = cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA)
    return np.repeat(img[None], 3, 0).astype(np.float32), depth_m

