"""Fast layered renderer: orientation, energy, agreement with the exact per-pixel renderer, occlusion."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from aat_deploy.optics.field import field_of
from training.render.exact import render_frame_exact
from training.render.layered import LayeredConfig, layer_diopters, render_layered

SENSOR = (96, 128)  # rows, cols of a toy sensor
pytestmark = pytest.mark.numerics  # float32 FFT convolution vs direct sums and analytic values
# float32 FFTs of n x n tiles (n <= 64 here) err by ~log2(n^2) eps = 1.4e-6 of the signal (4e-7 seen)
FFT_REL = 5e-6


class ToySource:
    """An asymmetric PSF that varies smoothly with field and depth: a Gaussian blob whose width follows the
    defocus (4 px per diopter) plus a tail pointing right and up whose length grows with the field x.
    Exact storage convention: (N, k, k) energy per cell, cells of `scale` pixels."""

    k = 9

    def blur_px(self, depth_m, focus_m):
        return 4.0 * np.abs(1.0 / np.asarray(depth_m) - 1.0 / np.asarray(focus_m))

    def scale(self, depth_m, focus_m):
        return np.maximum(1.0, (self.blur_px(depth_m, focus_m) + 2.0) / (self.k - 1))

    def __call__(self, x, y, depth_m, focus_m):
        x, y, d, f = (np.asarray(a, dtype=np.float64).ravel() for a in np.broadcast_arrays(x, y, depth_m, focus_m))
        s = self.scale(d, f)
        sig = np.maximum(self.blur_px(d, f) / 4.0, 0.5) / s
        g = np.arange(self.k) - self.k // 2
        ker = np.exp(-(g[None, :, None] ** 2 + g[None, None, :] ** 2) / (2 * sig[:, None, None] ** 2))
        ker /= ker.sum((1, 2), keepdims=True)
        tail = np.zeros_like(ker)
        tail[:, self.k // 2 - 2, self.k // 2 + 3] = 1.0  # 2 cells up, 3 cells right
        a = 0.3 * (x + 1) / 2  # tail share grows across the field
        ker = (1 - a)[:, None, None] * ker + a[:, None, None] * tail
        return torch.from_numpy(ker).float(), torch.from_numpy(s).float()


def _field(origin=(0, 0)):
    return lambda r, c: field_of(r, c, SENSOR, origin)


def test_orientation_point_source_lands_right_and_up():
    src = ToySource()
    img = torch.zeros(1, 40, 40)
    img[0, 20, 20] = 1.0
    depth = torch.full((40, 40), 2.0)
    out = render_layered(img, depth, 2.0, src, _field((30, 80)), LayeredConfig(cell_px=16))
    r, c = divmod(int(out[0].argmax()), 40)
    assert (r, c) == (20, 20)  # in focus: the core stays
    # The tail goes 2 px up and 3 px right (true convolution); a correlation would put it down-left.
    assert float(out[0, 18, 23]) > 0.05 and float(out[0, 22, 17]) < 1e-6
    assert float(out.sum()) == pytest.approx(1.0, rel=1e-5)  # FFT_REL per pixel, mostly cancelling in the sum


def test_flat_field_stays_flat_and_energy_conserved():
    src = ToySource()
    g = torch.Generator().manual_seed(0)
    # One depth: light that leaves a pixel is replaced by its neighbours'. The tail share a(x) grows by
    # 0.3 / 128 per pixel across the field and the tail lands 3 px right of its source, so the level is
    # 0.25 (1 - a(q) + a(q - 3 px)) = 0.25 (1 - 0.9 / 128): what a true convolution gives, flat to FFT rounding.
    expected = 0.25 * (1 - 0.9 / 128)
    for d in (0.6, 1.0, 3.0):
        flat = render_layered(torch.full((3, 48, 64), 0.25), torch.full((48, 64), d), 1.0, src, _field())
        assert torch.allclose(flat, torch.full_like(flat, expected), rtol=FFT_REL, atol=0), d
    depth = 0.5 + 3 * torch.rand(48, 64, generator=g)  # energy is conserved whatever the depth
    img = torch.zeros(3, 48, 64)
    img[:, 16:32, 20:44] = torch.rand(3, 16, 24, generator=g)
    out = render_layered(img, depth, 1.0, src, _field())
    assert float(out.sum() / img.sum()) == pytest.approx(1.0, rel=1e-4)


def test_matches_exact_renderer_within_one_percent():
    src = ToySource()
    rng = np.random.default_rng(3)
    h, w = 64, 96
    img = torch.from_numpy(rng.random((3, h, w))).float()
    img = torch.nn.functional.avg_pool2d(img[None], 3, 1, 1)[0]  # some texture at every scale
    yy, xx = np.mgrid[0:h, 0:w]
    depth = torch.from_numpy(1.0 / (0.4 + 1.6 * xx / w + 0.3 * np.sin(yy / 9.0))).float()  # 0.5 .. 2.5 m
    origin = (10, 20)
    for focus in (0.7, 1.6):
        exact = render_frame_exact(img, depth, focus, src, SENSOR, origin)
        fast = render_layered(img, depth, focus, src, _field(origin), LayeredConfig(cell_px=16))
        rel = float((fast - exact).abs().mean() / exact.abs().mean())
        assert rel < 0.01, rel
        # and the field variation matters: a field-invariant render is much further off
        assert float((fast - img).abs().mean()) > 10 * float((fast - exact).abs().mean())


def test_layers_even_in_diopters_and_dense_enough():
    src = ToySource()
    inv = torch.tensor([0.2, 2.0])
    layers = layer_diopters(inv, src.blur_px, 1.0, LayeredConfig(layer_blur_px=0.5))
    assert np.allclose(np.diff(layers), np.diff(layers)[0])
    assert layers[[0, -1]] == pytest.approx([0.2, 2.0], rel=1e-7)  # the float32 inputs' rounding (6e-8)
    assert np.diff(layers)[0] * 4.0 <= 0.5 + 1e-9  # blur step between layers <= 0.5 px


def test_occlusion_mode_hides_background_behind_foreground():
    src = ToySource()
    h, w = 48, 64
    img = torch.zeros(1, h, w)
    img[0, :, 32:] = 1.0  # bright background on the right half ...
    depth = torch.full((h, w), 4.0)
    depth[:, :34] = 0.5  # ... partly behind a dark near object on the left (its edge at column 34)
    plain = render_layered(img, depth, 0.5, src, _field(), LayeredConfig(cell_px=16))
    occl = render_layered(img, depth, 0.5, src, _field(), LayeredConfig(cell_px=16, occlusion=True))
    # Focused on the near object: the blurred background must not bleed over the sharp occluder.
    assert float(occl[0, :, 26:31].mean()) < 0.5 * float(plain[0, :, 26:31].mean())
    assert float(occl[0, :, 40:].mean()) > 0.9 * float(plain[0, :, 40:].mean())


def test_torch_backend_spells_the_same_operations_as_numpy():
    """One algorithm, two backends (`aat_deploy.render.layered`): each operation torch spells differently gives
    numpy's result (float rounding apart), including the fold path of overlap-add (> 64 active cells) and the
    pooling, upsampling and resampling the coarse layers use."""
    from aat_deploy.render.layered import NUMPY, cells_to_pixels
    from training.render.layered import TORCH

    rng = np.random.default_rng(3)
    ny, nx, cc, r = 9, 10, 8, 3
    idx = np.argwhere(rng.random((ny, nx)) < 0.9)  # about 80 active cells
    assert len(idx) > 64
    blocks = rng.random((len(idx), 2, cc + 2 * r, cc + 2 * r))
    a = NUMPY.overlap_add(blocks, idx, ny, nx, cc, r)
    b = TORCH.overlap_add(torch.from_numpy(blocks), torch.from_numpy(idx), ny, nx, cc, r).numpy()
    np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12)
    img = rng.random((3, 12, 16))
    for op, args in (("box_mean", (4,)), ("upsample", (3,)), ("pad_edge", (5,)), ("pad_end", (2, 3))):
        np.testing.assert_allclose(getattr(TORCH, op)(torch.from_numpy(img), *args).numpy(),
                                   getattr(NUMPY, op)(img, *args), rtol=1e-12, atol=1e-14, err_msg=op)
    np.testing.assert_array_equal(TORCH.box_max(torch.from_numpy(img[0]), 4).numpy(), NUMPY.box_max(img[0], 4))
    k = rng.random((5, 7, 7))
    scale = np.array([1.0, 1.5, 2.0, 3.0, 4.5])
    np.testing.assert_allclose(cells_to_pixels(torch.from_numpy(k), torch.from_numpy(scale), 33).numpy(),
                               cells_to_pixels(k, scale, 33), rtol=1e-12, atol=1e-15)


def test_field_varying_focus_same_on_both_backends():
    """Focus varying over the field (`focus_at`: each anchor's PSF at its own focus and cell size): the torch
    backend renders what the numpy one does (float32 rounding)."""
    from aat_deploy.render.layered import render_layered as render_numpy

    src = ToySource()

    class NumpySource(ToySource):
        def __call__(self, *args):
            k, s = src(*args)
            return k.numpy(), s.numpy()

    def split(x, y, focus_m):  # the right half focused near, the left far: cell sizes 1 and 1.42
        return np.where(np.asarray(x) > 0, 0.9, 0.3)

    rng = np.random.default_rng(5)
    img = rng.random((2, 48, 64)).astype(np.float32)
    depth = np.full((48, 64), 1.0, np.float32)
    a = render_numpy(img, depth, 0.5, NumpySource(), _field(), LayeredConfig(cell_px=16), focus_at=split)
    b = render_layered(torch.from_numpy(img), torch.from_numpy(depth), 0.5, src, _field(), LayeredConfig(cell_px=16),
                       focus_at=split)
    np.testing.assert_allclose(b.numpy(), a, rtol=0, atol=2e-6)
