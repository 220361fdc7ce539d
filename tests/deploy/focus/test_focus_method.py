"""The classical depth-from-focus method (aat_deploy.focus): estimators against hand-computed curves, the method on
synthetic and rendered stacks with known depth, tied focus distances, the best-focus map's storage."""

from __future__ import annotations

import numpy as np
import pytest

from aat_deploy.focus import BestFocusMap, FocusConfig, classical_depth
from aat_deploy.focus.aif import blend_at, focus_weights, spread_m
from aat_deploy.focus.bestfocus import BestFocusError, load_json
from aat_deploy.focus.estimate import estimate_peak
from aat_deploy.focus.fill import fill_depth
from aat_deploy.focus.measures import MEASURES, focus_volume, prefilter
from aat_deploy.focus.placement import place_equal_focus, tied_groups
from aat_deploy.infer.geometry import equalise_exposure


def _volume(curve_fn, x: np.ndarray, d_true: np.ndarray) -> np.ndarray:
    """(S, 1, N) focus volume of curves m(x_s; D) for pixels with peaks d_true (N,)."""
    return np.stack([curve_fn(xs, d_true) for xs in x])[:, None, :].astype(np.float32)


X_UNEVEN = np.array([2.0, 1.6, 1.1, 0.8, 0.37, 0.1])  # diopters, near to far, uneven spacing


def test_gauss_estimator_is_exact_for_gaussian_curves():
    d = np.array([1.95, 1.7, 1.3, 0.9, 0.5, 0.15])
    vol = _volume(lambda xs, dd: np.exp(-(xs - dd) ** 2 / (2 * 0.3 ** 2)), X_UNEVEN, d)
    p = estimate_peak(vol, X_UNEVEN, estimator="gauss")
    np.testing.assert_allclose(p.diopters[0], d, atol=1e-4)


def test_ratio_estimator_is_exact_for_power_law_curves():
    """m = |x - D|^-gamma: (m_k / m_n)^(1/gamma) = |x_n - D| / |x_k - D|, any spacing (hand-checkable case first)."""
    x = np.array([0.37, 0.1])
    vol = _volume(lambda xs, dd: np.abs(xs - dd) ** -1.0, x, np.array([0.2]))
    # m at 0.37: 1/0.17, at 0.1: 1/0.1 -> rho = 1.7 -> D = (0.37 + 1.7 * 0.1) / 2.7 = 0.2
    assert estimate_peak(vol, x, estimator="ratio", gamma=1.0).diopters[0, 0] == pytest.approx(0.2, abs=1e-6)
    d = np.array([1.8, 1.4, 0.95, 0.6, 0.25])
    vol = _volume(lambda xs, dd: np.abs(xs - dd) ** -2.0, X_UNEVEN, d)
    np.testing.assert_allclose(estimate_peak(vol, X_UNEVEN, estimator="ratio", gamma=2.0).diopters[0], d, atol=1e-4)


def test_estimators_stay_inside_the_stack_and_use_per_pixel_positions():
    """Peaks beyond the first/last frame are kept at the end; radial positions (S, R) are looked up per pixel."""
    x = np.array([1.0, 0.5, 0.2])
    vol = _volume(lambda xs, dd: np.exp(-(xs - dd) ** 2 / 0.02), x, np.array([1.5, -0.2]))
    for est in ("argmax", "parabola", "gauss", "ratio"):
        got = estimate_peak(vol, x, estimator=est).diopters[0]
        assert got[0] == pytest.approx(1.0, abs=1e-3) and got[1] == pytest.approx(0.2, abs=1e-3)
    lut = np.stack([x, x - 0.1], 1)  # radius bin 1: every frame in focus 0.1 D farther
    vol = _volume(lambda xs, dd: np.exp(-(xs - dd) ** 2 / 0.02), x, np.array([0.5, 0.5]))
    p = estimate_peak(vol, lut, np.array([[0, 1]]), estimator="argmax")
    np.testing.assert_allclose(p.diopters[0], [0.5, 0.4], atol=1e-6)


def test_confidence_is_low_without_texture_and_high_with_a_peak():
    x = np.array([1.0, 0.5, 0.2])
    flat = np.full((3, 1, 1), 1e-9, np.float32)
    peak = np.array([1e-3, 1.0, 2e-3], np.float32)[:, None, None]
    vol = np.concatenate([flat, peak], 2)
    c = estimate_peak(vol, x).confidence[0]
    assert c[0] < 0.05 and c[1] > 0.95


def _synthetic_stack(depth_m: np.ndarray, focus_m: np.ndarray, px_per_diopter: float = 12.0, seed: int = 0):
    """A textured scene blurred per depth layer (Gaussian, sigma proportional to the defocus in diopters)."""
    import cv2

    rng = np.random.default_rng(seed)
    h, w = depth_m.shape
    tex = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 0.7)
    frames = []
    for f in focus_m:
        out = np.zeros_like(tex)
        for d in np.unique(depth_m):
            s = px_per_diopter * abs(1 / d - 1 / f) / 2
            layer = cv2.GaussianBlur(tex, (0, 0), s) if s > 0.05 else tex
            out[depth_m == d] = layer[depth_m == d]
        frames.append(out.transpose(2, 0, 1))
    return np.stack(frames), tex


@pytest.mark.parametrize("measure", MEASURES)
def test_method_recovers_depth_of_a_synthetic_stack(measure):
    """Two planes (0.8 m, 2.5 m) between frames of a 9-frame stack: every measure, median error within 0.05 D."""
    focus = 1.0 / np.linspace(1.6, 0.2, 9)
    depth = np.full((64, 96), 2.5, np.float32)
    depth[:, :48] = 0.8
    stack, _ = _synthetic_stack(depth, focus)
    r = classical_depth(stack[::-1], focus[::-1], config=FocusConfig(measure=measure))  # any frame order
    inner = np.zeros_like(depth, bool)
    inner[8:-8, 8:40] = inner[8:-8, 56:-8] = True  # away from the border and the step
    err_d = np.abs(1 / r.depth_m - 1 / depth)[inner]
    assert np.median(err_d) < 0.05, np.median(err_d)
    assert r.depth_m.shape == depth.shape and r.aif.shape == (3, 64, 96) and np.isfinite(r.std_m).all()
    assert list(r.focus_m) == sorted(r.focus_m)


def test_prefilter_hand_cases():
    g = np.random.default_rng(0).random((2, 16, 20)).astype(np.float32)
    assert prefilter(g, 0.0) is g  # off: untouched
    np.testing.assert_allclose(prefilter(np.full((1, 9, 9), 0.3, np.float32), 1.5), 0.3, rtol=1e-6)  # flat stays
    blurred = prefilter(g, 1.0)
    assert blurred.shape == g.shape and blurred.std() < 0.6 * g.std()  # white noise loses most of its variance
    np.testing.assert_allclose(blurred.mean(), g.mean(), rtol=0.02)  # ... but not its mean
    with pytest.raises(ValueError, match="prefilter_px"):
        prefilter(g, -1.0)
    with pytest.raises(ValueError, match="prefilter_px"):
        FocusConfig(prefilter_px=-0.5)


def test_prefilter_rescues_the_method_under_noise():
    """Strong white noise on the synthetic two-plane stack: the high-pass measure then answers to noise wherever
    the frames are blurred; a 1 px pre-filter brings the median error back down (and below no pre-filter's)."""
    focus = 1.0 / np.linspace(1.6, 0.2, 9)
    depth = np.full((64, 96), 2.5, np.float32)
    depth[:, :48] = 0.8
    stack, _ = _synthetic_stack(depth, focus)
    noisy = stack + np.random.default_rng(1).normal(0, 0.06, stack.shape).astype(np.float32)
    inner = np.zeros_like(depth, bool)
    inner[8:-8, 8:40] = inner[8:-8, 56:-8] = True
    err = {s: np.median(np.abs(1 / classical_depth(noisy, focus, config=FocusConfig(prefilter_px=s, fill="none"))
                               .depth_m - 1 / depth)[inner]) for s in (0.0, 1.0)}
    assert err[1.0] < 0.7 * err[0.0] and err[1.0] < 0.1, err


def test_aif_blend_is_sharper_than_any_frame():
    focus = 1.0 / np.linspace(1.6, 0.2, 7)
    depth = np.full((48, 64), 2.5, np.float32)
    depth[:, :32] = 0.8
    stack, tex = _synthetic_stack(depth, focus)
    r = classical_depth(stack, focus)
    ref = tex.transpose(2, 0, 1)
    err_aif = np.abs(r.aif - ref)[:, 6:-6, 6:-6].mean()
    assert all(err_aif < np.abs(f - ref)[:, 6:-6, 6:-6].mean() for f in stack)


def test_blend_helpers_hand_cases():
    st = np.stack([np.zeros((3, 1, 2)), np.ones((3, 1, 2))]).astype(np.float32)
    np.testing.assert_allclose(blend_at(st, np.array([[0.25, 1.0]], np.float32))[:, 0], [[0.25, 1.0]] * 3)
    w = focus_weights(np.array([[[1.0]], [[1.0]]], np.float32))
    np.testing.assert_allclose(w[:, 0, 0], [0.5, 0.5])
    # spread of two equal weights at 1 m and 3 m about 2 m: 1 m
    assert spread_m(w, np.array([1.0, 3.0]), np.array([[2.0]]))[0, 0] == pytest.approx(1.0)


def test_fill_takes_confident_values_along_the_guide_not_across_edges():
    d = np.zeros((40, 80), np.float32)
    d[:, :40], d[:, 40:] = 1.0, 3.0
    c = np.zeros_like(d)
    c[:, :5], c[:, -5:] = 1.0, 1.0  # confident only at the far left and far right
    guide = np.zeros((3, 40, 80), np.float32)
    guide[:, :, 40:] = 1.0  # an edge where the depth steps
    out = fill_depth(np.where(c > 0, d, 2.0), c, guide, sigma_s_px=200, sigma_r=0.05, downscale=1)
    assert np.abs(out[:, 10:35] - 1.0).max() < 0.05 and np.abs(out[:, 45:70] - 3.0).max() < 0.05


def test_tied_frames_are_placed_from_the_images():
    """Frames 3 and 4 reported at the same distance (as Lightroom's coarse XMP values): placed near their truth."""
    focus_true = 1.0 / np.linspace(2.0, 0.3, 8)
    h, w = 96, 128
    yy = np.linspace(0, 1, w)[None].repeat(h, 0)
    depth = (1.0 / (2.1 - 1.9 * yy)).astype(np.float32)  # a slanted plane through every frame's focus
    depth = np.round(depth * 200) / 200  # depth layers for the synthetic renderer
    stack, _ = _synthetic_stack(depth, focus_true, px_per_diopter=10.0)
    reported = focus_true.copy()
    reported[4] = reported[3]
    assert tied_groups(reported) == [[3, 4]]
    vol = focus_volume(stack, "mlap2", 9)
    placed, notes = place_equal_focus(vol, reported)
    assert {n["frame"] for n in notes} == {3, 4} and all(n["method"] == "images" for n in notes)
    err = np.abs(1 / placed - 1 / focus_true)
    assert err[[3, 4]].max() < 0.1, err  # the frames are 0.24 D apart (measured: 0.075 and 0.067 D)
    assert placed[3] < placed[4]
    r = classical_depth(stack, reported)
    assert any("equal reported focus" in x for x in r.warnings)


def test_equalise_exposure_removes_a_gain():
    rng = np.random.default_rng(1)
    a = rng.random((20, 30, 3)).astype(np.float32)
    out, gains = equalise_exposure([a, 2 * a, 0.5 * a], ref=0)
    assert gains == pytest.approx([1.0, 0.5, 2.0], rel=1e-5)
    np.testing.assert_allclose(out[1], a, rtol=1e-5)


def test_best_focus_map_round_trip_and_interpolation(tmp_path):
    r = np.array([0.0, 0.5, 1.0])
    f = np.array([0.1, 1.0, 2.0])
    shift = -0.1 * r[:, None] ** 2 * np.ones((1, 3))  # curvature growing with r^2
    m = BestFocusMap(r, f, f[None] + shift, (36.0, 24.0), offset_diopters=np.full((3, 3), 0.02), lens_hash="x")
    got = m.frame_diopters([1.0 / 1.5], [0.0, 0.75, 1.0], calibrated=False)[0]
    np.testing.assert_allclose(got, 1.5 - 0.1 * np.array([0.0, 0.75, 1.0]) ** 2, atol=1e-9)  # exact in r^2
    np.testing.assert_allclose(m.frame_diopters([1.0], [1.0])[0], [1.0 - 0.1 + 0.02])
    np.testing.assert_allclose(m.frame_diopters([1 / 5.0], [1.0], calibrated=False)[0], [5.0 - 0.1])  # held
    path = m.save_json(tmp_path / "best_focus" / "lens.json")
    m2 = load_json(path)
    np.testing.assert_allclose(m2.object_diopters, m.object_diopters)
    assert m2.lens_hash == "x" and m2.offset_diopters is not None
    (tmp_path / "bad.json").write_text('{"format": "aat-best-focus-map-v1", "radius": [0]}')
    with pytest.raises(BestFocusError, match="bad.json"):
        load_json(tmp_path / "bad.json")


def test_a_map_calibrated_for_other_measure_settings_is_named_in_a_warning():
    """The map's calibration belongs to the measure it was made with: other settings get a one-line warning,
    matching ones (and maps that do not say, or calibrated=False) none."""
    from dataclasses import replace

    from aat_deploy.focus.method import calibration_mismatch

    r, f = np.array([0.0, 1.0]), np.array([0.1, 2.0])
    m = BestFocusMap(r, f, np.tile(f, (2, 1)), (36.0, 24.0), offset_diopters=np.zeros((2, 2)),
                     notes={"calibration": {"measure": "mlap2", "window_px": 15.0, "prefilter_px": 1.0}})
    cfg = FocusConfig(measure="mlap2", window_px=15.0, prefilter_px=1.0)
    assert calibration_mismatch(m, cfg) == ""
    assert calibration_mismatch(m, replace(cfg, prefilter_px=2.0)) == "prefilter_px 1.0 in the map, 2.0 here"
    old = replace(m, notes={"calibration": {"measure": "mlap2", "window_px": 15.0}})  # made before the pre-filter
    assert "prefilter_px 0.0 in the map, 1.0 here" in calibration_mismatch(old, cfg)
    assert calibration_mismatch(replace(m, notes={}), replace(cfg, measure="sml")) == ""
    focus = 1.0 / np.linspace(1.6, 0.2, 5)
    stack, _ = _synthetic_stack(np.full((24, 32), 1.0, np.float32), focus)
    warned = classical_depth(stack, focus, m, replace(cfg, window_px=9.0)).warnings
    assert sum("calibrated with another focus measure" in w and "window_px 15.0 in the map, 9.0 here" in w
               for w in warned) == 1
    assert not any("calibrated with another" in w for w in classical_depth(stack, focus, m, cfg).warnings)
    assert not any("calibrated with another" in w
                   for w in classical_depth(stack, focus, m, replace(cfg, window_px=9.0, calibrated=False)).warnings)


def test_radius_px_is_the_normalised_sensor_radius():
    m = BestFocusMap(np.array([0.0, 1.0]), np.array([0.1, 1.0]), np.zeros((2, 2)) + [0.1, 1.0], (36.0, 24.0))
    r = m.radius_px(640, 960)
    assert r[320, 480] < 0.01 and r[0, 0] == pytest.approx(1.0, abs=0.005)
    assert r[320, 0] == pytest.approx(18 / np.hypot(18, 12), abs=0.005)
