"""The chart as a scene for the virtual camera: the all-in-focus image and the depth map (metres from the sensor
plane) of a printed chart at a pose, for a pinhole at the lens's entrance pupil (`pose.py` conventions). The
renderer (`aat_deploy.capture.virtual.shoot`, or `aat-render` with torch) then blurs it through any lens with any
effects; every later step is tested against this known truth."""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..io.color import srgb_to_linear
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



def turned_view(rgb: np.ndarray, z_mm: np.ndarray, f_px: float, yaw_deg: float, pitch_deg: float, width: int,
                height: int) -> tuple[np.ndarray, np.ndarray]:
    """The scene seen by the same pinhole turned about its centre (the pupil): rgb (3, Hp, Wp) and z_mm (Hp, Wp)
    (z from the pinhole, mm) of a wide view with focal length f_px and its principal point at its centre; yaw
    (+: turned right), pitch (+: turned up). Returns rgb (3, H, W) (bilinear) and z_mm (H, W) (nearest, so
    depth edges stay sharp) of the turned H x W view: a point keeps its range rho = z / cos(theta), so
    z' = z cos(theta') / cos(theta)."""
    hp, wp = z_mm.shape
    k0 = np.array([[f_px, 0, (wp - 1) / 2], [0, f_px, (hp - 1) / 2], [0, 0, 1]])
    k1 = np.array([[f_px, 0, (width - 1) / 2], [0, f_px, (height - 1) / 2], [0, 0, 1]])
    a, b = math.radians(yaw_deg), math.radians(pitch_deg)
    ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    r = ry @ rx  # new camera axes in the old camera's frame: a ray d1 of the new view is r @ d1 in the old
    m = k0 @ r @ np.linalg.inv(k1)  # new pixel -> old pixel
    flags = cv2.WARP_INVERSE_MAP
    out_rgb = np.stack([cv2.warpPerspective(np.ascontiguousarray(c, np.float32), m, (width, height),
                                            flags=cv2.INTER_LINEAR | flags, borderMode=cv2.BORDER_REFLECT)
                        for c in rgb])
    z_old = cv2.warpPerspective(np.ascontiguousarray(z_mm, np.float32), m, (width, height),
                                flags=cv2.INTER_NEAREST | flags, borderMode=cv2.BORDER_REFLECT)
    vv, uu = np.mgrid[0:height, 0:width].astype(np.float64)
    src = cv2.perspectiveTransform(np.stack([uu, vv], -1).reshape(-1, 1, 2), m).reshape(height, width, 2)
    cos_old = 1 / np.sqrt(1 + ((src[..., 0] - k0[0, 2]) ** 2 + (src[..., 1] - k0[1, 2]) ** 2) / f_px ** 2)
    cos_new = 1 / np.sqrt(1 + ((uu - k1[0, 2]) ** 2 + (vv - k1[1, 2]) ** 2) / f_px ** 2)
    return out_rgb.astype(np.float32), (z_old * cos_new / cos_old).astype(np.float32)
