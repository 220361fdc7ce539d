"""aat_deploy.api: arrays in, the same results as aat-infer out; bad input is a one-line ValueError."""

from __future__ import annotations

import json

import numpy as np
import pytest
from deploy_fixtures import render_stack, synthetic_scene, write_dng_capture

from aat_deploy.api import depth_from_focus, load_model, read_stack
from aat_deploy.infer.pipeline import Options, run_capture
from aat_deploy.io.color import linear_to_srgb

FOCUS = [0.6, 0.8, 1.2, 2.0, 3.0, 4.5]


@pytest.fixture(scope="module")
def model(model_path):
    return load_model(model_path, threads=1)


def test_same_as_aat_infer(model, tmp_path):
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    run_capture(cap, model, tmp_path / "out", Options(quiet=True))
    stack, focus = read_stack(cap)
    assert stack.shape == (6, 48, 64, 3) and focus.tolist() == pytest.approx(FOCUS)
    res = depth_from_focus(stack[::-1], focus[::-1], model)  # any order: sorted near to far inside
    np.testing.assert_array_equal(res.depth_m, np.load(tmp_path / "out" / "depth_m.npy"))
    np.testing.assert_array_equal(res.std_m, np.load(tmp_path / "out" / "std_m.npy"))
    assert res.focus_m.tolist() == pytest.approx(FOCUS) and res.aif.shape == (48, 64, 3)
    assert res.camera.fx == pytest.approx(50.0 / 0.540)
    res.save(tmp_path / "saved")
    for name in ("depth_m.npy", "aif.png", "camera.json", "points.ply", "recording.rrd"):
        assert (tmp_path / "saved" / name).is_file(), name
    assert json.loads((tmp_path / "saved" / "summary.json").read_text())["source"] == "aat_deploy.api"
    with pytest.raises(ValueError, match="exists"):
        res.save(tmp_path / "saved")
    res.save(tmp_path / "saved", force=True)


def test_srgb_integer_frames_are_decoded(model):
    tex, depth = synthetic_scene()
    frames = render_stack(tex, depth, FOCUS)
    lin = depth_from_focus(np.stack(frames), FOCUS, model)
    srgb16 = np.stack([np.rint(linear_to_srgb(f) * 65535).astype(np.uint16) for f in frames])
    enc = depth_from_focus(srgb16, FOCUS, model)
    # 16-bit sRGB round trip: the same depth to well within a focus step
    assert np.abs(enc.depth_m - lin.depth_m).mean() < 0.01 * (FOCUS[-1] - FOCUS[0])


def test_native_resolution(model):
    tex, depth = synthetic_scene(96, 128)
    frames = np.stack(render_stack(tex, depth, FOCUS))
    res = depth_from_focus(frames, FOCUS, model, native_res=True)
    assert res.depth_m.shape == (96, 128) and res.aif.shape == (96, 128, 3)
    assert res.camera.width == 128 and res.camera.fx == pytest.approx(2 * 50.0 / 0.540)


@pytest.mark.parametrize("stack, focus, message", [
    (np.zeros((3, 8, 8, 3), np.float32), [1, 2], "2 distances for 3 frames"),
    (np.zeros((3, 8, 8), np.float32), [1, 2, 3], r"frames must be \(H, W, 3\)"),
    (np.zeros((3, 8, 8, 3), np.float32), [1, 2, -3], "not positive"),
    (np.zeros((3, 8, 8, 3), np.float32), [1, 2, 2], "same focus distance"),
    (np.full((3, 8, 8, 3), np.nan, np.float32), [1, 2, 3], "finite"),
    (np.zeros((1, 8, 8, 3), np.float32), [1], "the model takes 2..16"),
    (np.zeros((0, 8, 8, 3), np.float32), [], "no frames"),
])
def test_bad_input_is_one_line(model, stack, focus, message):
    with pytest.raises(ValueError, match=message) as e:
        depth_from_focus(stack, focus, model)
    assert "\n" not in str(e.value)


def test_unknown_model_names_the_shipped_ones():
    with pytest.raises(ValueError, match="rf50_dfvnet_aat_field"):
        load_model("no_such_model")
