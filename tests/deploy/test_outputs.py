"""aat-infer's outputs opened by the libraries that read them: the float TIFF by tifffile, the point cloud by
trimesh, camera.json by aat-gt's intrinsics reader, the recording's blueprint and colour maps by rerun's RrdReader;
the colour previews, the writer on its own (as the classical focus method calls it), and the native-resolution
upsampling."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from deploy_fixtures import write_dng_capture

from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.outputs import DepthMaps, RecordingInputs, write_outputs
from aat_deploy.infer.pipeline import Options, run_capture
from aat_deploy.infer.process import native_warp
from aat_deploy.infer.upsample import blend_by_depth, guided_upsample
from aat_deploy.io.colorize import depth_preview, depth_range
from aat_deploy.optics.camera import Intrinsics, load_intrinsics, points_from_depth

FOCUS = [0.6, 0.8, 1.2, 2.0, 3.0, 4.5]
F_PX = 50.0 / 0.540  # the tiny model: focal length mm / pixel pitch mm


@pytest.fixture(scope="module")
def model(model_path):
    return DfFModel(model_path, threads=1)


@pytest.fixture(scope="module")
def result(model, tmp_path_factory):
    cap = write_dng_capture(tmp_path_factory.mktemp("cap") / "scene", FOCUS)
    out = tmp_path_factory.mktemp("res") / "out"
    summary = run_capture(cap, model, out, Options(quiet=True))
    return out, summary


def test_float_tiff_is_the_depth(result):
    tifffile = pytest.importorskip("tifffile")
    out, _ = result
    tif = tifffile.imread(out / "depth_m.tif")
    assert tif.dtype == np.float32
    np.testing.assert_array_equal(tif, np.load(out / "depth_m.npy"))


def test_point_cloud_read_by_trimesh(result):
    trimesh = pytest.importorskip("trimesh")
    out, _ = result
    depth = np.load(out / "depth_m.npy")
    aif = cv2.imread(str(out / "aif.png"))[..., ::-1]
    cloud = trimesh.load(out / "points.ply")
    pts = np.asarray(cloud.vertices)
    assert len(pts) == np.isfinite(depth).sum() == 48 * 64
    # row-major order: the pixel (v, u) = (10, 50) is point 10 * 64 + 50
    v, u, pupil_m = 10, 50, 0.050
    z = depth[v, u] - pupil_m  # the pinhole sits the focal length in front of the sensor (thin lens, infinity)
    np.testing.assert_allclose(pts[v * 64 + u], [(u - 31.5) / F_PX * z, (v - 23.5) / F_PX * z, z], rtol=1e-5)
    colors = np.asarray(cloud.colors)[:, :3]
    np.testing.assert_array_equal(colors[v * 64 + u], aif[v, u])
    header = (out / "points.ply").read_bytes().split(b"end_header")[0].decode()
    assert "camera frame" in header and "sensor plane" in header


def test_camera_json_is_read_by_aat_gt(result):
    out, summary = result
    cam = json.loads((out / "camera.json").read_text())
    assert (cam["width"], cam["height"]) == (64, 48) and cam["depth_measured_from"] == "sensor plane"
    assert cam["fx_px"] == pytest.approx(F_PX) and cam["K"][0][0] == cam["fx_px"]
    intr = load_intrinsics(out / "camera.json")
    assert (intr.fx, intr.fy, intr.cx, intr.cy) == pytest.approx((F_PX, F_PX, 31.5, 23.5))
    assert intr.pupil_to_sensor_mm == pytest.approx(50.0)
    assert summary["camera"] == cam


def test_depth_preview_scale_and_bar(result):
    out, summary = result
    depth = np.load(out / "depth_m.npy")
    img = cv2.imread(str(out / "depth_color.png"))[..., ::-1]
    assert img.shape[0] == 48 and img.shape[1] > 64  # the map, then the colour bar with its labels
    near, far = summary["color_scales"]["depth_color.png"]["range_m"]
    assert (near, far) == pytest.approx(depth_range(depth))
    turbo = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
    for v, u in ((20, 5), (20, 60)):
        t = np.clip((1 / near - 1 / depth[v, u]) / (1 / near - 1 / far), 0, 1)  # inverse-depth scale
        np.testing.assert_array_equal(img[v, u], turbo[round(t * 255)])
    assert not np.array_equal(img[20, 5], img[20, 60])  # near and far halves differ


def test_depth_preview_bar_runs_near_to_far():
    depth = np.linspace(0.5, 5.0, 200 * 300, dtype=np.float32).reshape(200, 300)
    img, scale = depth_preview(depth, 0.5, 5.0)
    bar = img[:, 300:]
    turbo = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
    cols = [c for c in range(bar.shape[1]) if (bar[:, c] == turbo[255]).all(-1).any()]
    assert cols, "no colour bar"
    column = bar[:, cols[0]]
    top = np.where((column == turbo[255]).all(-1))[0].min()
    bottom = np.where((column == turbo[0]).all(-1))[0].max()
    assert top < bottom  # far (high end) at the top, near at the bottom
    assert scale.as_json() == {"colormap": "turbo", "range_m": [0.5, 5.0], "scale": "inverse"}
    # unknown depth is grey
    depth[0, 0] = np.nan
    assert (depth_preview(depth, 0.5, 5.0)[0][0, 0] == 128).all()


@pytest.mark.parametrize("h, w", [(1, 1), (2, 3), (5, 7), (24, 32), (48, 64), (700, 900)])
def test_previews_of_any_size(h, w):
    depth = np.linspace(0.5, 5.0, h * w, dtype=np.float32).reshape(h, w)
    img, _ = depth_preview(depth, *depth_range(depth))
    assert img.shape[0] == h and img.shape[1] > w and img.dtype == np.uint8


def test_recording_blueprint_and_colormaps(result):
    from rerun.chunk import RrdReader

    out, summary = result
    reader = RrdReader(out / "recording.rrd")
    assert reader.blueprints(), "no blueprint in the recording"
    views: dict[str, dict] = {}
    for ch in reader.stream(store=reader.blueprints()[0]).collect().stream():
        b = ch.to_record_batch()
        key = str(ch.entity_path).removesuffix("/ViewContents")
        for n in b.schema.names:
            if n.startswith(("ViewBlueprint:", "ViewContents:")):
                views.setdefault(key, {})[n.split(":")[1]] = b.column(n).to_pylist()[0][0]
    by_name = {v["display_name"]: v for v in views.values() if "display_name" in v}
    assert {"focal stack", "depth (m from sensor)", "all-in-focus", "3-D points", "uncertainty (m)"} <= set(by_name)
    assert by_name["3-D points"]["class_identifier"] == "3D"
    assert by_name["depth (m from sensor)"]["query"] == "+ world/camera/depth"
    # depth and uncertainty carry an explicit colour map and range (the previews' own)
    data = {str(c.entity_path): c.to_record_batch() for c in reader.stream().collect().stream()
            if "DepthImage:colormap" in c.to_record_batch().schema.names}
    near, far = summary["color_scales"]["depth_color.png"]["range_m"]
    rng = data["/world/camera/depth"].column("DepthImage:depth_range").to_pylist()[0][0]
    assert rng == pytest.approx([near, far])
    std_rng = data["/world/camera/std_m"].column("DepthImage:depth_range").to_pylist()[0][0]
    assert std_rng == pytest.approx(summary["color_scales"]["std_color.png"]["range_m"])


def test_writer_alone_with_confidence_and_unknown_depth(tmp_path):
    """The writer as any depth method calls it: arrays in, files out; NaN depth stays unknown everywhere."""
    h, w = 30, 40
    depth = np.full((h, w), 2.0, np.float32)
    depth[:5] = np.nan
    aif = np.random.default_rng(0).random((3, h, w), dtype=np.float32)
    cam = Intrinsics(w, h, 60.0, 60.0, (w - 1) / 2, (h - 1) / 2, 20.0, "test")
    conf = np.linspace(0, 1, h * w, dtype=np.float32).reshape(h, w)
    info = write_outputs(tmp_path, DepthMaps(depth, aif, None, conf), cam)
    assert set(info["outputs"]) == {"depth_m.npy", "depth_m.tif", "depth_mm.png", "depth_color.png", "aif.png",
                                    "confidence.npy", "confidence.png", "points.ply", "camera.json"}
    assert (cv2.imread(str(tmp_path / "depth_mm.png"), cv2.IMREAD_UNCHANGED)[:5] == 0).all()
    assert info["points"]["count"] == (h - 5) * w
    np.testing.assert_array_equal(np.load(tmp_path / "confidence.npy"), conf)


def test_writer_subsamples_large_clouds_and_previews_the_recording(tmp_path):
    h, w = 120, 160
    depth = np.full((h, w), 1.5, np.float32)
    aif = np.full((3, h, w), 0.5, np.float32)
    cam = Intrinsics(w, h, 100.0, 100.0, (w - 1) / 2, (h - 1) / 2, 0.0, "test")
    frames = np.full((2, 3, 60, 80), 0.5, np.float32)
    info = write_outputs(tmp_path, DepthMaps(depth, aif, np.zeros_like(depth)), cam,
                         RecordingInputs(frames, np.array([1.0, 2.0])), max_points=1000)
    assert info["points"]["stride_px"] == 5 and info["points"]["count"] == 24 * 32
    assert (tmp_path / "recording.rrd").stat().st_size > 0


def test_points_skip_pixels_in_front_of_the_pinhole():
    cam = Intrinsics(4, 2, 10.0, 10.0, 1.5, 0.5, 50.0, "test")
    depth = np.array([[0.04, 1.0, np.nan, -1.0], [2.0, 0.0, np.inf, 3.0]], np.float32)
    pts, rows, cols = points_from_depth(depth, cam)
    assert list(zip(rows, cols)) == [(0, 1), (1, 0), (1, 3)]
    assert pts[:, 2] == pytest.approx([0.95, 1.95, 2.95])


# -- native resolution ------------------------------------------------------------------------------------------
def test_guided_upsampling_puts_the_edge_where_the_image_has_it():
    """A depth step at a column that is not on the coarse grid: the coarse map has a blurred transition, the
    guide the sharp edge. The guided result errs far less than bilinear interpolation near the edge."""
    hh, wh, k = 64, 128, 4
    edge = 61  # native column of the step (not a multiple of k)
    inv = np.where(np.arange(wh) < edge, 1 / 0.8, 1 / 3.0).astype(np.float32)[None].repeat(hh, 0)
    guide = np.where(np.arange(wh) < edge, 0.8, 0.3).astype(np.float32)[None].repeat(hh, 0)
    lo = cv2.resize(inv, (wh // k, hh // k), interpolation=cv2.INTER_AREA)
    bilinear = cv2.resize(lo, (wh, hh), interpolation=cv2.INTER_LINEAR)
    guided = guided_upsample(lo, guide)
    band = slice(edge - 2 * k, edge + 2 * k)
    err_b = np.abs(bilinear[:, band] - inv[:, band]).mean()
    err_g = np.abs(guided[:, band] - inv[:, band]).mean()
    assert err_g < 0.25 * err_b
    # far from the edge (beyond the filter's reach: two box filters of 2 * 4 + 1 coarse px) flat stays flat
    far = slice(0, edge - 10 * k)
    assert np.abs(guided[:, far] - inv[:, far]).max() < 1e-5 * inv.max()


def test_blend_by_depth_interpolates_in_diopters():
    focus = np.array([0.5, 1.0, 2.0])  # 2, 1, 0.5 D
    frames = [np.full((1, 3, 3), v, np.float32) for v in (10.0, 20.0, 40.0)]
    depth = np.array([[0.5, 1.0, 1 / 0.75]], np.float32)  # at frames 0 and 1, halfway between 1 and 2 (0.75 D)
    out = blend_by_depth(frames, focus, depth)
    np.testing.assert_allclose(out[0, :, 0], [10.0, 20.0, 30.0], rtol=1e-6)
    # outside the stack's range: the nearest frame
    outside = blend_by_depth([f[:, :2] for f in frames], focus, np.array([[0.2, 50.0]], np.float32))
    np.testing.assert_allclose(outside[0, :, 0], [10.0, 40.0], rtol=1e-6)


def test_native_warp_matches_the_working_size_warp():
    """A shift of 1.5 working pixels is 3 native pixels at half size; a scale about the centre stays one."""
    m = np.array([[1.0, 0.0, 1.5], [0.0, 1.0, -0.5]])
    n = native_warp(m, (128, 96), (64, 48))
    np.testing.assert_allclose(n, [[1, 0, 3.0], [0, 1, -1.0]], atol=1e-6)


def test_native_resolution_outputs(model, tmp_path):
    cap = write_dng_capture(tmp_path / "big", FOCUS, h=96, w=128)
    out = tmp_path / "out"
    s = run_capture(cap, model, out, Options(quiet=True, native=True))
    depth = np.load(out / "depth_m.npy")
    assert depth.shape == (96, 128) and s["native_resolution"] and s["working_size_px"] == [64, 48]
    assert cv2.imread(str(out / "aif.png")).shape == (96, 128, 3)
    cam = json.loads((out / "camera.json").read_text())
    assert (cam["width"], cam["height"]) == (128, 96)
    assert cam["fx_px"] == pytest.approx(2 * F_PX) and cam["cx_px"] == pytest.approx(63.5)
    # depth stays within the working-size result's range, the near half nearer than the far half
    assert depth[:, :50].mean() < 1.2 < 2.0 < depth[:, 78:].mean()
    assert np.load(out / "std_m.npy").shape == (96, 128)
    # without the option the same capture gives the working size
    s2 = run_capture(cap, model, tmp_path / "out2", Options(quiet=True))
    assert np.load(tmp_path / "out2" / "depth_m.npy").shape == (48, 64) and not s2["native_resolution"]
    lo = np.load(tmp_path / "out2" / "depth_m.npy")
    assert lo.min() * (1 - 1e-5) <= depth.min() and depth.max() <= lo.max() * (1 + 1e-5)


def test_focus_method_writes_through_the_same_writer(tmp_path):
    """The classical method (no model) gets the same files, with its own camera: the assumed focal length (the
    longer side in px) and the pinhole at the sensor when no lens is given."""
    from aat_deploy.focus.runner import FocusMethod

    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    out = tmp_path / "out"
    s = run_capture(cap, FocusMethod(), out, Options(quiet=True))
    assert {"points.ply", "camera.json", "depth_m.tif", "depth_color.png", "confidence.npy"} <= set(s["outputs"])
    cam = json.loads((out / "camera.json").read_text())
    assert (cam["width"], cam["height"], cam["fx_px"], cam["pupil_to_sensor_mm"]) == (64, 48, 64.0, 0.0)
    assert any("assumed" in n for n in cam["notes"])
