"""The simulator's effect registry: each effect switched on alone changes what it should, and only that."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import ROOT

from aat_deploy.lens.io import load_lens
from aat_deploy.render import effects as fx
from aat_deploy.render.effects.focus_breathing import breathing_scale
from aat_deploy.render.effects.noise import poisson_gaussian
from training.render.layered import LayeredConfig
from training.render.simulator import Simulator
from training.render.sources import OnnxPSF

LENS = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
SRC = OnnxPSF(ROOT / "models/psf_rf50.onnx", LENS, threads=1)
CFG = LayeredConfig(cell_px=32)


def _sim(*names, **params):
    return Simulator(LENS, SRC, [fx.make(n, **params.get(n, {})) for n in names], CFG)


def test_registry_lists_effects_and_rejects_unknown():
    assert {"aberrations", "vignetting", "noise", "focus_breathing", "chromatic"} <= set(fx.names())
    with pytest.raises(ValueError, match="unknown effect 'blur'"):
        fx.make("blur")
    with pytest.raises(ValueError, match="unknown parameter"):
        fx.make("noise", gain=2)
    assert [e.name for e in fx.parse("noise,aberrations")] == ["aberrations", "noise"]  # PSF first, sensor last


def _corner_scene(h=64, w=64, seed=0):
    rng = np.random.default_rng(seed)
    img = torch.from_numpy(rng.random((3, h, w))).float()
    return img, torch.full((h, w), 0.9)


def test_aberrations_change_the_corners_more_than_the_centre():
    img, depth = _corner_scene()
    hs, ws = LENS.sensor.height_px, LENS.sensor.width_px
    diff = {}
    for name, origin in (("centre", (hs // 2 - 32, ws // 2 - 32)), ("corner", (0, 0))):
        thin = _sim().render_stack(img, depth, [0.9], origin).frames[0]  # in focus
        real = _sim("aberrations").render_stack(img, depth, [0.9], origin).frames[0]
        diff[name] = float((thin - real).abs().mean())
    assert diff["corner"] > 3 * diff["centre"], diff


def test_vignetting_darkens_corners_by_traced_ratio_times_cos4():
    flat = torch.full((3, 32, 32), 0.5)
    depth = torch.full((32, 32), 2.0)
    hs, ws = LENS.sensor.height_px, LENS.sensor.width_px
    sim = _sim("aberrations", "vignetting")
    centre = sim.render_stack(flat, depth, [2.0], (hs // 2 - 16, ws // 2 - 16)).frames[0]
    corner = sim.render_stack(flat, depth, [2.0], (0, 0)).frames[0]
    assert float(centre.mean()) == pytest.approx(0.5, rel=0.01)  # on axis: nothing lost
    src = sim.source(sim.context((0, 0)))
    x, y = -1 + 2 * 16 / ws, 1 - 2 * 16 / hs  # the corner crop's centre
    ri = float(src.relative_illumination(x, y, 2.0, 2.0)[0])
    assert ri < 0.8  # RF50 at f/1.8: strong fall-off in the corner
    assert abs(float(corner[:, 8:24, 8:24].mean()) / 0.5 - ri) < 0.02
    # without the effect, a flat field stays flat everywhere
    plain = _sim("aberrations").render_stack(flat, depth, [2.0], (0, 0)).frames[0]
    assert float(plain.mean()) == pytest.approx(0.5, rel=0.01)


def test_noise_is_poisson_gaussian_in_raw_units():
    rng = np.random.default_rng(0)
    for level in (0.05, 0.5):
        x = np.full(200000, level)
        y = poisson_gaussian(x, 4000.0, 5.0, rng)
        assert abs(y.mean() - level) < 3 * np.sqrt(level / 4000 / len(x)) + 1e-6
        var_expected = level / 4000 + (5.0 / 4000) ** 2
        assert abs(y.var() / var_expected - 1) < 0.03
    img, depth = _corner_scene(16, 16)
    a = _sim("noise").render_stack(img, depth, [0.9], rng=np.random.default_rng(1)).frames
    b = _sim().render_stack(img, depth, [0.9]).frames
    assert 0.001 < float((a - b).std()) < 0.05


def test_focus_breathing_magnifies_near_focus_about_the_axis():
    s_near, s_far = breathing_scale(LENS, [0.4, 10.0])
    assert s_near > s_far > 1.0 and s_near - 1 > 0.02  # ~ EFL / (0.4 m) of extra extension
    hs, ws = LENS.sensor.height_px, LENS.sensor.width_px
    h, w = 40, 40
    origin = (hs // 2 - 20, ws // 2 - 8)  # the axis is 8 px from the crop's left edge
    img = torch.zeros(1, h, w)
    img[0, :, 30] = 1.0  # a vertical line 22.5 px right of the axis (moves ~4 px out at 0.4 m)
    depth = torch.full((h, w), 0.4)
    sim = Simulator(LENS, SRC, [fx.make("focus_breathing")], CFG)
    out = sim.render_stack(img.expand(3, h, w).contiguous(), depth, [0.4], origin).frames[0, 0]
    ref = _sim().render_stack(img.expand(3, h, w).contiguous(), depth, [0.4], origin).frames[0, 0]
    cols = torch.arange(w, dtype=torch.float64) + 0.5
    centroid = float((out.mean(0).double() * cols).sum() / out.mean(0).sum())
    centroid_ref = float((ref.mean(0).double() * cols).sum() / ref.mean(0).sum())
    axis_col = ws / 2 - origin[1]
    assert abs((centroid - axis_col) / (centroid_ref - axis_col) - s_near) < 0.005


def test_chromatic_gives_three_different_channel_psfs():
    sim = _sim("chromatic", chromatic={"n_rays": 256})
    src = sim.source(sim.context())
    k, s = src(np.array([0.0, 0.9]), np.array([0.0, -0.9]), np.array([1.0, 1.0]), np.array([1.0, 1.0]))
    assert k.shape == (2, 3, 11, 11)
    spread = (k * (torch.arange(11) - 5.0).pow(2)[None, None, :, None]).sum((2, 3)) / k.sum((2, 3))
    # focused at the design wavelength (589 nm): red (610 nm) is sharpest, green and blue defocus
    assert float(spread[0, 1]) > 1.2 * float(spread[0, 0]) and float(spread[0, 2]) > 1.2 * float(spread[0, 1])
    # lateral colour: in the corner the channels' centroids differ
    cx = (k * (torch.arange(11) - 5.0)[None, None, None, :]).sum((2, 3)) / k.sum((2, 3))
    assert float((cx[1, 0] - cx[1, 2]).abs()) > 0.05
