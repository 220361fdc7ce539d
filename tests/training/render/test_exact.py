"""Exact renderer: true convolution (not correlation), energy conservation, kernel resampling."""

from __future__ import annotations

import pytest
import torch

from training.render.exact import cells_to_pixels, pixel_kernel_size, render_exact

pytestmark = pytest.mark.numerics  # float sums in another order than the references'


def test_asymmetric_psf_proves_convolution_orientation():
    h, w, kk = 15, 17, 7
    img = torch.zeros(1, h, w, dtype=torch.float64)
    img[0, 7, 8] = 1.0  # a single bright point
    ker = torch.zeros(h * w, kk, kk, dtype=torch.float64)
    ker[:, 3, 5] = 0.75  # light goes 2 px right of the source...
    ker[:, 1, 3] = 0.25  # ...and 2 px up
    out = render_exact(img, ker)
    # exact: float64 products and sums of dyadic values (0, 0.25, 0.75, 1) round nowhere
    assert float(out[0, 7, 10]) == 0.75 and float(out[0, 5, 8]) == 0.25
    assert float(out.sum()) == 1.0
    # A correlation (gather with the receiving pixel's kernel) would have put it 2 px left and 2 px down.
    assert float(out[0, 7, 6]) == 0.0 and float(out[0, 9, 8]) == 0.0


def test_flat_field_stays_flat_and_energy_is_conserved():
    h, w, kk = 12, 14, 9
    g = torch.Generator().manual_seed(0)
    ker = torch.rand(h * w, kk, kk, generator=g, dtype=torch.float64)
    ker = ker / ker.sum((1, 2), keepdim=True)
    same = ker[:1].expand(h * w, kk, kk).contiguous()
    flat = render_exact(torch.full((3, h, w), 0.4, dtype=torch.float64), same)
    # float64 sums of 81 cells: ~81 eps = 2e-14 relative; up to the border
    assert torch.allclose(flat, torch.full_like(flat, 0.4), rtol=1e-12, atol=0)
    img = torch.zeros(1, h, w, dtype=torch.float64)
    img[0, 4:8, 5:9] = torch.rand(4, 4, generator=g, dtype=torch.float64)
    out = render_exact(img, ker)  # spatially varying kernels, light well inside the frame
    assert float(out.sum()) == pytest.approx(float(img.sum()), rel=1e-12)  # float64 sums


def test_cells_to_pixels_conserves_energy_and_is_identity_at_scale_one():
    g = torch.Generator().manual_seed(1)
    k = torch.rand(4, 11, 11, generator=g, dtype=torch.float64)
    scale = torch.tensor([1.0, 1.7, 3.0, 6.4], dtype=torch.float64)
    for i, s in enumerate(scale.tolist()):
        size = pixel_kernel_size(11, s)
        p = cells_to_pixels(k[i:i + 1], scale[i:i + 1], size)
        assert float(p.sum()) == pytest.approx(float(k[i].sum()), rel=1e-12)  # float64 resampling weights
        if s == 1.0:
            c = size // 2
            assert torch.allclose(p[0, c - 5:c + 6, c - 5:c + 6], k[i])
    # A centred point kernel at scale s becomes a tent of half-width s: its second moment is s^2 / 6 per axis.
    pt = torch.zeros(1, 11, 11, dtype=torch.float64)
    pt[0, 5, 5] = 1.0
    p = cells_to_pixels(pt, torch.tensor([4.0], dtype=torch.float64), pixel_kernel_size(11, 4.0))
    off = torch.arange(p.shape[-1], dtype=torch.float64) - p.shape[-1] // 2
    var = float((p[0].sum(0) * off**2).sum())
    assert var == pytest.approx((4.0**2 - 1) / 6, rel=1e-12)  # discrete tent of half-width s: variance (s^2 - 1) / 6


def test_frame_with_thin_lens_gaussian_and_orientation_of_field():
    import numpy as np
    from conftest import LENSES

    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.field import pixel_fields
    from aat_deploy.psf.kernel import KernelSpec
    from training.psf.surrogates import GaussianPSF
    from training.render.exact import render_frame_exact
    from training.render.sources import ModelPSF

    lens = load_lens(LENSES / "canon_rf50mm_f1.8.json")
    x, y = pixel_fields(2, 3, (640, 960))
    assert x[0, 0] < 0 < y[0, 0] and x[0, -1] > x[0, 0] and y[-1, 0] < y[0, 0]  # x right, y up
    src = ModelPSF(GaussianPSF(lens, KernelSpec.for_lens(lens), 0.3, 20.0), lens)
    img = torch.full((3, 24, 32), 0.5)
    depth = torch.full((24, 32), 1.2)
    out = render_frame_exact(img, depth, 2.0, src, (640, 960), origin=(300, 460))
    k, _ = src(np.zeros(1), np.zeros(1), 1.2, 2.0)
    # flat stays flat: float32 sums of ~10^2 kernel cells, in another order than k.sum(): a few eps
    assert torch.allclose(out, torch.full_like(out, 0.5 * float(k.sum())), rtol=1e-5, atol=0)
