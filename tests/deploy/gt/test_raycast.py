"""aat-gt render: ray-cast meshes of known geometry and compare with the analytic depth (to 1 mm); pose and
intrinsics formats; outputs and their checks."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from conftest import ROOT

trimesh = pytest.importorskip("trimesh")

from aat_deploy.cli import gt as gt_cli
from aat_deploy.gt.raycast import GTRenderError, load_pose, pixel_rays, render_depth
from aat_deploy.optics.camera import CameraError, Intrinsics, intrinsics_from_dict, load_intrinsics

PUPIL_MM = 40.0
# the accuracy aat-gt promises, a length by design (metres); Embree's float32 rounding is ~1e-7 of the depth
GT_TOL_M = 1e-3
INTR = {"focal_length_mm": 50.0, "sensor_px": [96, 64], "pixel_um": 375.0, "pupil_to_sensor_mm": PUPIL_MM}


def _intr() -> Intrinsics:
    return intrinsics_from_dict(INTR, "test")


def _plane(z: float, half: float = 50.0) -> trimesh.Trimesh:
    return trimesh.Trimesh([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]],
                           [[0, 1, 2], [0, 2, 3]], process=False)


def _rot_y(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def _write_pose(path, **kw):
    path.write_text(json.dumps({k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in kw.items()}))
    return path


def test_fronto_parallel_plane_is_flat_at_distance_plus_pupil():
    depth, info = render_depth(_plane(2.0), _intr(), np.eye(4))
    assert np.isfinite(depth).all() and info["hits"] == depth.size
    assert np.abs(depth - (2.0 + PUPIL_MM / 1000)).max() < GT_TOL_M


def test_rotated_and_shifted_camera_matches_analytic_plane_depth():
    """Camera 1 m behind the origin, turned 20° about y, plane z = 2: z-depth = 3 / (R·d)_z per pixel."""
    intr = _intr()
    pose = np.eye(4)
    pose[:3, :3] = _rot_y(20.0)
    pose[:3, 3] = [0.0, 0.0, -1.0]
    depth, _ = render_depth(_plane(2.0), intr, pose)
    d_world = pixel_rays(intr) @ pose[:3, :3].T
    expected = 3.0 / d_world[..., 2] + PUPIL_MM / 1000
    assert np.isfinite(depth).all()
    assert np.abs(depth - expected).max() < GT_TOL_M
    assert depth[:, -1].mean() > depth[:, 0].mean() + 0.1  # turned right (+x): the plane recedes to the right


def test_box_front_face_and_background():
    """A 1 x 0.6 x 0.4 m box centred at (0.1, 0, 3): its front face (z = 2.8) where its pixels look, no hit elsewhere."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    box.apply_translation((0.1, 0.0, 3.0))
    intr = _intr()
    depth, _ = render_depth(box, intr, np.eye(4))
    rays = pixel_rays(intr)
    x, y = rays[..., 0] * 2.8, rays[..., 1] * 2.8  # where each ray crosses the front face's plane
    margin = 0.01
    inside = (x > -0.4 + margin) & (x < 0.6 - margin) & (np.abs(y) < 0.3 - margin)
    outside = (x < -0.4 - margin) | (x > 0.6 + margin) | (np.abs(y) > 0.3 + margin)
    assert inside.sum() > 100 and outside.sum() > 100
    assert np.abs(depth[inside] - (2.8 + PUPIL_MM / 1000)).max() < GT_TOL_M
    assert np.isnan(depth[outside]).all()


def test_pose_formats_agree(tmp_path):
    r = _rot_y(15.0)
    t = np.array([0.2, -0.1, -0.5])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    a = load_pose(_write_pose(tmp_path / "a.json", camera_to_world=m))
    b = load_pose(_write_pose(tmp_path / "b.json", R=r, t=t))
    c = load_pose(_write_pose(tmp_path / "c.json", world_to_camera=np.linalg.inv(m)))
    # ARKit/OpenGL camera axes (x right, y up, z backward): the same camera has R·diag(1, -1, -1)
    d = load_pose(_write_pose(tmp_path / "d.json", R=r @ np.diag([1.0, -1.0, -1.0]), t=t, axes="RUB"))
    for p in (b, c, d):
        assert np.allclose(p, a, rtol=0, atol=1e-9)  # float64 4x4 poses with entries <= 1 m: ~1e-16 rounding


@pytest.mark.parametrize("pose, msg", [
    ({"R": np.diag([1.0, 1.0, 2.0]), "t": [0, 0, 0]}, "orthonormal"),
    ({"R": np.diag([1.0, 1.0, -1.0]), "t": [0, 0, 0]}, "orthonormal"),
    ({"camera_to_world": np.eye(3)}, "4x4"),
    ({"t": [0, 0, 0]}, "needs"),
    ({"R": np.eye(3), "t": [0, 0, 0], "axes": "LUF"}, "axes"),
])
def test_bad_pose_is_one_line_error(tmp_path, pose, msg):
    path = _write_pose(tmp_path / "pose.json", **pose)
    with pytest.raises(GTRenderError, match=msg) as e:
        load_pose(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)


def test_intrinsics_sources(tmp_path):
    model = ROOT / "models" / "reproduce" / "dff_dfvnet_aat.onnx"
    i = load_intrinsics(model)
    assert (i.width, i.height) == (960, 640)
    assert i.fx == pytest.approx(49.5616023 / 0.0375) and i.cx == pytest.approx(479.5)
    assert i.pupil_to_sensor_mm == pytest.approx(49.5616023) and "thin lens" in i.notes[0]
    half = load_intrinsics(model, 480, 320, pupil_to_sensor_mm=37.0)
    assert half.fx == pytest.approx(i.fx / 2) and half.cx == pytest.approx(239.5)
    assert half.pupil_to_sensor_mm == 37.0 and half.notes == []
    with pytest.raises(CameraError, match="aspect"):
        load_intrinsics(model, 480, 480)
    # `aat-lens info --json` output: the entrance pupil with the sensor focused at infinity
    info = {"efl_mm": 49.56, "bfl_mm": 25.67, "entrance_pupil_z_mm": 22.51, "total_track_mm": 33.91,
            "sensor_mm": [36.0, 24.0], "sensor_px": [960, 640], "pixel_um": 37.5}
    p = tmp_path / "intr.json"
    p.write_text(json.dumps(info))
    j = load_intrinsics(p)
    assert j.pupil_to_sensor_mm == pytest.approx(33.91 + 25.67 - 22.51) and j.fx == pytest.approx(49.56 / 0.0375)
    calib = tmp_path / "calib.json"
    calib.write_text(json.dumps({"width": 640, "height": 480, "fx_px": 500.0, "fy_px": 501.0, "cx_px": 320.0,
                                 "cy_px": 240.0, "pupil_to_sensor_mm": 5.0}))
    k = load_intrinsics(calib)
    assert (k.fx, k.fy, k.cx, k.cy, k.pupil_to_sensor_mm) == (500.0, 501.0, 320.0, 240.0, 5.0)
    with pytest.raises(CameraError, match="aat-lens info"):
        load_intrinsics(ROOT / "lenses" / "canon_rf50mm_f1.8.json")


def test_cli_render_writes_depth_mask_and_refuses_to_overwrite(tmp_path, capsys):
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    box.apply_translation((0.0, 0.0, 3.0))
    box.apply_scale(1000.0)  # a mesh in millimetres
    mesh = tmp_path / "box.ply"
    box.export(mesh)
    pose = _write_pose(tmp_path / "pose.json", camera_to_world=np.eye(4))
    intr = tmp_path / "intr.json"
    intr.write_text(json.dumps(INTR))
    cap = tmp_path / "capture"
    args = ["render", str(mesh), "--pose", str(pose), "--lens", str(intr), "--out", str(cap), "--mesh-scale",
            "0.001", "-q"]
    assert gt_cli.main(args) == 0
    mm = cv2.imread(str(cap / "gt_depth_mm.png"), cv2.IMREAD_UNCHANGED)
    m = np.load(cap / "gt_depth_m.npy")
    mask = cv2.imread(str(cap / "gt_mask.png"), cv2.IMREAD_UNCHANGED)
    assert mm.dtype == np.uint16 and mm.shape == (64, 96) and m.dtype == np.float32
    assert set(np.unique(mask)) == {0, 255}
    assert ((mask > 0) == np.isfinite(m)).all() and ((mm > 0) == np.isfinite(m)).all()
    assert np.abs(m[mask > 0] - (2.8 + PUPIL_MM / 1000)).max() < GT_TOL_M  # only the front face is seen
    assert (mm[mask > 0] == 2840).all()
    rinfo = json.loads((cap / "gt_render.json").read_text())
    assert rinfo["intrinsics"]["pupil_to_sensor_mm"] == PUPIL_MM and rinfo["hits"] == int((mask > 0).sum())
    capsys.readouterr()
    assert gt_cli.main(args) == 2
    assert "exists" in capsys.readouterr().err
    assert gt_cli.main(args + ["--force"]) == 0
    # a .png path: the .npy and mask beside it
    assert gt_cli.main(args[:7] + [str(tmp_path / "d_mm.png"), "--mesh-scale", "0.001", "-q"]) == 0
    assert (tmp_path / "d_m.npy").is_file() and (tmp_path / "d_mm_mask.png").is_file()


def test_cli_render_missing_the_mesh_is_an_error(tmp_path, capsys):
    pose = _write_pose(tmp_path / "pose.json", camera_to_world=np.eye(4))
    intr = tmp_path / "intr.json"
    intr.write_text(json.dumps(INTR))
    mesh = tmp_path / "far.ply"
    _plane(-5.0).export(mesh)  # behind the camera
    rc = gt_cli.main(["render", str(mesh), "--pose", str(pose), "--lens", str(intr), "--out", str(tmp_path / "o"),
                      "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "no pixel sees the mesh" in err and len(err.strip().splitlines()) == 1
