"""The one thin-lens blur (aat_deploy.optics.thin_lens): against the textbook circle of confusion, in the inputs'
precision for numpy and torch alike, and the Lens wrapper in float64; the thin-lens baseline's Gaussian kernels
(`gaussian_kernels`) against a hand computation and across the two namespaces."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import LENSES

from aat_deploy.lens.io import load_lens
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.optics.thin_lens import blur_diameter_px, gaussian_kernels, thin_lens_blur_px

F, A, PX = 50.0, 25.0, 0.01  # focal length, aperture diameter, pixel (mm)


def _coc_px(depth_m: float, focus_m: float) -> float:
    """Textbook CoC of a thin lens focused at object distance s_f, for a point at s (both from the lens):
    c = A f |s - s_f| / (s (s_f - f)); distances here are from the sensor, so s_f = D - v with u + v = D."""
    big_d = 1000.0 * focus_m
    v = (big_d - math.sqrt(big_d * big_d - 4 * big_d * F)) / 2  # the lens-to-sensor distance focusing D
    s_f, s = big_d - v, 1000.0 * depth_m - v
    return A * F * abs(s - s_f) / (s * (s_f - F)) / PX


@pytest.mark.parametrize("depth_m, focus_m", [(1.0, 2.0), (3.0, 0.7), (2.0, 2.0), (50.0, 0.5)])
def test_textbook_circle_of_confusion(depth_m, focus_m):
    ref = _coc_px(depth_m, focus_m)
    got = blur_diameter_px(np.float64(depth_m), np.float64(focus_m), F, A, PX)
    assert got == pytest.approx(ref, rel=1e-9, abs=1e-9)
    got32 = blur_diameter_px(np.float32(depth_m), np.float32(focus_m), F, A, PX)
    assert got32.dtype == np.float32 and got32 == pytest.approx(ref, rel=1e-3, abs=1e-3)  # float32: ~8 ulps at focus


def test_torch_and_numpy_share_the_formula():
    torch = pytest.importorskip("torch")
    d = np.geomspace(0.3, 30, 50)
    f = np.full(50, 1.3)
    ref = blur_diameter_px(d, f, F, A, PX)
    t64 = blur_diameter_px(torch.from_numpy(d), torch.from_numpy(f), F, A, PX)
    assert isinstance(t64, torch.Tensor) and t64.dtype == torch.float64
    assert np.allclose(t64.numpy(), ref, rtol=1e-12, atol=1e-9)
    t32 = blur_diameter_px(torch.from_numpy(d).float(), torch.from_numpy(f).float(), F, A, PX)
    assert t32.dtype == torch.float32 and np.allclose(t32.numpy(), ref, rtol=1e-4, atol=1e-3)


def test_lens_wrapper_uses_efl_pupil_and_pixel():
    lens = load_lens(LENSES / "canon_rf50mm_f1.8.json")
    p = paraxial_data(lens)
    d, f = np.array([0.6, 1.0, 4.0]), np.array([1.0, 1.0, 1.0])
    got = thin_lens_blur_px(lens, d, f)
    assert got.dtype == np.float64 and got[1] < 1e-9 and min(got[0], got[2]) > 20  # in focus: rounding only
    assert np.array_equal(got, blur_diameter_px(d, f, p.efl_mm, p.entrance_pupil_mm, lens.sensor.pixel_mm))


def test_gaussian_kernels_by_hand():
    """Blur 16 px, 11 cells, margin 4: cell s = 2 px, sigma^2 = (16/4/2)^2 + 1/6 cells^2; a separable Gaussian
    normalised over cells -51..51, so a window of 11 holds a little less than 1 (the tails are lost)."""
    k, s = gaussian_kernels(np.array([16.0]), 11, 4.0)
    assert k.shape == (1, 11, 11) and s[0] == 2.0
    var = 4.0 + 1.0 / 6.0
    norm = sum(math.exp(-(w * w) / (2 * var)) for w in range(-51, 52))
    row = [math.exp(-(g * g) / (2 * var)) / norm for g in range(-5, 6)]
    assert np.allclose(k[0], np.outer(row, row), rtol=1e-12, atol=0)
    assert 0.98 < k.sum() < 1.0  # tails beyond +-5 cells (2.4 sigma) lost, nothing renormalised
    k0, s0 = gaussian_kernels(np.array([0.0]), 11, 4.0)
    assert s0[0] == 1.0 and k0[0, 5, 5] == pytest.approx((1 / sum(math.exp(-3 * w * w) for w in range(-51, 52))) ** 2)


def test_gaussian_kernels_torch_and_numpy_agree():
    torch = pytest.importorskip("torch")
    b = np.geomspace(0.01, 80, 40).astype(np.float32)
    kn, sn = gaussian_kernels(b, 11, 4.0)
    kt, st = gaussian_kernels(torch.from_numpy(b), 11, 4.0)
    assert kt.dtype == torch.float32 and kn.dtype == np.float32
    # the same float32 operations in the same order; exp may differ by an ulp between the libraries
    assert np.allclose(kt.numpy(), kn, rtol=1e-6, atol=1e-9) and np.array_equal(st.numpy(), sn)
