"""aat-eval end to end: virtual captures whose ground truth is a known perturbation of the model's own prediction
give the hand-computed metrics; --align recovers the perturbation; --compare puts models in one table; bad
ground truth fails its capture on one line and the batch goes on; the shipped sample agrees with aat-infer."""

from __future__ import annotations

import csv
import json
import math
import shutil

import cv2
import numpy as np
import pytest
from conftest import ROOT
from deploy_fixtures import (
    build_tiny_dff,
    run_without_torch,
    write_dng_capture,
    write_pfm,
    write_png_capture,
)

from aat_deploy.cli import eval as eval_cli
from aat_deploy.eval.score import aif_pair, fit_alignment
from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.pipeline import Options, run_capture

FOCUS = [0.6, 0.8, 1.2, 2.0, 3.0, 4.5]


@pytest.fixture(scope="module")
def base(tmp_path_factory, model_path):
    """A DNG capture without ground truth and the tiny model's prediction P (48, 64) on it."""
    d = tmp_path_factory.mktemp("eval")
    cap = write_dng_capture(d / "frames", FOCUS, gt=False)
    run_capture(cap, DfFModel(model_path, threads=1), d / "pred", Options(quiet=True, record=False))
    return cap, np.load(d / "pred" / "depth_m.npy").astype(np.float64)


def _copy_frames(src, dst):
    shutil.copytree(src, dst)
    return dst


def _eval(args, capsys=None):
    rc = eval_cli.main([str(a) for a in args] + ["--threads", "1", "-q"])
    return rc, (capsys.readouterr() if capsys else None)


def _rows(out):
    rep = json.loads((out / "metrics.json").read_text())
    return rep, {(r["capture"], r["model"]): r for r in rep["per_capture"]}


def test_known_perturbations_give_hand_computed_metrics(base, model_path, tmp_path, capsys):
    frames, p = base
    root = tmp_path / "root"
    a = _copy_frames(frames, root / "a")
    np.save(a / "gt_depth_m.npy", (1.1 * p).astype(np.float32))  # every pixel 10 % further than predicted
    b = _copy_frames(frames, root / "sub" / "b")
    write_pfm(b / "gt_lidar_mm.pfm", ((p + 0.2) * 1000).astype(np.float32))  # 0.2 m further, in mm
    (b / "gt.json").write_text(json.dumps({"depth": "gt_lidar_mm.pfm", "scale_to_m": 0.001}))
    mask = np.zeros(p.shape, np.uint8)
    mask[:, 32:] = 255
    cv2.imwrite(str(b / "gt_mask.png"), mask)
    _copy_frames(frames, root / "c")  # frames without ground truth: skipped
    out = tmp_path / "out"
    rc, _ = _eval([root, "--model", model_path, "--out", out], capsys)
    assert rc == 0
    rep, rows = _rows(out)
    label = model_path.stem
    ra, rb = rows[("a", label)], rows[("sub__b", label)]
    g = 1.1 * p
    assert ra["n_valid"] == p.size
    assert ra["mae"] == pytest.approx(0.1 * p.mean(), rel=1e-5)
    assert ra["rmse"] == pytest.approx(0.1 * math.sqrt((p * p).mean()), rel=1e-5)
    assert ra["abs_rel"] == pytest.approx(0.1 / 1.1, rel=1e-5)
    assert ra["sq_rel"] == pytest.approx(((0.1 * p) ** 2 / g).mean(), rel=1e-5)
    assert ra["rmse_log"] == pytest.approx(math.log(1.1), rel=1e-4)
    assert ra["delta1"] == 1.0 and ra["align_scale"] is None
    assert rb["n_valid"] == p.size // 2
    assert rb["mae"] == pytest.approx(0.2, rel=1e-4) and rb["rmse"] == pytest.approx(0.2, rel=1e-4)
    assert rb["abs_rel"] == pytest.approx((0.2 / (p[:, 32:] + 0.2)).mean(), rel=1e-4)
    assert rep["overall"][label]["mae"] == pytest.approx((ra["mae"] + rb["mae"]) / 2)
    assert rep["overall"][label]["n_images"] == 2 and rep["overall_captures"] == ["a", "sub__b"]
    assert rep["skipped_without_gt"] == [str(root / "c")]
    assert rep["captures"][1]["gt"] == {"depth": "gt_lidar_mm.pfm", "scale_to_m": 0.001, "mask": "gt_mask.png",
                                        "aif": None}
    # the error maps hold pred − GT where the GT is valid
    err = np.load(out / "runs" / label / "sub__b" / "error_m.npy")
    # float32 GT of up to 4.7 m (in mm, then scaled): rounding ~1e-7 of the depths, not of the 0.2 m error
    assert np.isnan(err[:, :32]).all() and np.allclose(err[:, 32:], -0.2, rtol=0, atol=1e-5 * p.max())
    # tables and pictures
    with open(out / "metrics.csv") as f:
        lines = list(csv.DictReader(f))
    assert [(ln["capture"], ln["status"]) for ln in lines] == [("a", "ok"), ("sub__b", "ok"), ("ALL", "mean")]
    assert float(lines[0]["abs_rel"]) == pytest.approx(0.1 / 1.1, rel=1e-4)
    md = (out / "metrics.md").read_text()
    assert "| model | captures | MAE m |" in md and f"| sub__b | {label} | {p.size // 2} |" in md
    for png in ("error_vs_radius.png", "error_vs_depth.png", "maps/a.png", f"maps/{label}/a_abs_error.png",
                f"maps/{label}/mean_abs_error.png"):
        img = cv2.imread(str(out / png))
        assert img is not None and img.size > 0, png
    assert sum(rep["profiles"][label]["field_radius"]["count"]) == p.size + p.size // 2
    assert sum(rep["profiles"][label]["depth"]["count"]) == p.size + p.size // 2
    assert not list(tmp_path.glob(".out.tmp-*"))


def test_recording_has_gt_prediction_and_error(base, model_path, tmp_path):
    from rerun.chunk import RrdReader

    frames, p = base
    root = tmp_path / "root"
    np.save(_copy_frames(frames, root / "a") / "gt_depth_m.npy", (p + 0.1).astype(np.float32))
    out = tmp_path / "out"
    assert _eval([root, "--model", model_path, "--out", out])[0] == 0
    label = model_path.stem
    entities = {str(c.entity_path): c.to_record_batch()
                for c in RrdReader(out / "eval.rrd").stream().collect().stream()}
    for part in ("gt", "depth", "abs_error"):
        assert f"/models/{label}/{part}" in entities
    depth = entities[f"/models/{label}/depth"]
    assert "capture" in depth.schema.names and depth.column("capture").to_pylist() == [0]
    buf = np.frombuffer(bytes(depth.column("DepthImage:buffer").to_pylist()[0][0]), np.float32)
    np.testing.assert_allclose(buf.reshape(p.shape), p, rtol=1e-6)
    mae = entities[f"/metrics/{label}/mae_m"].column("Scalars:scalars").to_pylist()[0][0]
    assert mae == pytest.approx(0.1, rel=1e-4)


@pytest.mark.parametrize("mode, gt_of, scale, shift", [
    ("scale-shift", lambda p: 1.1 * p + 0.05, 1.1, 0.05),
    ("scale", lambda p: 1.3 * p, 1.3, 0.0),
    ("median", lambda p: 0.8 * p, 0.8, 0.0),
])
def test_align_recovers_and_reports_the_fit(base, model_path, tmp_path, mode, gt_of, scale, shift):
    frames, p = base
    root = tmp_path / "root"
    np.save(_copy_frames(frames, root / "a") / "gt_depth_m.npy", gt_of(p).astype(np.float32))
    out = tmp_path / "out"
    assert _eval([root, "--model", model_path, "--out", out, "--align", mode])[0] == 0
    rep, rows = _rows(out)
    r = rows[("a", model_path.stem)]
    # float32 GT: the fit recovers the perturbation to ~1e-7 of the depths (the shift, in m, may be 0)
    assert r["align_scale"] == pytest.approx(scale, rel=1e-4)
    assert r["align_shift"] == pytest.approx(shift, abs=2e-5 * p.max())
    assert r["mae"] < 2e-5 * p.max() and rep["options"]["align"] == mode
    assert "scale s" in (out / "metrics.md").read_text()


def test_compare_scores_models_on_the_same_captures(base, model_path, tmp_path, capsys):
    frames, p = base
    other = build_tiny_dff(tmp_path / "soft_dff.onnx", sharpness=1.0)
    root = tmp_path / "root"
    for name in ("a", "b"):
        np.save(_copy_frames(frames, root / name) / "gt_depth_m.npy", (p + 0.1).astype(np.float32))
    out = tmp_path / "out"
    rc, io = _eval([root, "--model", model_path, "--compare", other, "--out", out], capsys)
    assert rc == 0
    rep, rows = _rows(out)
    labels = [m["label"] for m in rep["models"]]
    assert labels == [model_path.stem, "soft_dff"]
    assert set(rows) == {(c, lb) for c in ("a", "b") for lb in labels}
    assert rows[("a", "soft_dff")]["mae"] != pytest.approx(rows[("a", model_path.stem)]["mae"])
    md = (out / "metrics.md").read_text()
    assert f"| {model_path.stem} | 2 |" in md and "| soft_dff | 2 |" in md
    assert f"{model_path.stem}: 2 capture(s)" in io.out and "soft_dff: 2 capture(s)" in io.out


def test_cropped_frames_bring_their_ground_truth_along(model_path, tmp_path):
    """PNG frames 96x64 (3:2) on the 64x48 (4:3) sensor: the columns the crop drops hold 999 m in the GT;
    none of it may reach the scores."""
    root = tmp_path / "root"
    cap = write_png_capture(root / "wide", FOCUS, h=64, w=96)
    gt = np.full((64, 96), 2.0, np.float32)
    gt[:, :5] = gt[:, -5:] = 999.0  # the crop keeps columns 5..90 (85.33 px wide)
    np.save(cap / "gt_depth_m.npy", gt)
    out = tmp_path / "out"
    assert _eval([root, "--model", model_path, "--out", out])[0] == 0
    label = model_path.stem
    pred = np.load(out / "runs" / label / "wide" / "depth_m.npy")
    gts = np.load(out / "runs" / label / "wide" / "gt_sensor_m.npy")
    assert gts.shape == (48, 64) and (gts == 2.0).all()
    _, rows = _rows(out)
    assert rows[("wide", label)]["mae"] == pytest.approx(np.abs(pred - 2.0).mean(), rel=1e-5)


def test_bad_ground_truth_fails_its_capture_and_the_batch_goes_on(base, model_path, tmp_path, capsys):
    frames, p = base
    root = tmp_path / "root"
    np.save(_copy_frames(frames, root / "good") / "gt_depth_m.npy", (p + 0.1).astype(np.float32))
    np.save(_copy_frames(frames, root / "mm") / "gt_depth_m.npy", (p * 1000).astype(np.float32))
    np.save(_copy_frames(frames, root / "narrow") / "gt_depth_m.npy", p[:, :40].astype(np.float32))
    np.save(_copy_frames(frames, root / "empty") / "gt_depth_m.npy", np.zeros_like(p, np.float32))
    out = tmp_path / "out"
    rc, io = _eval([root, "--model", model_path, "--out", out], capsys)
    assert rc == 1
    failed = [ln for ln in io.err.splitlines() if "FAILED" in ln]
    assert len(failed) == 3
    by_cap = {ln.split()[2]: ln for ln in failed}
    assert str(root / "mm" / "gt_depth_m.npy") in by_cap["mm"] and "wrong units" in by_cap["mm"]
    assert str(root / "narrow" / "gt_depth_m.npy") in by_cap["narrow"] and "aspect" in by_cap["narrow"]
    assert str(root / "empty" / "gt_depth_m.npy") in by_cap["empty"] and "no valid" in by_cap["empty"]
    rep, rows = _rows(out)
    assert rows[("good", model_path.stem)]["status"] == "ok" and len(rep["failed"]) == 3
    assert rep["overall_captures"] == ["good"]
    assert "## Failed" in (out / "metrics.md").read_text()
    # the output folder is kept unless --force
    rc, io = _eval([root / "good", "--model", model_path, "--out", out], capsys)
    assert rc == 2 and "exists" in io.err
    rc, _ = _eval([root / "good", "--model", model_path, "--out", out, "--force"], capsys)
    assert rc == 0 and _rows(out)[0]["failed"] == []


def test_no_ground_truth_anywhere_is_an_error(base, model_path, tmp_path, capsys):
    frames, _ = base
    _copy_frames(frames, tmp_path / "root" / "a")
    rc, io = _eval([tmp_path / "root", "--model", model_path, "--out", tmp_path / "out"], capsys)
    assert rc == 2 and "no capture folder with ground truth" in io.err
    assert not (tmp_path / "out").exists()


def test_fit_alignment_and_aif_pair_units():
    rng = np.random.default_rng(0)
    p = rng.uniform(0.5, 5, (20, 30))
    g = 2.0 * p - 0.3
    g[0, 0] = np.nan
    assert fit_alignment(p, g, "scale-shift") == pytest.approx((2.0, -0.3))
    ref = rng.uniform(0.02, 0.9, (16, 16, 3)).astype(np.float32)
    from aat_deploy.io.color import linear_to_srgb

    half = np.rint(linear_to_srgb(ref * 0.5) * 255).astype(np.uint8)  # the same picture, one stop darker
    p8, r8, gain = aif_pair(half, ref)
    assert gain == pytest.approx(2.0, rel=0.02) and p8.shape == r8.shape == (3, 16, 16)
    assert np.abs(p8.astype(int) - r8.astype(int)).max() <= 3


def test_shipped_sample_agrees_with_aat_infer(tmp_path):
    """captures/sample_rf50 (virtual camera, GT beside it) with the shipped AAT model: aat-eval's scores equal the
    ground-truth error aat-infer writes into summary.json (separate code), and the AiF is scored."""
    out = tmp_path / "out"
    model = ROOT / "models" / "reproduce" / "dff_dfvnet_aat.onnx"
    rc, _ = _eval([ROOT / "captures" / "sample_rf50", "--model", model, "--out", out, "--no-recording",
                   "--no-panels"])
    assert rc == 0
    _, rows = _rows(out)
    r = rows[("sample_rf50", "dff_dfvnet_aat")]
    infer = json.loads((out / "runs" / "dff_dfvnet_aat" / "sample_rf50" / "summary.json").read_text())
    assert r["mae"] == pytest.approx(infer["ground_truth"]["mae_m"], rel=1e-5)
    assert r["rmse"] == pytest.approx(infer["ground_truth"]["rmse_m"], rel=1e-5)
    assert r["abs_rel"] == pytest.approx(infer["ground_truth"]["abs_rel"], rel=1e-5)
    assert r["n_valid"] == infer["ground_truth"]["pixels"] == 960 * 640
    assert 15 < r["psnr"] < 60 and 0.3 < r["ssim"] <= 1


def test_eval_and_gt_render_run_without_torch(base, model_path, tmp_path):
    """aat-eval and aat-gt run in an interpreter where `import torch` fails (the runtime never needs it)."""
    pytest.importorskip("trimesh")

    frames, p = base
    root = tmp_path / "root"
    np.save(_copy_frames(frames, root / "a") / "gt_depth_m.npy", (p + 0.1).astype(np.float32))
    (tmp_path / "plane.obj").write_text("v -9 -9 2\nv 9 -9 2\nv 9 9 2\nv -9 9 2\nf 1 2 3\nf 1 3 4\n")
    (tmp_path / "pose.json").write_text(json.dumps({"R": np.eye(3).tolist(), "t": [0, 0, 0]}))
    r = run_without_torch(f"""
        import json, sys
        from aat_deploy.cli import eval as ev, gt
        assert ev.main([{str(root)!r}, "--model", {str(model_path)!r}, "--out", "out", "--threads", "1", "-q"]) == 0
        assert gt.main(["render", "plane.obj", "--pose", "pose.json", "--lens", {str(model_path)!r}, "--out",
                        "gt", "--pupil-to-sensor-mm", "40", "-q"]) == 0
        print(json.dumps({{"torch_loaded": any(k == "torch" or k.startswith("torch.") for k in sys.modules)}}))
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(r.stdout.strip().splitlines()[-1]) == {"torch_loaded": False}
    # aat-gt's promised accuracy, 1 mm (a length by design; Embree's float32 rounding is ~1e-7 of the depth)
    assert np.allclose(np.load(tmp_path / "gt" / "gt_depth_m.npy"), 2.04, rtol=0, atol=1e-3)
    assert (tmp_path / "out" / "metrics.md").is_file()
