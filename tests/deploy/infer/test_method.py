"""The one depth-method interface (aat_deploy.infer.method): the classical method, the lens-specific ONNX models and
the any-camera model implement it; the runtime asks nothing else of them; the Python API runs the classical method
and returns its confidence; the array functions have distinct names."""

from __future__ import annotations

import ast
import warnings

import numpy as np
import pytest
from conftest import ROOT
from deploy_fixtures import render_stack, synthetic_scene, write_dng_capture

from aat_deploy.anycam.model import FocusMapModel
from aat_deploy.api import depth_from_focus, read_stack
from aat_deploy.focus import FocusConfig, classical_depth
from aat_deploy.focus.runner import FocusMethod
from aat_deploy.infer.method import DepthMethod, DepthOutput
from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.pipeline import Options, run_capture
from aat_deploy.infer.process import depth_from_frames
from aat_deploy.optics.camera import Intrinsics

FOCUS = [0.6, 0.8, 1.2, 2.0, 3.0, 4.5]


def test_every_estimator_is_a_depth_method():
    for cls in (FocusMethod, DfFModel, FocusMapModel):
        assert issubclass(cls, DepthMethod), cls
    assert FocusMethod.places_tied_frames and not DfFModel.places_tied_frames
    assert FocusMethod.noun == "method" and DfFModel.noun == "model"


def test_the_runtime_asks_no_kind_and_probes_no_attribute():
    """Where a depth method is driven (pipeline, process, api), no `.kind` comparison, hasattr or getattr on it."""
    for rel in ("aat_deploy/infer/pipeline.py", "aat_deploy/infer/process.py", "aat_deploy/api.py"):
        tree = ast.parse((ROOT / rel).read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("hasattr",
                                                                                                    "getattr"):
                arg = node.args[0]
                assert not (isinstance(arg, ast.Name) and arg.id in ("model", "net", "res")), \
                    f"{rel}:{node.lineno}: {node.func.id}({arg.id}, ...)"
            if isinstance(node, ast.Attribute) and node.attr == "kind" and isinstance(node.value, ast.Name):
                assert node.value.id not in ("model", "net"), f"{rel}:{node.lineno}: {node.value.id}.kind"


class _Flat(DepthMethod):
    """A toy method (what a new estimator writes): depth is the stack's middle focus distance everywhere."""

    stack_range = (2, 16)
    focus_range_m = (0.1, 100.0)

    def working_size(self, frame_hw):
        return frame_hw[1] // 2, frame_hw[0] // 2

    def infer(self, stack, focus_m, tile=None, progress=None):
        _, _, h, w = stack.shape
        d = np.full((h, w), float(np.median(focus_m)), np.float32)
        return DepthOutput(d, stack.mean(0), np.zeros_like(d), np.full_like(d, 0.5), ["flat"], {"toy": True})

    def intrinsics(self, size_wh):
        w, h = size_wh
        return Intrinsics(w, h, float(w), float(w), (w - 1) / 2, (h - 1) / 2, 0.0, "toy", [])

    def summary(self):
        return {"method": "flat"}


def test_a_new_method_runs_through_the_runtime_and_the_api(tmp_path):
    frames = [np.random.default_rng(i).random((40, 60, 3), dtype=np.float32) for i in range(4)]
    res = depth_from_frames(frames, np.array([0.5, 1.0, 2.0, 4.0], np.float32), _Flat())
    assert res.maps.depth_m.shape == (20, 30) and np.all(res.maps.depth_m == 1.5)
    assert res.warnings == ["flat"] and res.info == {"toy": True} and np.all(res.maps.confidence == 0.5)
    api = depth_from_focus(np.stack(frames), [0.5, 1.0, 2.0, 4.0], _Flat())
    assert api.model == {"method": "flat"} and api.confidence.shape == (20, 30)
    with pytest.raises(ValueError, match="lens"):  # a method that takes no lens says so in one line
        depth_from_focus(np.stack(frames), [0.5, 1.0, 2.0, 4.0], _Flat(), lens="lenses/canon_rf50mm_f1.8.json")


def test_api_runs_the_classical_method_with_its_confidence(tmp_path):
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    s = run_capture(cap, FocusMethod(), tmp_path / "out", Options(quiet=True, record=False))
    stack, focus = read_stack(cap)
    res = depth_from_focus(stack, focus, method="focus")
    np.testing.assert_array_equal(res.depth_m, np.load(tmp_path / "out" / "depth_m.npy"))
    assert res.confidence is not None and res.confidence.shape == res.depth_m.shape
    assert np.all((res.confidence >= 0) & (res.confidence <= 1)) and res.model["method"] == "focus"
    assert s["model"]["method"] == "focus"
    with pytest.warns(DeprecationWarning, match='method="focus"'):  # the older spelling still works
        old = depth_from_focus(stack, focus, "focus")
    np.testing.assert_array_equal(old.depth_m, res.depth_m)
    with pytest.raises(ValueError, match="method"):
        depth_from_focus(stack, focus, method="magic")
    with pytest.raises(ValueError, match="camera"):
        depth_from_focus(stack, focus, method="focus", camera=(50, 1.8, 4.3))


def test_lens_specific_model_refuses_a_camera_in_one_line(model_path):
    tex, depth = synthetic_scene(48, 64)
    with pytest.raises(ValueError, match="is a lens-specific model") as e:
        depth_from_focus(render_stack(tex, depth, FOCUS), FOCUS, DfFModel(model_path, threads=1),
                         camera=(50, 1.8, 4.3))
    assert "\n" not in str(e.value)


def test_the_array_functions_have_distinct_names_and_the_old_one_warns():
    rng = np.random.default_rng(0)
    stack = rng.random((4, 3, 32, 32), dtype=np.float32)
    focus = np.array([0.5, 1.0, 2.0, 4.0])
    new = classical_depth(stack, focus, config=FocusConfig(fill="none"))
    from aat_deploy import focus as focus_pkg

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        old = focus_pkg.depth_from_focus(stack, focus, config=FocusConfig(fill="none"))
    assert any(issubclass(x.category, DeprecationWarning) and "classical_depth" in str(x.message) for x in w)
    np.testing.assert_array_equal(new.depth_m, old.depth_m)
