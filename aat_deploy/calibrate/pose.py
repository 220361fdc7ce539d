"""Where the chart is: its markers found in a frame, the chart-to-image homography, and each pixel's distance from
the sensor plane (torch-free, OpenCV's ArUco detector).

Geometry (docs/contracts.md, "Camera pose"): a pinhole at the entrance pupil, `pupil_to_sensor_mm` in front of
the sensor; camera axes x right, y down, z forward; pixels in OpenCV's convention (the centre of the top-left pixel
is (0, 0)). The chart is the plane z = 0 of chart millimetres (origin at its centre, x right, y down, z into the
chart): X_cam = R X_chart + t (mm).

Two ways to distances, both from the markers' homography H (chart mm -> pixels):

- with a **measured distance** (a tape or laser meter from the camera's sensor-plane mark to the chart point at the
  frame centre): a plane's inverse depth is affine in pixel coordinates, 1/z(u, v) ~ g . (u, v, 1) with g the
  third row of H^-1, whatever the intrinsics; so z(u, v) = z_c g.(c) / g.(u, v), z_c = the measured distance
  minus the pupil's distance from the sensor. The intrinsics and the pupil's position then matter only through
  the chart's tilt (a 13 mm pupil error moves a 20 deg tilted chart's edge by under 2 mm);
- without one: the pose from the markers (PnP) with the focal length in pixels (EXIF focal length and the sensor
  width, or fitted from the tilted chart's perspective), and the pupil a focal length in front of the sensor
  (a thin lens focused at infinity) unless told.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .chart import ChartLayout, aruco_dictionary

MIN_MARKERS = 4  # a homography needs 4 points; 4 markers (16 corners) spread over the chart make it stable


@dataclass(frozen=True)
class ChartPose:
    """A chart placed in front of the camera (for rendering): distance_m from the sensor plane to the chart along
    the optical axis; tilt_x_deg: rotation about the camera's vertical axis (+: the chart's right side farther);
    tilt_y_deg: about its horizontal axis (+: the top farther); roll_deg: about the optical axis (+: clockwise as
    seen by the camera); axis_point_mm: the chart point (chart mm) the optical axis meets."""

    distance_m: float
    tilt_x_deg: float = 0.0
    tilt_y_deg: float = 0.0
    roll_deg: float = 0.0
    axis_point_mm: tuple[float, float] = (0.0, 0.0)

    def rotation(self) -> np.ndarray:
        """R (3, 3): chart axes in camera axes."""
        a, b, c = (math.radians(v) for v in (self.tilt_x_deg, self.tilt_y_deg, self.roll_deg))
        ry = np.array([[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]])
        rx = np.array([[1, 0, 0], [0, math.cos(b), math.sin(b)], [0, -math.sin(b), math.cos(b)]])
        rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
        return ry @ rx @ rz

    def extrinsics(self, pupil_to_sensor_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """(R, t): X_cam = R X_chart + t in mm, the pinhole at the entrance pupil."""
        r = self.rotation()
        z_axis = 1000.0 * self.distance_m - pupil_to_sensor_mm
        t = np.array([0.0, 0.0, z_axis]) - r @ np.array([*self.axis_point_mm, 0.0])
        return r, t


def intrinsics_matrix(f_px: float, width: int, height: int) -> np.ndarray:
    """K with square pixels and the principal point at the frame centre."""
    return np.array([[f_px, 0, (width - 1) / 2], [0, f_px, (height - 1) / 2], [0, 0, 1]], np.float64)


def homography_from_pose(k: np.ndarray, r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """H (3, 3): chart mm (z = 0) -> pixels, scaled so that its third row gives the camera z (mm)."""
    return k @ np.column_stack([r[:, 0], r[:, 1], t])


def plane_depth_mm(r: np.ndarray, t: np.ndarray, k: np.ndarray, u, v) -> np.ndarray:
    """Camera z (mm from the pinhole) of the chart plane under pixels (u, v)."""
    n = r[:, 2]
    x = (np.asarray(u, np.float64) - k[0, 2]) / k[0, 0]
    y = (np.asarray(v, np.float64) - k[1, 2]) / k[1, 1]
    return float(n @ t) / (n[0] * x + n[1] * y + n[2])


@dataclass
class ChartView:
    """The chart found in one frame: homography (chart mm -> px), the matched points, their count and the
    homography's reprojection RMS (px), the frame it came from."""

    homography: np.ndarray
    object_mm: np.ndarray  # (N, 2)
    image_px: np.ndarray  # (N, 2)
    markers: int
    rms_px: float
    frame: int = -1

    def inverse_depth_row(self) -> np.ndarray:
        """g (3,): 1/z(u, v) is proportional to g . (u, v, 1) on the chart plane."""
        return np.linalg.inv(self.homography)[2]

    def depth_ratio(self, u, v, cx: float, cy: float) -> np.ndarray:
        """z(u, v) / z(cx, cy) of the chart plane (no intrinsics needed)."""
        g = self.inverse_depth_row()
        return (g[0] * cx + g[1] * cy + g[2]) / (g[0] * np.asarray(u, np.float64) + g[1] * np.asarray(v, np.float64)
                                                 + g[2])

    def chart_mask(self, height: int, width: int, layout: ChartLayout, margin_mm: float = 0.0) -> np.ndarray:
        """(H, W) bool: pixels that see the chart (inside its border shrunk by margin_mm)."""
        w, h = layout.size_mm
        poly = np.array([[-w / 2 + margin_mm, -h / 2 + margin_mm], [w / 2 - margin_mm, -h / 2 + margin_mm],
                         [w / 2 - margin_mm, h / 2 - margin_mm], [-w / 2 + margin_mm, h / 2 - margin_mm]])
        img = cv2.perspectiveTransform(poly.reshape(-1, 1, 2), self.homography).reshape(-1, 2)
        mask = np.zeros((height, width), np.uint8)
        cv2.fillPoly(mask, [np.round(img * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
        return mask.astype(bool)


def to_u8(frame_linear: np.ndarray) -> np.ndarray:
    """(3, H, W) or (H, W, 3) or (H, W) linear -> (H, W) uint8 sRGB-encoded grey, exposure-normalised (99.5th
    percentile to 1), what the marker detector sees."""
    from ..io.color import linear_to_srgb

    x = np.asarray(frame_linear, np.float32)
    if x.ndim == 3:
        x = x.mean(0) if x.shape[0] == 3 else x.mean(2)
    x = x / max(float(np.percentile(x, 99.5)), 1e-12)
    return np.round(np.clip(linear_to_srgb(np.clip(x, 0, 1)), 0, 1) * 255).astype(np.uint8)


def detect_markers(grey_u8: np.ndarray, layout: ChartLayout) -> dict[int, np.ndarray]:
    """{marker id: (4, 2) image corners} of the layout's markers found in one grey frame (uint8)."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(aruco_dictionary(layout.dictionary), params)
    corners, ids, _ = det.detectMarkers(grey_u8)
    known = set(int(i) for i in layout.ids)
    return {} if ids is None else {int(i): c.reshape(4, 2).astype(np.float64)
                                   for c, i in zip(corners, ids.ravel()) if int(i) in known}


def view_from_markers(found: dict[int, np.ndarray], layout: ChartLayout) -> ChartView | None:
    """The homography from matched markers (RANSAC, then least squares on the inliers); None under MIN_MARKERS."""
    if len(found) < MIN_MARKERS:
        return None
    known = {int(i): c for i, c in zip(layout.ids, layout.corners_mm)}
    obj = np.concatenate([known[i] for i in found]).astype(np.float64)
    img = np.concatenate(list(found.values())).astype(np.float64)
    h, inliers = cv2.findHomography(obj, img, cv2.RANSAC, 3.0)
    if h is None:
        return None
    keep = inliers.ravel().astype(bool)
    h, _ = cv2.findHomography(obj[keep], img[keep], 0)  # least squares on the inliers
    proj = cv2.perspectiveTransform(obj[keep].reshape(-1, 1, 2), h).reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum((proj - img[keep]) ** 2, 1))))
    return ChartView(h, obj[keep], img[keep], int(keep.sum() // 4), rms)


def detect(grey_u8: np.ndarray, layout: ChartLayout) -> ChartView | None:
    """The chart's view in one grey frame (uint8); None when fewer than MIN_MARKERS markers are found."""
    return view_from_markers(detect_markers(grey_u8, layout), layout)


def best_view(frames_linear, layout: ChartLayout) -> ChartView | None:
    """The chart's view from a sweep, frames (S, 3, H, W): each marker from the middle frame of those it is found
    in (a tilted chart is sharp in different frames at different places; the middle of a marker's run is where it
    is sharpest). `frame` is the frame with most markers found."""
    runs: dict[int, list] = {}
    counts = []
    for i, fr in enumerate(frames_linear):
        found = detect_markers(to_u8(fr), layout)
        counts.append(len(found))
        for k, c in found.items():
            runs.setdefault(k, []).append((i, c))
    chosen = {k: v[len(v) // 2][1] for k, v in runs.items()}
    view = view_from_markers(chosen, layout)
    if view is not None:
        view.frame = int(np.argmax(counts))
    return view


def pose_from_view(view: ChartView, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, RMS px) by PnP with intrinsics k (planar IPPE, then Levenberg-Marquardt)."""
    obj = np.column_stack([view.object_mm, np.zeros(len(view.object_mm))])
    ok, rvec, tvec = cv2.solvePnP(obj, view.image_px, k, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ValueError("PnP failed")
    rvec, tvec = cv2.solvePnPRefineLM(obj, view.image_px, k, None, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, k, None)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - view.image_px) ** 2, 1))))
    return cv2.Rodrigues(rvec)[0], tvec.ravel(), rms


def focal_from_view(view: ChartView, width: int, height: int) -> tuple[float, float]:
    """(f_px, relative standard error) from one tilted view, principal point at the centre, square pixels, no
    distortion (Zhang's constraints on one homography, refined by OpenCV's calibration). The error is
    `focal_profile_rel`'s: OpenCV's own deviation reads 0 % with the aspect ratio fixed, even for a chart square
    to the camera, which leaves the focal length undetermined (a large or infinite error)."""
    obj = np.column_stack([view.object_mm, np.zeros(len(view.object_mm))]).astype(np.float32)
    k0 = intrinsics_matrix(float(max(width, height)), width, height)
    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
             | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3)
    try:
        _, k, *_ = cv2.calibrateCameraExtended(
            [obj], [view.image_px.astype(np.float32)], (width, height), k0, np.zeros(5), flags=flags)
    except cv2.error:
        return math.nan, math.inf
    f = float(k[0, 0])
    if not (math.isfinite(f) and f > 0):
        return math.nan, math.inf
    return f, focal_profile_rel(view, f, width, height)


def focal_profile_rel(view: ChartView, f_px: float, width: int, height: int, step: float = 0.1) -> float:
    """Relative standard error of a focal length in pixels from the markers themselves: the curvature of the PnP
    reprojection's sum of squares in the focal length's log (f_px x (1 +- step)), against the residual's own
    variance. A chart square to the camera leaves the sum flat: inf."""
    n = 2 * len(view.image_px)
    if not (math.isfinite(f_px) and f_px > 0) or n <= 7:
        return math.inf
    try:
        ssr = [n * pose_from_view(view, intrinsics_matrix(f_px * (1 + s), width, height))[2] ** 2
               for s in (0.0, step, -step)]
    except (ValueError, cv2.error):
        return math.inf
    curvature = (ssr[1] + ssr[2] - 2 * ssr[0]) / (2 * step ** 2)
    var = ssr[0] / (n - 7)  # 6 of the pose, 1 of the focal length
    return math.sqrt(var / curvature) if curvature > 0 else math.inf
