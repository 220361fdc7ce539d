"""aat-infer's per-capture run: ground truth in every form gt/read reads reaches its summary, and the maps it
returns (what aat-eval scores in memory) are the files it wrote."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from deploy_fixtures import write_dng_capture

from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.outputs import to_srgb8
from aat_deploy.infer.pipeline import Options, infer_capture, run_capture
from aat_deploy.io.images import imread

FOCUS = [0.6, 0.8, 1.2, 2.0, 3.0, 4.5]


@pytest.fixture(scope="module")
def model(model_path):
    return DfFModel(model_path, threads=1)


@pytest.mark.parametrize("form", ["gt.json", "pfm_default", "tif_default", "mm_png"])
def test_every_ground_truth_form_reaches_the_summary(form, model, tmp_path):
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    reference = run_capture(cap, model, tmp_path / "ref", Options(quiet=True, record=False))["ground_truth"]
    gt = np.load(cap / "gt_depth_m.npy")
    (cap / "gt_depth_m.npy").unlink()
    if form == "gt.json":  # before: aat-infer ignored it (only .npy and mm .png were read)
        np.save(cap / "scan_cm.npy", gt * 100)
        (cap / "gt.json").write_text(json.dumps({"depth": "scan_cm.npy", "scale_to_m": 0.01}))
    elif form == "pfm_default":
        from aat_deploy.gt.read import read_pfm

        h, w = gt.shape
        (cap / "gt_depth_m.pfm").write_bytes(f"Pf\n{w} {h}\n-1.0\n".encode() + gt[::-1].astype("<f4").tobytes())
        assert np.array_equal(read_pfm(cap / "gt_depth_m.pfm"), gt)
    elif form == "tif_default":
        cv2.imwrite(str(cap / "gt_depth_m.tif"), gt.astype(np.float32))
    else:
        cv2.imwrite(str(cap / "gt_depth_mm.png"), np.rint(gt * 1000).astype(np.uint16))
    s = run_capture(cap, model, tmp_path / "o", Options(quiet=True, record=False))
    assert s["ground_truth"] is not None and s["ground_truth"]["pixels"] == reference["pixels"] == 48 * 64, s
    tol = 1e-3 if form == "mm_png" else 1e-6  # mm steps
    assert s["ground_truth"]["mae_m"] == pytest.approx(reference["mae_m"], abs=tol)


def test_unusable_ground_truth_is_a_warning_not_a_failure(model, tmp_path):
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    (cap / "gt_depth_m.npy").unlink()
    (cap / "gt.json").write_text("{not json")
    run = infer_capture(cap, model, tmp_path / "o", Options(quiet=True, record=False))
    assert run.ground_truth is None and run.summary["ground_truth"] is None
    assert len(run.ground_truth_warnings) == 1 and "gt.json" in run.ground_truth_warnings[0]
    assert run.ground_truth_warnings[0] in run.summary["warnings"]


def test_returned_maps_are_the_written_files(model, tmp_path):
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    run = infer_capture(cap, model, tmp_path / "o", Options(quiet=True, record=False))
    np.testing.assert_array_equal(run.maps.depth_m, np.load(tmp_path / "o" / "depth_m.npy"))
    np.testing.assert_array_equal(to_srgb8(run.maps.aif),
                                  imread(tmp_path / "o" / "aif.png", cv2.IMREAD_COLOR)[..., ::-1])
    assert run.ground_truth is not None and run.ground_truth.shape == run.working.depth_m.shape
    assert json.loads((tmp_path / "o" / "summary.json").read_text()) == json.loads(json.dumps(run.summary))
