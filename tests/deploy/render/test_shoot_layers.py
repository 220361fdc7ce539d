"""`shoot(layer_blur_px=...)`: the depth layers' spacing reaches the layered renderer (benchmarks/probes/tile_bias.py
renders chart sweeps with layers 4 x finer to see what the layers do to a tilted chart's tiles)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import ROOT

from aat_deploy.capture.virtual import shoot
from aat_deploy.lens.io import load_lens

W, H = 64, 48


def _scene():
    lens = load_lens(ROOT / "lenses" / "canon_rf50mm_f1.8.json")
    lens = dataclasses.replace(lens, sensor=lens.sensor.with_resolution(W, H))
    rgb = np.random.default_rng(0).random((3, H, W)).astype(np.float32) * 0.6
    return lens, rgb


def test_finer_layers_change_a_tilted_plane_and_not_a_flat_one():
    lens, rgb = _scene()
    ramp = (1.0 / np.linspace(1.0, 1.6, W, dtype=np.float32))[None].repeat(H, 0)  # 1.0-1.6 D across the frame
    flat = np.full((H, W), 1 / 1.3, np.float32)
    focus = np.array([1 / 1.3])
    tilt = [shoot(lens, rgb, ramp, focus, [], layer_blur_px=b, cell_px=16)[0] for b in (1.0, 0.25)]
    level = [shoot(lens, rgb, flat, focus, [], layer_blur_px=b, cell_px=16)[0] for b in (1.0, 0.25)]
    assert np.max(np.abs(tilt[0] - tilt[1])) > 1e-3  # more layers: each pixel's light nearer its own depth
    np.testing.assert_allclose(level[0], level[1], atol=1e-6)  # one depth is one layer whatever the spacing


def test_a_bad_layer_spacing_is_refused():
    lens, rgb = _scene()
    with pytest.raises(ValueError, match="LayeredConfig"):
        shoot(lens, rgb, np.full((H, W), 1.0, np.float32), np.array([1.0]), [], layer_blur_px=0.0)
