"""Ground-truth depth rendered from a mesh (an iPhone lidar scan, a CAD model): camera intrinsics, the pose file
and ray casting (trimesh with Embree through embreex, the optional `gt` extra: `pip install "aat-dff[gt]"`).

Camera model: a pinhole whose projection centre is the lens's entrance pupil. Pixel (u, v) (column, row; the
centre of the top-left pixel is (0, 0), OpenCV's convention) looks along ((u − cx)/fx, (v − cy)/fy, 1) in camera
axes x right, y down, z forward. The ray cast gives the z-depth from the projection centre; the project's depth is
metres from the **sensor plane** (README, Conventions), so the entrance pupil's distance in front of the sensor,
`pupil_to_sensor_mm`, is added: depth_m = z_m + pupil_to_sensor_mm / 1000.

Intrinsics come from a DfF model (.onnx metadata `aat.focal_length_mm`, `aat.pixel_um`, `aat.sensor_px`) or a
small JSON (`load_intrinsics`); `aat-lens info LENS --json` writes one, with the pupil position.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import CaptureError

ORTHO_TOL = 1e-3


class GTRenderError(CaptureError):
    """Bad input to the ground-truth renderer (intrinsics, pose, mesh), reported as one line."""


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
            raise GTRenderError(f"{self.source}: {width}x{height} px has another aspect ratio than the sensor's "
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
        raise GTRenderError(f"{where}: {key} must be a positive number, got {v!r}")
    return float(v)


def _pair(d: dict, key: str, where: str) -> tuple[float, float]:
    v = d.get(key)
    if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(x, (int, float)) and x > 0 for x in v)):
        raise GTRenderError(f"{where}: {key} must be [W, H] (positive), got {v!r}")
    return float(v[0]), float(v[1])


def intrinsics_from_dict(d: dict, where: str) -> Intrinsics:
    """Intrinsics from a dict (JSON file or ONNX metadata with the `aat.` prefix removed). Accepted keys:
    calibrated: width, height, fx_px, fy_px[, cx_px, cy_px]; or from the lens: focal_length_mm (or efl_mm),
    sensor_px [W, H], pixel_um (or sensor_mm [W, H]). Pupil: pupil_to_sensor_mm, else total_track_mm + bfl_mm −
    entrance_pupil_z_mm (`aat-lens info --json`, sensor focused at infinity), else the focal length (thin lens)."""
    notes: list[str] = []
    if "surfaces" in d:
        raise GTRenderError(f"{where}: a lens prescription; write its intrinsics with "
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
            raise GTRenderError(f"{where}: needs fx_px/fy_px/width/height, or focal_length_mm (or efl_mm) with "
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
        raise GTRenderError(f"{path}: no such file")
    if path.suffix.lower() == ".onnx":
        import onnxruntime as ort

        try:
            sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        except Exception as e:  # noqa: BLE001 (onnxruntime's errors derive from Exception only)
            raise GTRenderError(f"{path}: not a loadable ONNX model ({str(e).splitlines()[0][:200]})") from None
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
        try:
            d = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise GTRenderError(f"{path}: not valid JSON ({e})") from None
        if not isinstance(d, dict):
            raise GTRenderError(f"{path}: expected a JSON object")
        intr = intrinsics_from_dict(d, str(path))
    if (width is None) != (height is None):
        raise GTRenderError("give both --width and --height, or neither")
    if width is not None:
        intr = intr.resized(int(width), int(height))
    if pupil_to_sensor_mm is not None:
        intr = replace(intr, pupil_to_sensor_mm=float(pupil_to_sensor_mm),
                       notes=[n for n in intr.notes if "pupil" not in n])
    return intr


AXES = {"RDF": np.diag([1.0, 1.0, 1.0]), "RUB": np.diag([1.0, -1.0, -1.0])}


def load_pose(path: str | Path) -> np.ndarray:
    """Camera-to-world (4, 4) with camera axes x right, y down, z forward (RDF), from a pose JSON:
    {"camera_to_world": 4x4} | {"world_to_camera": 4x4} | {"R": 3x3, "t": [x, y, z]} (camera to world:
    X_world = R·X_cam + t, t = the projection centre in world coordinates), with optional
    "axes": "RDF" (default; OpenCV) or "RUB" (x right, y up, z backward; ARKit, OpenGL). World units = the mesh's
    (scaled to metres by --mesh-scale)."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise GTRenderError(f"{path}: not valid JSON ({e})") from None
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
