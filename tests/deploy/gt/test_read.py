"""Ground truth for aat-eval: formats (npy, PFM, TIFF, mm PNG, gt.json scale, mask), checks with one-line
errors naming the file (all invalid, wrong units, wrong aspect), and resampling to the sensor like the frames."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from deploy_fixtures import tiny_model_path, write_pfm

from aat_deploy.cli import gt as gt_cli
from aat_deploy.gt.read import (
    GTError,
    check_units,
    find_gt,
    load_ground_truth,
    to_sensor,
)
from aat_deploy.infer.geometry import fit_to_sensor

RNG = np.random.default_rng(3)
DEPTH = RNG.uniform(0.7, 4.0, (48, 64)).astype(np.float32)


def _load(folder):
    src = find_gt(folder)
    assert src is not None
    return load_ground_truth(src)


@pytest.mark.parametrize("kind", ["npy", "pfm", "tif", "png", "json_mm_tif"])
def test_formats_read_to_metres(tmp_path, kind):
    d = DEPTH.copy()
    d[0, 0] = 0.0
    d[1, 1] = np.nan
    if kind == "npy":
        np.save(tmp_path / "gt_depth_m.npy", d)
    elif kind == "pfm":
        write_pfm(tmp_path / "gt_depth_m.pfm", d)
    elif kind == "tif":
        assert cv2.imwrite(str(tmp_path / "gt_depth_m.tif"), d)
    elif kind == "png":
        d = np.rint(np.nan_to_num(d) * 1000) / 1000
        cv2.imwrite(str(tmp_path / "gt_depth_mm.png"), np.rint(d * 1000).astype(np.uint16))
    else:
        assert cv2.imwrite(str(tmp_path / "gt_lidar.tif"), d * 1000)
        (tmp_path / "gt.json").write_text(json.dumps({"depth": "gt_lidar.tif", "scale_to_m": 0.001}))
    gt = _load(tmp_path)
    assert gt.depth_m.dtype == np.float32 and gt.depth_m.shape == (48, 64)
    assert np.isnan(gt.depth_m[0, 0]) and np.isnan(gt.depth_m[1, 1])
    ok = np.isfinite(d) & (d > 0)
    # float32 in m or mm, scaled by 0.001: a few float32 roundings (6e-8 each) of the depth
    assert np.allclose(gt.depth_m[ok], d[ok], rtol=1e-6, atol=0)


def test_mask_and_precedence(tmp_path):
    np.save(tmp_path / "gt_depth_m.npy", DEPTH)
    cv2.imwrite(str(tmp_path / "gt_depth_mm.png"), np.full((48, 64), 9999, np.uint16))
    mask = np.zeros((48, 64), np.uint8)
    mask[:, 32:] = 255
    cv2.imwrite(str(tmp_path / "gt_mask.png"), mask)
    gt = _load(tmp_path)
    assert gt.source.depth.name == "gt_depth_m.npy" and gt.source.mask.name == "gt_mask.png"
    assert np.isnan(gt.depth_m[:, :32]).all() and np.allclose(gt.depth_m[:, 32:], DEPTH[:, 32:])


def _one_line_error(folder, match, focus_range=None):
    with pytest.raises(GTError, match=match) as e:
        gt = _load(folder)
        if focus_range:
            check_units(gt, focus_range)
    msg = str(e.value)
    assert "\n" not in msg
    return msg


def test_all_invalid_is_an_error(tmp_path):
    d = np.zeros((48, 64), np.float32)
    d[0, :5] = np.nan
    np.save(tmp_path / "gt_depth_m.npy", d)
    msg = _one_line_error(tmp_path, "no valid ground-truth pixel")
    assert "gt_depth_m.npy" in msg


def test_masked_out_entirely_is_an_error(tmp_path):
    np.save(tmp_path / "gt_depth_m.npy", DEPTH)
    cv2.imwrite(str(tmp_path / "gt_mask.png"), np.zeros((48, 64), np.uint8))
    assert "masked out by gt_mask.png" in _one_line_error(tmp_path, "no valid")


def test_millimetres_in_a_metres_file_is_an_error(tmp_path):
    np.save(tmp_path / "gt_depth_m.npy", DEPTH * 1000)
    msg = _one_line_error(tmp_path, "wrong units", focus_range=(0.5, 10.0))
    assert "gt_depth_m.npy" in msg and "millimetres" in msg and '"scale_to_m": 0.001' in msg


def test_metres_in_a_millimetre_png_is_an_error(tmp_path):
    cv2.imwrite(str(tmp_path / "gt_depth_mm.png"), np.rint(DEPTH).astype(np.uint16))
    msg = _one_line_error(tmp_path, "wrong units", focus_range=(0.5, 10.0))
    assert "gt_depth_mm.png" in msg


def test_bad_files_name_themselves(tmp_path):
    (tmp_path / "gt_depth_m.npy").write_bytes(b"not numpy")
    assert "gt_depth_m.npy" in _one_line_error(tmp_path, "unreadable")
    (tmp_path / "gt_depth_m.npy").unlink()
    cv2.imwrite(str(tmp_path / "gt_depth_mm.png"), np.zeros((48, 64, 3), np.uint8))
    assert "16-bit" in _one_line_error(tmp_path, "gt_depth_mm.png")
    (tmp_path / "gt.json").write_text(json.dumps({"depth": "scan.tif"}))
    assert "gt.json" in _one_line_error(tmp_path, "does not exist")
    (tmp_path / "gt.json").write_text(json.dumps({"scale_to_m": -1}))
    _one_line_error(tmp_path, "scale_to_m must be a positive number")
    cv2.imwrite(str(tmp_path / "scan.tif"), DEPTH)
    (tmp_path / "gt.json").write_text(json.dumps({"depth": "scan.tif"}))
    _one_line_error(tmp_path, "name the depth file gt_")


def test_wrong_aspect_is_an_error_naming_the_file():
    with pytest.raises(GTError, match="different aspect ratio") as e:
        to_sensor(DEPTH[:, :48], (64, 48), (0, 0, 64, 48), (64, 48), "cap/gt_depth_m.npy")
    assert str(e.value).startswith("cap/gt_depth_m.npy:")


def test_resampling_follows_the_frames_and_never_blends():
    """Frames 120x60 (2:1) onto a 48x32 (3:2) sensor: centre crop 90x60, then 0.533x. A ground truth holding each
    frame pixel's x (and y) centre, at the frames' size and at twice it, lands within half a frame pixel of where
    fit_to_sensor's area average puts each output pixel, and every value is one of the inputs."""
    fw, fh, size = 120, 60, (48, 32)
    xs = np.broadcast_to(np.arange(fw) + 0.5, (fh, fw)).astype(np.float32)
    ys = np.broadcast_to((np.arange(fh) + 0.5)[:, None], (fh, fw)).astype(np.float32)
    frame = np.stack([xs, ys, xs], -1)
    fitted, geo = fit_to_sensor(frame, size)
    assert geo["crop_xywh"] == [15, 0, 90, 60]
    for k in (1, 2):  # ground truth at the frames' resolution and at twice it (same field of view)
        gx = np.broadcast_to((np.arange(fw * k) + 0.5) / k, (fh * k, fw * k))
        gy = np.broadcast_to(((np.arange(fh * k) + 0.5) / k)[:, None], (fh * k, fw * k))
        sx = to_sensor(gx, (fw, fh), tuple(geo["crop_xywh"]), size)
        sy = to_sensor(gy, (fw, fh), tuple(geo["crop_xywh"]), size)
        assert sx.shape == (32, 48)
        slack = 1e-6 * fw  # float32 area averages of coordinates up to fw px: a few ulps of fw
        assert np.abs(sx - fitted[..., 0]).max() <= 0.5 + slack
        assert np.abs(sy - fitted[..., 1]).max() <= 0.5 + slack
        assert np.isin(sx, gx).all()
    same = to_sensor(DEPTH, (64, 48), (0, 0, 64, 48), (64, 48))
    assert np.array_equal(same, DEPTH)


def test_gt_check_cli(tmp_path, tmp_path_factory, capsys):
    good, bad = tmp_path / "good", tmp_path / "bad"
    good.mkdir()
    bad.mkdir()
    np.save(good / "gt_depth_m.npy", DEPTH)
    np.save(bad / "gt_depth_m.npy", DEPTH * 1000)
    assert gt_cli.main(["check", str(good), str(bad)]) == 0  # without a model the units are not checked
    assert "64x48 px" in capsys.readouterr().out
    model = tiny_model_path(tmp_path_factory)
    assert gt_cli.main(["check", str(good), str(bad), "--model", str(model)]) == 1
    out = capsys.readouterr()
    err = [ln for ln in out.err.splitlines() if ln.startswith("aat-gt: error")]
    assert len(err) == 1 and str(bad / "gt_depth_m.npy") in err[0] and "wrong units" in err[0]
