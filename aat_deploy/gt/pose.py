"""Camera pose from clicked correspondences, for `aat-gt render` (the pose-calibration helper).

A user clicks a few points in a frame (pixel u, v) and the same points on the mesh (world x, y, z, in the mesh's
units times --mesh-scale, metres). The pose is the camera-to-world transform that reprojects the world points
onto the clicked pixels with the least squared error, through the same pinhole as the ground-truth renderer
(`aat_deploy.optics.camera.Intrinsics`: projection centre at the entrance pupil, OpenCV's pixel convention, camera axes x right,
y down, z forward). Without a starting pose it needs 4 points not all on a line and solves globally (OpenCV's
SQPnP); with one (`init`, e.g. a phone's own camera transform) it refines it, and 3 points are enough.
Then Levenberg-Marquardt on all points. The residual of every point is reported, so a mis-click shows.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..optics.camera import Intrinsics
from .raycast import GTRenderError


@dataclass
class Correspondences:
    """pixels (N, 2) (u = column, v = row, px, OpenCV convention); world (N, 3) in metres; source: the file."""

    pixels: np.ndarray
    world: np.ndarray
    source: str


@dataclass
class PoseFit:
    """cam_to_world (4, 4), camera axes RDF; residuals_px (N,) reprojection error of each point; rms_px."""

    cam_to_world: np.ndarray
    residuals_px: np.ndarray
    rms_px: float
    method: str

    def as_json(self, intr: Intrinsics, points: Correspondences, notes: list[str]) -> dict:
        """The pose file `load_pose` reads (R, t, axes RDF), with how it was found."""
        return {"R": self.cam_to_world[:3, :3].tolist(), "t": self.cam_to_world[:3, 3].tolist(), "axes": "RDF",
                "calibration": {"points": str(points.source), "method": self.method, "n_points": len(points.pixels),
                                "reprojection_rms_px": self.rms_px, "residuals_px": self.residuals_px.tolist(),
                                "image_px": [intr.width, intr.height], "intrinsics": intr.as_dict(),
                                "notes": notes}}


def load_correspondences(path: str | Path, mesh_scale: float = 1.0) -> Correspondences:
    """Points from JSON ({"points": [{"pixel": [u, v], "world": [x, y, z]}, ...]} or the list alone) or CSV
    (header u,v,x,y,z). World coordinates are scaled by mesh_scale to metres."""
    path = Path(path)
    if not path.is_file():
        raise GTRenderError(f"{path}: no such file")
    try:
        if path.suffix.lower() == ".csv":
            with path.open(newline="") as f:
                rows = list(csv.DictReader(f))
            missing = {"u", "v", "x", "y", "z"} - set(rows[0] if rows else [])
            if missing:
                raise GTRenderError(f"{path}: CSV needs the columns u,v,x,y,z (missing {', '.join(sorted(missing))})")
            pix = [[float(r["u"]), float(r["v"])] for r in rows]
            wld = [[float(r["x"]), float(r["y"]), float(r["z"])] for r in rows]
        else:
            d = json.loads(path.read_text())
            pts = d.get("points") if isinstance(d, dict) else d
            if not isinstance(pts, list) or not all(isinstance(p, dict) for p in pts):
                raise GTRenderError(f'{path}: expected {{"points": [{{"pixel": [u, v], "world": [x, y, z]}}, ...]}}')
            pix = [p.get("pixel") for p in pts]
            wld = [p.get("world") for p in pts]
        pixels = np.asarray(pix, dtype=np.float64)
        world = np.asarray(wld, dtype=np.float64) * mesh_scale
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, ValueError, TypeError) as e:
        raise GTRenderError(f"{path}: malformed correspondences ({type(e).__name__}: {str(e)[:120]})") from None
    if pixels.ndim != 2 or pixels.shape[1:] != (2,) or world.shape != (len(pixels), 3):
        raise GTRenderError(f"{path}: every point needs a pixel [u, v] and a world [x, y, z]")
    if not (np.isfinite(pixels).all() and np.isfinite(world).all()):
        raise GTRenderError(f"{path}: non-finite coordinates")
    return Correspondences(pixels, world, str(path))


def _camera_matrix(intr: Intrinsics) -> np.ndarray:
    return np.array([[intr.fx, 0, intr.cx], [0, intr.fy, intr.cy], [0, 0, 1]], dtype=np.float64)


def project(world: np.ndarray, intr: Intrinsics, cam_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of world points (N, 3) and their z in camera axes (N,) (m, in front of the pupil if > 0)."""
    r, t = cam_to_world[:3, :3], cam_to_world[:3, 3]
    cam = (world - t) @ r  # R^T (X - t), row-wise
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([intr.fx * cam[:, 0] / z + intr.cx, intr.fy * cam[:, 1] / z + intr.cy], axis=1)
    return uv, z


def _to_cam_to_world(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    r_wc, _ = cv2.Rodrigues(rvec)  # world to camera
    m = np.eye(4)
    m[:3, :3] = r_wc.T
    m[:3, 3] = (-r_wc.T @ tvec.reshape(3, 1)).ravel()
    return m


def solve_pose(points: Correspondences, intr: Intrinsics, init: np.ndarray | None = None) -> PoseFit:
    """The camera-to-world pose (RDF axes) that best reprojects `points` through `intr`; `init` (4, 4) starts the
    refinement. Raises GTRenderError (one line) for too few or degenerate points or a pose behind the points."""
    n, src = len(points.pixels), points.source
    need = 3 if init is not None else 4
    if n < need:
        raise GTRenderError(f"{src}: {n} point(s); the pose needs at least {need} "
                            f"({'with' if init is not None else 'without'} a starting pose)")
    centred = points.world - points.world.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[1] <= 1e-6 * max(sv[0], 1e-12):
        raise GTRenderError(f"{src}: the world points lie on one line; the rotation about it is undetermined")
    k, dist = _camera_matrix(intr), np.zeros(5)
    obj, img = points.world.reshape(-1, 1, 3), points.pixels.reshape(-1, 1, 2)
    if init is not None:
        r_wc = init[:3, :3].T
        rvec, _ = cv2.Rodrigues(r_wc)
        tvec = (-r_wc @ init[:3, 3]).reshape(3, 1)
        method = "refined from the starting pose (Levenberg-Marquardt)"
    else:
        ok, rvec, tvec = cv2.solvePnP(obj, img, k, dist, flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            raise GTRenderError(f"{src}: no pose found (SQPnP failed; are the points matched correctly?)")
        method = "SQPnP, then Levenberg-Marquardt"
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, dist, rvec.astype(np.float64), tvec.astype(np.float64),
                                      (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-12))
    pose = _to_cam_to_world(rvec, tvec)
    uv, z = project(points.world, intr, pose)
    if (z <= 0).any():
        raise GTRenderError(f"{src}: the fitted camera has {int((z <= 0).sum())} point(s) behind it "
                            "(wrong matches, or world units off: --mesh-scale?)")
    res = np.linalg.norm(uv - points.pixels, axis=1)
    return PoseFit(pose, res, float(math.sqrt(np.mean(res ** 2))), method)


def fit_notes(fit: PoseFit, points: Correspondences, intr: Intrinsics) -> list[str]:
    """What the user should check: clicks outside the image, a poor fit, single points far off the rest."""
    notes = []
    u, v = points.pixels[:, 0], points.pixels[:, 1]
    outside = np.flatnonzero((u < -0.5) | (v < -0.5) | (u > intr.width - 0.5) | (v > intr.height - 0.5))
    if len(outside):
        notes.append(f"point(s) {', '.join(str(i) for i in outside)} lie outside the {intr.width}x{intr.height} px "
                     "image (pixels clicked at another resolution? give --width/--height)")
    if len(points.pixels) > 4:
        med = float(np.median(fit.residuals_px))
        bad = np.flatnonzero(fit.residuals_px > max(3 * med, 2.0))
        if len(bad):
            notes.append("point(s) " + ", ".join(f"{i} ({fit.residuals_px[i]:.1f} px)" for i in bad)
                         + f" reproject far from their click (median {med:.2f} px): a mis-click or a wrong match?")
    else:
        notes.append(f"{len(points.pixels)} points leave little to check the pose against; 6 or more spread over "
                     "the frame and in depth are better")
    if fit.rms_px > 2.0:
        notes.append(f"reprojection RMS {fit.rms_px:.2f} px: the intrinsics or the matches may be off")
    return notes


def preview(image_rgb: np.ndarray, points: Correspondences, intr: Intrinsics, fit: PoseFit) -> np.ndarray:
    """8-bit BGR picture (for cv2.imwrite): the frame with each click (green circle) and where the fitted pose
    puts its world point (red cross), joined by a line, numbered. image_rgb (H, W, 3) display-referred 0..1."""
    img = np.ascontiguousarray((np.clip(image_rgb, 0, 1) * 255).astype(np.uint8)[..., ::-1])
    if img.shape[:2] != (intr.height, intr.width):
        img = cv2.resize(img, (intr.width, intr.height), interpolation=cv2.INTER_AREA)
    uv, _ = project(points.world, intr, fit.cam_to_world)
    r = max(3, round(min(intr.width, intr.height) / 100))
    for i, (c, p) in enumerate(zip(points.pixels, uv)):
        c_i, p_i = tuple(round(float(x)) for x in c), tuple(round(float(x)) for x in p)
        cv2.line(img, c_i, p_i, (0, 255, 255), 1, cv2.LINE_AA)
        cv2.circle(img, c_i, r, (0, 255, 0), 1, cv2.LINE_AA)
        cv2.drawMarker(img, p_i, (0, 0, 255), cv2.MARKER_CROSS, 2 * r, 1, cv2.LINE_AA)
        cv2.putText(img, str(i), (c_i[0] + r, c_i[1] - r), cv2.FONT_HERSHEY_SIMPLEX, r / 10, (255, 255, 255), 1,
                    cv2.LINE_AA)
    return img
