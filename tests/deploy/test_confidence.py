"""Calibrated confidence (aat_deploy/confidence.py): the isotonic fit and the reliability table on hand-computed
cases, the calibration file's reader, unknown depth in the outputs (NaN, grey, not in the PLY, its share in
summary.json), and the focus method's use of a calibration (own vs filled pixels)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from deploy_fixtures import write_dng_capture

from aat_deploy import confidence as cf
from aat_deploy.focus import FocusConfig, classical_depth


def test_pool_adjacent_violators_by_hand():
    assert cf.pool_adjacent_violators(np.array([1.0, 3, 2, 4]), np.ones(4)).tolist() == [1, 2.5, 2.5, 4]
    # weights: (3 * 1 + 1 * 3) / 4 = 1.5 for both
    assert cf.pool_adjacent_violators(np.array([3.0, 1]), np.array([1.0, 3])).tolist() == [1.5, 1.5]
    # a violation that reaches back two blocks: 5, (4, 3) -> 3.5 < 5 -> (5, 4, 3) = 4
    assert cf.pool_adjacent_violators(np.array([5.0, 4, 3, 6]), np.ones(4)).tolist() == [4, 4, 4, 6]


def test_fit_curve_recovers_a_known_probability():
    rng = np.random.default_rng(0)
    s = rng.random(200_000)
    correct = rng.random(s.size) < s ** 2  # P(correct | s) = s^2
    c = cf.fit_curve(s, correct, increasing=True)
    grid = np.linspace(0.05, 0.95, 19)
    assert np.abs(c(grid) - grid ** 2).max() < 0.03
    assert np.all(np.diff(c.p) >= 0)
    # a decreasing relation (a model's relative std): P = exp(-s)
    r = rng.random(200_000) * 2
    d = cf.fit_curve(r, rng.random(r.size) < np.exp(-r), increasing=False)
    assert np.all(np.diff(d.p) <= 0) and abs(float(d(np.array(1.0))) - np.exp(-1)) < 0.03
    # calibrated on itself: reliability near perfect
    assert cf.reliability(c(s), correct)["ece"] < 0.01


def test_reliability_by_hand():
    conf = np.array([0.15] * 10 + [0.85] * 10)
    ok = np.array([1] * 2 + [0] * 8 + [1] * 6 + [0] * 4, bool)
    rel = cf.reliability(conf, ok)
    assert [r["observed"] for r in rel["bins"]] == pytest.approx([0.2, 0.6])
    assert rel["ece"] == pytest.approx((10 * 0.05 + 10 * 0.25) / 20)


def test_calibration_file_round_trip_and_errors(tmp_path):
    cal = cf.Calibration({"estimate": cf.Curve([0.0, 0.5, 1.0], [0.1, 0.4, 0.9], 100)})
    p = cal.save(tmp_path / "c.json")
    back = cf.load(p)
    assert back["estimate"](np.array([0.25, 2.0])).tolist() == pytest.approx([0.25, 0.9])
    assert back.tolerance_rel == cf.TOLERANCE_REL
    bad = tmp_path / "bad.json"
    for text in ("{", json.dumps({"format": "x"}), json.dumps({**cal.to_dict(), "curves": {"e": {"x": [0, 1]}}}),
                 json.dumps({**cal.to_dict(), "curves": {"e": {"x": [1, 0], "p": [0.1, 0.2]}}}),
                 json.dumps({**cal.to_dict(), "curves": {"e": {"x": [0, 1], "p": [0.1, 1.2]}}})):
        bad.write_text(text)
        with pytest.raises(cf.ConfidenceCalibrationError) as e:
            cf.load(bad)
        assert str(bad) in str(e.value) and "\n" not in str(e.value)


def test_mark_unknown():
    d = np.array([[1.0, 2.0], [3.0, np.nan]], np.float32)
    c = np.array([[0.9, 0.4], [np.nan, 0.9]], np.float32)
    out, info = cf.mark_unknown(d, c, 0.5)
    assert np.isfinite(out).tolist() == [[True, False], [False, False]]
    assert info["unknown_share"] == 0.75 and info["below_threshold_share"] == 0.5
    out, info = cf.mark_unknown(d, None, 0.5)
    assert np.array_equal(out, d, equal_nan=True) and info["unknown_share"] == 0.25
    out, _ = cf.mark_unknown(d, c, 0.0)
    assert np.isfinite(out).sum() == 2  # a NaN confidence is never known


def test_std_confidence_maps_relative_std():
    cal = cf.Calibration({"relative_std": cf.Curve([0.0, 0.1, 0.5], [0.9, 0.5, 0.1])})
    d = np.array([2.0, 2.0, 0.0], np.float32)
    s = np.array([0.0, 0.2, 0.1], np.float32)
    assert cf.std_confidence(cal, d, s).tolist() == pytest.approx([0.9, 0.5, 0.0])


def _slanted_stack(h=64, w=96, s=7):
    """A textured plane whose depth runs left to right, rendered by Gaussian blur growing with defocus, and a
    textureless band at the top (no depth can be known there)."""
    import cv2

    rng = np.random.default_rng(0)
    tex = rng.random((h, w)).astype(np.float32)
    tex[:16] = 0.5
    depth_d = np.linspace(0.5, 2.5, w)[None].repeat(h, 0)  # diopters
    focus_d = np.linspace(0.5, 2.5, s)
    frames = []
    for fd in focus_d:
        blur = np.abs(depth_d - fd) * 4 + 0.3
        levels = [cv2.GaussianBlur(tex, (0, 0), b) for b in np.linspace(0.3, 8.3, 21)]
        idx = np.clip(np.rint((blur - 0.3) / 0.4).astype(int), 0, 20)
        fr = np.choose(idx, levels)
        frames.append(np.repeat(fr[None], 3, 0))
    return np.stack(frames).astype(np.float32), (1 / focus_d).astype(np.float32), (1 / depth_d).astype(np.float32)


def test_focus_method_uses_the_calibration_for_own_and_filled_pixels():
    stack, focus, gt = _slanted_stack()
    cal = cf.Calibration({"estimate": cf.Curve([0.0, 1.0], [0.0, 1.0]), "fill": cf.Curve([0.0, 1.0], [0.2, 0.6])})
    r = classical_depth(stack, focus, config=FocusConfig(), confidence_calibration=cal)
    own = cal["estimate"](r.score)
    assert np.array_equal(r.filled, r.score < FocusConfig().c_full)  # the fill weighs by the raw contrast
    assert np.allclose(r.confidence[~r.filled], own[~r.filled])
    assert np.allclose(r.confidence[r.filled], 0.2 + 0.4 * r.fill_support[r.filled], atol=1e-6)
    assert r.filled[:4].mean() > 0.9 and r.filled[24:].mean() < 0.2  # the textureless band (beyond the window)
    assert r.info["confidence"]["calibrated"] and r.info["confidence"]["filled_share"] == pytest.approx(r.filled.mean())
    raw = classical_depth(stack, focus, config=FocusConfig(confidence="raw"))
    assert np.array_equal(raw.confidence, raw.score) and not raw.info["confidence"]["calibrated"]
    with pytest.raises(ValueError, match="confidence"):
        FocusConfig(confidence="other")


def test_unknown_depth_in_the_outputs(tmp_path, monkeypatch):
    """A calibration under which about half the pixels are below the threshold (the fixture's contrast is 0.9 ..
    0.998, median 0.996) and the fill never reaches it: those are NaN in depth_m, 0 in depth_mm.png, absent from
    points.ply, and counted in summary.json."""
    from aat_deploy.cli.infer import main

    cap = write_dng_capture(tmp_path / "cap", [0.6, 0.75, 0.95, 1.3, 1.9, 3.0, 5.0])
    strict = cf.Calibration({"estimate": cf.Curve([0.99, 0.9963, 1.0], [0.0, 0.5, 0.99]),
                             "fill": cf.Curve([0.0, 1.0], [0.0, 0.3])})
    monkeypatch.setattr(cf, "focus_calibration", lambda: strict)
    monkeypatch.setattr("aat_deploy.focus.method.focus_calibration", lambda: strict)
    out = tmp_path / "out"
    assert main([str(cap), "--method", "focus", "--out", str(out), "-q", "--no-recording"]) == 0
    d = np.load(out / "depth_m.npy")
    c = np.load(out / "confidence.npy")
    s = json.loads((out / "summary.json").read_text())
    unknown = ~np.isfinite(d)
    assert unknown.any() and (~unknown).any()
    assert np.array_equal(unknown, c < 0.5)
    assert s["unknown"]["unknown_share"] == pytest.approx(unknown.mean())
    assert s["unknown"]["min_confidence"] == 0.5
    import cv2

    mm = cv2.imread(str(out / "depth_mm.png"), cv2.IMREAD_UNCHANGED)
    assert np.all(mm[unknown] == 0)
    head = (out / "points.ply").read_bytes().split(b"end_header")[0].decode()
    assert f"element vertex {(~unknown).sum()}" in head  # every known pixel, no unknown one
    # --min-confidence 0 keeps every pixel
    out0 = tmp_path / "out0"
    assert main([str(cap), "--method", "focus", "--out", str(out0), "-q", "--no-recording",
                 "--min-confidence", "0"]) == 0
    assert np.isfinite(np.load(out0 / "depth_m.npy")).all()
    assert json.loads((out0 / "summary.json").read_text())["unknown"]["unknown_share"] == 0


def test_two_score_curve_by_hand_and_fit():
    c = cf.Curve([0.0, 1.0], np.array([[0.0, 0.2], [0.6, 1.0]]), y=[0.0, 2.0])
    # bilinear: at (0.5, 1.0) the mean of the four corners; held beyond the knots
    assert float(c(np.array(0.5), np.array(1.0))) == pytest.approx(0.45)
    assert float(c(np.array(2.0), np.array(-1.0))) == pytest.approx(0.6)
    with pytest.raises(ValueError, match="second"):
        c(np.array(0.5))
    rng = np.random.default_rng(1)
    s, t = rng.random(300_000), rng.random(300_000) * 3
    truth = s * np.minimum(t, 1.0)  # rises with both, flat in t beyond 1
    fit = cf.fit_curve(s, rng.random(s.size) < truth, n_bins=16, second=t, n_bins2=8)
    gs, gt = np.meshgrid(np.linspace(0.1, 0.9, 5), np.linspace(0.3, 2.7, 5))
    assert np.abs(fit(gs, gt) - gs * np.minimum(gt, 1.0)).max() < 0.08  # bins 1/16 x 3/8 wide
    assert np.all(np.diff(fit.p, axis=0) >= 0) and np.all(np.diff(fit.p, axis=1) >= 0)
    back = cf.Calibration.from_dict(cf.Calibration({"estimate": fit}).to_dict())
    assert np.allclose(back["estimate"](gs, gt), fit(gs, gt), atol=1e-4)


def test_tolerance_steps_by_hand():
    focus = [0.5, 1.0, 2.0, 4.0]  # 2, 1, 0.5, 0.25 D: gaps 0.25, 0.5, 1
    d = np.array([1.5, 0.3, 3.0])  # between 1 and 2 D; below the farthest frame; beyond the nearest
    assert cf.tolerance_steps(d, focus, 0.1).tolist() == pytest.approx([0.15 / 1.0, 0.03 / 0.25, 0.3 / 1.0])


def test_agreement_by_hand():
    focus = [0.5, 1.0 / 1.5, 1.0]  # 2, 1.5, 1 D: spacing 0.5 D
    flat = np.full((20, 20), 1.2, np.float32)
    assert np.allclose(cf.agreement(flat, focus, 15), 1.0)
    checker = np.where((np.indices((31, 31)).sum(0) % 2) == 0, 1.0, 1.5).astype(np.float32)  # one spacing apart
    a = cf.agreement(checker, focus, 15)[8:-8, 8:-8]  # std 0.25 D = half a spacing: 1 / 1.5
    assert np.allclose(a, 1 / 1.5, atol=2e-3)
