"""The layered renderer's numpy backend takes its FFTs from scipy.fft (faster on its batches of small blocks, issue 32):
its frames must be numpy.fft's to float32 rounding. (Noise drawn on frames that moved by float32 rounding can take
another path of numpy's Poisson sampler: noisy twins are then another draw, BENCHMARKS "Full-frame speed".)
Torch-free."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.fft
from conftest import ROOT, rel_err
from deploy_fixtures import synthetic_scene

from aat_deploy.lens.io import load_lens
from aat_deploy.optics.field import field_of
from aat_deploy.render import layered
from aat_deploy.render.layered import LayeredConfig, render_layered
from aat_deploy.render.sources import GaussianSource

LENS = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
SENSOR = (LENS.sensor.height_px, LENS.sensor.width_px)
pytestmark = pytest.mark.numerics  # two FFT implementations
# two float32 FFTs of blocks up to ~100 px: each ~log2(N) eps of the largest value apart
TOL = 1e-5


def test_numpy_backend_uses_scipy_fft():
    assert layered.NUMPY.fft is scipy.fft


@pytest.mark.parametrize("occlusion", [False, True])
def test_scipy_fft_frames_equal_numpy_fft_frames(monkeypatch, occlusion):
    """Frames near and far from focus (sharp layers: small blocks; blurred ones: coarse grids) with both FFTs."""
    tex, depth = synthetic_scene(48, 96)  # two depths (0.8 m, 3 m): a depth edge
    rgb = np.ascontiguousarray(tex.transpose(2, 0, 1))
    cfg = dataclasses.replace(LayeredConfig(cell_px=16), occlusion=occlusion)
    src = GaussianSource(LENS)

    def field(r, c):
        return field_of(r, c, SENSOR, (200, 300))

    for f in (0.6, 1.5, 3.0):
        a = render_layered(rgb, depth, f, src, field, cfg)
        with monkeypatch.context() as m:
            m.setattr(layered.NUMPY, "fft", np.fft)
            b = render_layered(rgb, depth, f, src, field, cfg)
        assert a.dtype == b.dtype == np.float32 and a.shape == b.shape
        assert float(np.abs(a - b).max()) > 0  # two implementations, not one called twice
        assert rel_err(a, b) < TOL, f
