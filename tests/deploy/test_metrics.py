"""Depth and all-in-focus metrics against hand-computed values; SSIM against scikit-image."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aat_deploy.metrics import MetricAccumulator, depth_metrics, psnr, ssim


def test_depth_metrics_hand_computed():
    pred = np.array([[1.0, 2.0], [3.0, 4.0]])
    gt = np.array([[1.0, 1.0], [4.0, 0.0]])  # 0 = invalid -> pixels (1|1), (2|1), (3|4)
    m = depth_metrics(pred, gt)
    assert m["n_valid"] == 3
    assert m["mae"] == pytest.approx(2 / 3)
    assert m["mse"] == pytest.approx(2 / 3)
    assert m["rmse"] == pytest.approx(math.sqrt(2 / 3))
    assert m["abs_rel"] == pytest.approx((0 + 1 + 0.25) / 3)
    assert m["sq_rel"] == pytest.approx((0 + 1 + 0.25) / 3)
    assert m["rmse_log"] == pytest.approx(math.sqrt((math.log(2) ** 2 + math.log(0.75) ** 2) / 3))
    # ratios 1, 2, 4/3: < 1.25 -> 1; < 1.5625 -> 2; < 1.953 -> 2
    assert m["delta1"] == pytest.approx(1 / 3)
    assert m["delta2"] == pytest.approx(2 / 3)
    assert m["delta3"] == pytest.approx(2 / 3)


def test_sq_rel_differs_from_abs_rel():
    m = depth_metrics(np.array([3.0, 1.0]), np.array([2.0, 0.5]))  # d = 1, 0.5
    assert m["abs_rel"] == pytest.approx((1 / 2 + 0.5 / 0.5) / 2)
    assert m["sq_rel"] == pytest.approx((1 / 2 + 0.25 / 0.5) / 2)


def test_invalid_gt_masked_nan_inf_negative_and_focus_range():
    pred = np.array([1.0, 5.0, 5.0, 5.0, 2.0, 9.0])
    gt = np.array([1.5, np.nan, np.inf, -1.0, 2.0, 10.0])
    m = depth_metrics(pred, gt)
    assert m["n_valid"] == 3
    assert m["mae"] == pytest.approx((0.5 + 0 + 1) / 3)
    m = depth_metrics(pred, gt, focus_range_m=(1.0, 5.0))  # 10 m is outside the stack's focus range
    assert m["n_valid"] == 2
    assert m["mae"] == pytest.approx(0.25)


def test_no_valid_pixel_gives_nan_and_is_skipped_in_the_mean():
    acc = MetricAccumulator()
    acc.add(np.ones((2, 2)), np.zeros((2, 2)))
    acc.add(np.ones((2, 2)), np.full((2, 2), 2.0))
    r = acc.result()
    assert r["n_images"] == 2
    assert r["mae"] == pytest.approx(1.0)


def test_per_image_then_mean():
    acc = MetricAccumulator()
    acc.add(np.array([[2.0]]), np.array([[1.0]]))  # error 1
    acc.add(np.array([[4.0]]), np.array([[1.0]]))  # error 3
    r = acc.result()
    assert r["mse"] == pytest.approx(5.0)
    assert r["rmse"] == pytest.approx(2.0)  # mean of per-image RMSE, not sqrt(mean MSE) = 2.236
    assert r["abs_rel"] == pytest.approx(2.0)


def test_error_map_mean_over_valid_images():
    acc = MetricAccumulator()
    acc.add(np.array([[1.0, 2.0]]), np.array([[2.0, 0.0]]))  # |err| 1 at pixel 0, pixel 1 invalid
    acc.add(np.array([[1.0, 2.0]]), np.array([[4.0, 1.0]]))  # 3, 1
    em = acc.error_map()
    assert em[0, 0] == pytest.approx(2.0)
    assert em[0, 1] == pytest.approx(1.0)
    acc2 = MetricAccumulator()
    acc2.add(np.array([[1.0]]), np.array([[0.0]]))
    assert np.isnan(acc2.error_map()[0, 0])
    assert acc.has_error_map


def test_images_of_several_sizes_give_metrics_but_no_error_map():
    acc = MetricAccumulator()
    acc.add(np.array([[1.0, 2.0]]), np.array([[2.0, 4.0]]))  # errors 1, 2
    acc.add(np.zeros((2, 2)), np.ones((2, 2)))  # error 1 everywhere
    assert acc.result()["mae"] == pytest.approx((1.5 + 1.0) / 2)
    assert not acc.has_error_map
    with pytest.raises(ValueError, match="sizes differ"):
        acc.error_map()
    assert not MetricAccumulator().has_error_map


def test_focus_range_mask_in_accumulator():
    acc = MetricAccumulator(focus_range_mask=True)
    acc.add(np.array([1.0, 3.0]), np.array([1.5, 30.0]), focus_m=np.array([1.0, 2.0, 4.0]))
    assert acc.result()["mae"] == pytest.approx(0.5)
    with pytest.raises(ValueError, match="focus_m"):
        acc.add(np.array([1.0]), np.array([1.0]))


def test_psnr_hand_computed():
    ref = np.full((4, 4, 3), 0.5)
    assert psnr(ref + 0.1, ref) == pytest.approx(20.0)
    assert psnr(ref + 0.1, ref, data_range=255.0) == pytest.approx(20 * math.log10(2550))
    assert psnr(ref, ref) == math.inf


def test_ssim_constant_images_closed_form():
    a, b = 0.2, 0.6
    c1 = 0.01**2
    got = ssim(np.full((16, 16), a), np.full((16, 16), b))
    assert got == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1))
    assert ssim(np.full((16, 16), a), np.full((16, 16), a)) == pytest.approx(1.0)


@pytest.mark.parametrize("shape,axis", [((40, 37), None), ((3, 33, 48), 0), ((31, 29, 3), 2)])
def test_ssim_matches_skimage(shape, axis):
    skm = pytest.importorskip("skimage.metrics")
    rng = np.random.default_rng(1)
    x = rng.random(shape)
    y = np.clip(x + 0.15 * rng.standard_normal(shape), 0, 1)
    want = skm.structural_similarity(x, y, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                     use_sample_covariance=False, channel_axis=axis)
    assert ssim(x, y, 1.0, channel_axis=axis) == pytest.approx(want, rel=1e-9)  # float64, other summation orders
    assert 0.1 < want < 0.95  # a case where SSIM is informative


def test_accumulator_aif_metrics():
    rng = np.random.default_rng(2)
    ref = rng.random((3, 16, 16))
    acc = MetricAccumulator()
    row = acc.add(np.ones((16, 16)), np.ones((16, 16)), ref + 0.1, ref)
    assert row["psnr"] == pytest.approx(20.0)
    assert row["ssim"] == pytest.approx(ssim(ref + 0.1, ref, channel_axis=0))
    assert acc.result()["psnr"] == pytest.approx(20.0)


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="shape"):
        depth_metrics(np.ones((2, 2)), np.ones((2, 3)))


def test_frame_error_hand_computed_in_frame_spacings_inside_each_pixels_frame_range():
    """frame_error: |1/p - 1/g| / the pixel's frame spacing, over pixels whose true diopters its frames reach."""
    from aat_deploy.metrics import frame_error

    fd = np.stack([np.full((2, 2), 2.0), np.full((2, 2), 1.5), np.full((2, 2), 1.0)])  # spacing 0.5 D
    fd[:, 1, 1] = [4.0, 2.5, 1.0]  # spacing 1.5 D at this pixel
    gt = np.array([[0.5, 0.25], [0.0, 0.5]])  # 2 D inside; 4 D beyond the near frame (2 D); invalid; 2 D inside
    pred = np.array([[1.0, 1.0], [1.0, 1.0]])  # 1 D everywhere
    r = frame_error(pred, gt, fd)
    assert r["n_valid"] == 2
    assert r["frames_l1"] == pytest.approx(((2 - 1) / 0.5 + (2 - 1) / 1.5) / 2)
    every = frame_error(pred, gt, fd, mask=np.ones((2, 2), bool))  # the beyond-range pixel too: (4 - 1) / 0.5
    assert every["n_valid"] == 3 and every["frames_l1"] == pytest.approx((2 + 2 / 3 + 6) / 3)
    assert frame_error(pred, np.full((2, 2), 0.1), fd)["n_valid"] == 0  # 10 D: beyond every pixel's frames
    with pytest.raises(ValueError, match="differ"):
        frame_error(pred, gt, fd[:, :1])
