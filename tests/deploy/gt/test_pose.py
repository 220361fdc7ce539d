"""aat-gt pose: the camera pose from clicked correspondences. Synthetic clicks from a known pose (projected by hand,
independently of OpenCV) are solved back; the written pose file renders the same ground truth as the true pose;
a mis-click is flagged; bad input gets one line."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from aat_deploy.cli import gt as gt_cli
from aat_deploy.gt.pose import (
    Correspondences,
    fit_notes,
    load_correspondences,
    solve_pose,
)
from aat_deploy.gt.raycast import GTRenderError, load_pose
from aat_deploy.optics.camera import intrinsics_from_dict

INTR = {"width": 1200, "height": 800, "fx_px": 1500.0, "fy_px": 1500.0, "cx_px": 610.0, "cy_px": 395.0,
        "pupil_to_sensor_mm": 37.0}


def _rot(ax: float, ay: float, az: float) -> np.ndarray:
    """Rotation from angles in degrees about x, then y, then z."""
    a, b, c = (math.radians(x) for x in (ax, ay, az))
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _pose(r: np.ndarray, t) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


TRUE = _pose(_rot(8.0, -15.0, 3.0), [0.4, -0.2, -1.5])  # camera to world, RDF axes


def _clicks(world: np.ndarray, pose: np.ndarray, noise_px: float = 0.0, seed: int = 0) -> np.ndarray:
    """Pinhole projection written out: camera coordinates R^T (X - t), then u = fx x/z + cx, v = fy y/z + cy."""
    cam = (pose[:3, :3].T @ (world - pose[:3, 3]).T).T
    u = INTR["fx_px"] * cam[:, 0] / cam[:, 2] + INTR["cx_px"]
    v = INTR["fy_px"] * cam[:, 1] / cam[:, 2] + INTR["cy_px"]
    return np.stack([u, v], 1) + np.random.default_rng(seed).normal(0, noise_px, (len(world), 2))


def _scene_points(n: int = 10, seed: int = 1) -> np.ndarray:
    """Points spread over the view, 2-5 m in front of the true camera (so they are visible), in world metres."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(2.0, 5.0, n)
    u, v = rng.uniform(50, 1150, n), rng.uniform(50, 750, n)
    cam = np.stack([(u - INTR["cx_px"]) / INTR["fx_px"] * z, (v - INTR["cy_px"]) / INTR["fy_px"] * z, z], 1)
    return cam @ TRUE[:3, :3].T + TRUE[:3, 3]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def test_solves_known_pose_from_noisy_clicks():
    world = _scene_points()
    pts = Correspondences(_clicks(world, TRUE, noise_px=0.3), world, "synthetic")
    fit = solve_pose(pts, intrinsics_from_dict(INTR, "test"))
    assert _angle_deg(fit.cam_to_world, TRUE) < 0.1
    assert np.linalg.norm(fit.cam_to_world[:3, 3] - TRUE[:3, 3]) < 0.01  # m, camera 2-5 m from the points
    assert 0.1 < fit.rms_px < 0.6  # about the click noise: the fit neither fails nor overfits
    assert fit_notes(fit, pts, intrinsics_from_dict(INTR, "test")) == []


def test_exact_clicks_give_the_exact_pose_coplanar_too():
    """Six points on one wall (coplanar) are enough; noise-free clicks give the pose to numerical precision."""
    world = np.array([[x, y, 3.0] for x in (-0.8, 0.0, 0.9) for y in (-0.5, 0.6)])
    fit = solve_pose(Correspondences(_clicks(world, TRUE), world, "wall"), intrinsics_from_dict(INTR, "test"))
    assert _angle_deg(fit.cam_to_world, TRUE) < 1e-4
    assert np.abs(fit.cam_to_world - TRUE).max() < 1e-6
    assert fit.rms_px < 1e-6


def test_refines_a_rough_starting_pose_from_three_points():
    world = _scene_points(3, seed=4)
    rough = _pose(_rot(5.0, -10.0, 0.0), [0.3, -0.1, -1.4])  # 5° and 15 cm off, e.g. a phone's own estimate
    assert _angle_deg(rough, TRUE) > 4
    pts = Correspondences(_clicks(world, TRUE), world, "three")
    intr = intrinsics_from_dict(INTR, "test")
    fit = solve_pose(pts, intr, init=rough)
    assert _angle_deg(fit.cam_to_world, TRUE) < 1e-3 and np.abs(fit.cam_to_world[:3, 3] - TRUE[:3, 3]).max() < 1e-4
    with pytest.raises(GTRenderError, match="at least 4"):  # three points without a start: ambiguous
        solve_pose(pts, intr)


def test_a_misclick_is_named():
    world = _scene_points(8)
    pix = _clicks(world, TRUE, noise_px=0.2)
    pix[5] += [25.0, -10.0]
    pts = Correspondences(pix, world, "p")
    intr = intrinsics_from_dict(INTR, "test")
    fit = solve_pose(pts, intr)
    notes = fit_notes(fit, pts, intr)
    assert any("point(s) 5 (" in n and "mis-click" in n for n in notes), notes
    assert int(np.argmax(fit.residuals_px)) == 5


def test_cli_pose_file_renders_the_same_ground_truth(tmp_path):
    """aat-gt pose from a CSV of clicks, then aat-gt render with the written pose: the depth equals the one
    rendered with the true pose (to 1 mm), and the clicks' picture is written."""
    pytest.importorskip("trimesh")
    import trimesh

    box = trimesh.creation.box(extents=(1.5, 1.0, 1.0))
    box.apply_translation(TRUE[:3, :3] @ [0.2, 0.1, 4.5] + TRUE[:3, 3])  # 4.5 m in front of the camera
    world = np.asarray(box.vertices)  # the corners a user would click
    pix = _clicks(world, TRUE)
    visible = (pix[:, 0] > 0) & (pix[:, 0] < 1199) & (pix[:, 1] > 0) & (pix[:, 1] < 799)
    assert visible.sum() >= 6
    rows = ["u,v,x,y,z"] + [",".join(f"{x:.6f}" for x in (*p, *(w * 1000))) for p, w in
                            zip(pix[visible], world[visible])]
    (tmp_path / "clicks.csv").write_text("\n".join(rows) + "\n")  # world in mm: --mesh-scale 0.001
    (tmp_path / "intr.json").write_text(json.dumps(INTR))
    frame = np.full((800, 1200, 3), 90, np.uint8)
    cv2.imwrite(str(tmp_path / "frame.png"), frame)
    box.export(tmp_path / "box.ply")
    args = ["pose", "--points", str(tmp_path / "clicks.csv"), "--lens", str(tmp_path / "intr.json"),
            "--out", str(tmp_path / "pose.json"), "--mesh-scale", "0.001", "--image", str(tmp_path / "frame.png")]
    assert gt_cli.main(args) == 0
    saved = json.loads((tmp_path / "pose.json").read_text())
    assert saved["calibration"]["n_points"] == int(visible.sum()) and saved["calibration"]["reprojection_rms_px"] < 1e-3
    assert np.abs(load_pose(tmp_path / "pose.json") - TRUE).max() < 1e-6
    pic = cv2.imread(str(tmp_path / "pose.png"))
    assert pic.shape == (800, 1200, 3) and (pic != 90).any()  # the marks are drawn
    (tmp_path / "true.json").write_text(json.dumps({"camera_to_world": TRUE.tolist()}))
    for name, pose in (("fit", tmp_path / "pose.json"), ("true", tmp_path / "true.json")):
        assert gt_cli.main(["render", str(tmp_path / "box.ply"), "--pose", str(pose), "--lens",
                            str(tmp_path / "intr.json"), "--out", str(tmp_path / name), "-q"]) == 0
    a, b = np.load(tmp_path / "fit" / "gt_depth_m.npy"), np.load(tmp_path / "true" / "gt_depth_m.npy")
    assert (np.isfinite(a) == np.isfinite(b)).mean() > 0.999 and np.isfinite(a).mean() > 0.2
    both = np.isfinite(a) & np.isfinite(b)
    assert np.abs(a[both] - b[both]).max() < 1e-3  # aat-gt's promised 1 mm (a length by design)
    # the same command again refuses to overwrite; --force does
    assert gt_cli.main(args) == 2
    assert gt_cli.main(args + ["--force"]) == 0


@pytest.mark.parametrize("content, message", [
    ('{"points": [{"pixel": [1, 2], "world": [0, 0, 1]}]}', "at least 4"),
    ('{"points": [{"pixel": [1, 2]}]}', "needs a pixel [u, v] and a world"),
    ("u,v,x,y\n1,2,3,4\n", "missing z"),
    ('{"points": 3}', 'expected {"points"'),
    ('{"points": [' + ",".join(f'{{"pixel": [{10 * i}, 5], "world": [{i}, 0, 3]}}' for i in range(5)) + "]}",
     "lie on one line"),
])
def test_bad_points_get_one_line(tmp_path, capsys, content, message):
    f = tmp_path / ("p.csv" if content.startswith("u,") else "p.json")
    f.write_text(content)
    (tmp_path / "intr.json").write_text(json.dumps(INTR))
    rc = gt_cli.main(["pose", "--points", str(f), "--lens", str(tmp_path / "intr.json"),
                      "--out", str(tmp_path / "pose.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and message in err and str(f) in err
    assert not (tmp_path / "pose.json").exists()


def test_points_behind_the_camera_are_refused():
    """Points reflected through the camera centre project to the same pixels, but behind the camera: refused."""
    world = _scene_points(6)
    pts = Correspondences(_clicks(world, TRUE), world, "flip")
    mirrored = Correspondences(pts.pixels, 2 * TRUE[:3, 3] - world, "flip")  # points reflected through the camera
    with pytest.raises(GTRenderError, match="behind it|no pose"):
        solve_pose(mirrored, intrinsics_from_dict(INTR, "test"), init=TRUE)


def test_load_correspondences_scales_world(tmp_path):
    f = tmp_path / "p.json"
    f.write_text(json.dumps([{"pixel": [1, 2], "world": [1000, 2000, 3000]}]))
    c = load_correspondences(f, 0.001)
    assert c.world.tolist() == [[1.0, 2.0, 3.0]] and c.pixels.tolist() == [[1.0, 2.0]]


def test_image_of_another_size_is_noted(tmp_path, capsys):
    """Clicks are read in the intrinsics' pixels; a frame of another size is drawn resized and the user told."""
    world = _scene_points(8)
    rows = ["u,v,x,y,z"] + [",".join(f"{x:.6f}" for x in (*p, *w)) for p, w in zip(_clicks(world, TRUE), world)]
    (tmp_path / "clicks.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "intr.json").write_text(json.dumps(INTR))
    cv2.imwrite(str(tmp_path / "half.png"), np.full((400, 600, 3), 90, np.uint8))
    assert gt_cli.main(["pose", "--points", str(tmp_path / "clicks.csv"), "--lens", str(tmp_path / "intr.json"),
                        "--out", str(tmp_path / "pose.json"), "--image", str(tmp_path / "half.png")]) == 0
    err = capsys.readouterr().err
    assert "is 600x400 px, the intrinsics 1200x800 px" in err and "pupil" not in err
    saved = json.loads((tmp_path / "pose.json").read_text())
    assert any("600x400" in n for n in saved["calibration"]["notes"])
    assert cv2.imread(str(tmp_path / "pose.png")).shape == (800, 1200, 3)


def test_out_must_be_json(tmp_path):
    with pytest.raises(SystemExit):
        gt_cli.main(["pose", "--points", "p.csv", "--lens", "i.json", "--out", str(tmp_path / "pose.png")])
