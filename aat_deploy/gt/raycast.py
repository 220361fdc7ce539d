"""Ground-truth depth rendered from a mesh (an iPhone lidar scan, a CAD model): the pose file and ray casting (trimesh with Embree through embreex, the optional `gt` extra: `pip install "aat-dff[gt]"`).

Camera model: a pinhole whose projection centre is the lens's entrance pupil. Pixel (u, v) (column, row; the
centre of the top-left pixel is (0, 0), OpenCV's convention) looks along ((u − cx)/fx, (v − cy)/fy, 1) in camera
axes x right, y down, z forward. The ray cast gives the z-depth from the projection centre; the project's depth is
metres from the **sensor plane** (README, Conventions), so the entrance pupil's distance in front of the sensor,
`pupil_to_sensor_mm`, is added: depth_m = z_m + pupil_to_sensor_mm / 1000.

Intrinsics (`aat_deploy.optics.camera.load_intrinsics`) come from a DfF model (.onnx metadata `aat.focal_length_mm`,
`aat.pixel_um`, `aat.sensor_px`) or a small JSON; `aat-lens info LENS --json` writes one, with the pupil position.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import CaptureError
from ..io.files import load_json
from ..optics.camera import Intrinsics

ORTHO_TOL = 1e-3


class GTRenderError(CaptureError):
    """Bad input to the ground-truth renderer (pose, mesh, clicked points), reported as one line."""


AXES = {"RDF": np.diag([1.0, 1.0, 1.0]), "RUB": np.diag([1.0, -1.0, -1.0])}


def load_pose(path: str | Path) -> np.ndarray:
    """Camera-to-world (4, 4) with camera axes x right, y down, z forward (RDF), from a pose JSON:
    {"camera_to_world": 4x4} | {"world_to_camera": 4x4} | {"R": 3x3, "t": [x, y, z]} (camera to world:
    X_world = R·X_cam + t, t = the projection centre in world coordinates), with optional
    "axes": "RDF" (default; OpenCV) or "RUB" (x right, y up, z backward; ARKit, OpenGL). World units = the mesh's
    (scaled to metres by --mesh-scale)."""
    path = Path(path)
    d = load_json(path, GTRenderError)  # the one reader of users' JSON (BOM, depth, size limits)
    if not isinstance(d, dict):
        raise GTRenderError(f"{path}: expected a JSON object")
    axes = d.get("axes", "RDF")
    if axes not in AXES:
        raise GTRenderError(f"{path}: axes must be one of {', '.join(AXES)}, got {axes!r}")
    try:
        if "camera_to_world" in d:
            m = np.asarray(d["camera_to_world"], dtype=np.float64)
        elif "world_to_camera" in d:
            m = np.asarray(d["world_to_camera"], dtype=np.float64)
            if m.shape == (4, 4):
                m = np.linalg.inv(m)
        elif "R" in d and "t" in d:
            m = np.eye(4)
            m[:3, :3] = np.asarray(d["R"], dtype=np.float64)
            m[:3, 3] = np.asarray(d["t"], dtype=np.float64).reshape(3)
        else:
            raise GTRenderError(f'{path}: needs "camera_to_world" (4x4), "world_to_camera" (4x4) or "R" and "t"')
    except (ValueError, TypeError, np.linalg.LinAlgError) as e:
        raise GTRenderError(f"{path}: malformed pose ({e})") from None
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise GTRenderError(f"{path}: the pose must be a finite 4x4 matrix, got shape {m.shape}")
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise GTRenderError(f"{path}: the last row of a pose must be [0, 0, 0, 1], got {m[3].tolist()}")
    r = m[:3, :3]
    if np.abs(r.T @ r - np.eye(3)).max() > ORTHO_TOL or np.linalg.det(r) < 0:
        raise GTRenderError(f"{path}: the rotation is not orthonormal with determinant +1 (scaled or mirrored?)")
    m = m.copy()
    m[:3, :3] = r @ AXES[axes]
    return m


def load_mesh(path: str | Path, scale_to_m: float = 1.0):
    """A triangle mesh (PLY, OBJ, STL, GLB, ... anything trimesh reads), vertices scaled to metres."""
    trimesh = _trimesh()
    path = Path(path)
    if not path.is_file():
        raise GTRenderError(f"{path}: no such mesh file")
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:  # noqa: BLE001 (trimesh raises many kinds for malformed files)
        raise GTRenderError(f"{path}: not a readable mesh ({type(e).__name__}: {str(e)[:160]})") from None
    if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
        raise GTRenderError(f"{path}: no triangles (a point cloud? mesh it first)")
    return trimesh.Trimesh(np.asarray(mesh.vertices, np.float64) * scale_to_m, np.asarray(mesh.faces), process=False)


def _trimesh():
    try:
        import trimesh
    except ImportError:
        raise GTRenderError('ray casting needs the gt extra: pip install "aat-dff[gt]" (trimesh, embreex)') from None
    return trimesh


def pixel_rays(intr: Intrinsics) -> np.ndarray:
    """(H, W, 3) ray directions in camera axes (x right, y down, z forward) with z = 1."""
    u = (np.arange(intr.width) - intr.cx) / intr.fx
    v = (np.arange(intr.height) - intr.cy) / intr.fy
    d = np.ones((intr.height, intr.width, 3))
    d[..., 0] = u[None, :]
    d[..., 1] = v[:, None]
    return d


def render_depth(mesh, intr: Intrinsics, cam_to_world: np.ndarray, max_incidence_deg: float | None = None,
                 chunk: int = 1 << 20) -> tuple[np.ndarray, dict]:
    """Depth (H, W) float32 in metres from the sensor plane (NaN where no surface is hit) and render info.

    First hit along each pixel's ray; z-depth from the projection centre plus pupil_to_sensor_mm. Hits more
    oblique than max_incidence_deg (angle between the ray and the surface normal) are dropped when given."""
    r, t = cam_to_world[:3, :3], cam_to_world[:3, 3]
    dirs = pixel_rays(intr).reshape(-1, 3) @ r.T
    n = dirs.shape[0]
    z = np.full(n, np.nan)
    dropped = 0
    cos_min = math.cos(math.radians(max_incidence_deg)) if max_incidence_deg is not None else None
    intersector = mesh.ray
    for s in range(0, n, chunk):
        d = dirs[s:s + chunk]
        o = np.broadcast_to(t, d.shape)
        loc, idx_ray, idx_tri = intersector.intersects_location(o, d, multiple_hits=False)
        if len(idx_ray) == 0:
            continue
        zz = (loc - t) @ r[:, 2]
        if cos_min is not None:
            du = d[idx_ray] / np.linalg.norm(d[idx_ray], axis=1, keepdims=True)
            cos = np.abs(np.sum(mesh.face_normals[idx_tri] * du, axis=1))
            keep = cos >= cos_min
            dropped += int((~keep).sum())
            idx_ray, zz = idx_ray[keep], zz[keep]
        z[s + idx_ray] = zz
    z = z.reshape(intr.height, intr.width)
    with np.errstate(invalid="ignore"):
        z = np.where(z > 0, z, np.nan)
    depth = (z + intr.pupil_to_sensor_mm / 1000.0).astype(np.float32)
    info = {"engine": type(intersector).__module__, "rays": n, "hits": int(np.isfinite(depth).sum()),
            "dropped_oblique": dropped}
    return depth, info
