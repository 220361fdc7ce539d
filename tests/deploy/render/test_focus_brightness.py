"""The focus_brightness effect against its definition: irradiance falls with the square of the exit pupil's
distance from the sensor, which grows as the lens moves out to focus (the focus table and exit pupil of the
PSF surrogate, as the torch-free twins have them)."""

import numpy as np
import pytest
from conftest import LENSES, ROOT

from aat_deploy.lens.io import load_lens
from aat_deploy.render import effects as fx
from aat_deploy.render.effects.focus_brightness import irradiance_gains
from aat_deploy.render.sources import OnnxSource


@pytest.fixture(scope="module")
def ctx():
    lens = load_lens(LENSES / "canon_rf50mm_f1.8.json")
    src = OnnxSource(ROOT / "models" / "psf_rf50.onnx", lens)
    s = lens.sensor
    return fx.SimContext(lens, (s.height_px, s.width_px), (0, 0), src, src.focus_table(), src.exit_pupil_z_mm())


def test_gains_follow_the_exit_pupil_distance(ctx):
    focus = np.array([0.6, 1.0, 2.0, 6.0, 50.0])
    g = irradiance_gains(focus, ctx)
    table, xp = ctx.focus_table(), ctx.exit_pupil_z_mm
    z = np.interp(1 / focus, table.diopters, table.sensor_z_mm)
    np.testing.assert_allclose(g, ((table.sensor_z_mm[0] - xp) / (z - xp)) ** 2, rtol=1e-9)
    assert np.all(np.diff(g) > 0) and g[-1] == pytest.approx(1.0, abs=0.005)
    assert 0.75 < g[0] < 0.9  # the RF50 at 0.6 m: its exit pupil 10 % farther from the sensor than at infinity
    np.testing.assert_allclose(irradiance_gains(focus, ctx, 0.5) ** 2, g, rtol=1e-9)
    assert np.all(irradiance_gains(focus, ctx, 0.0) == 1.0)


def test_stack_multiplies_each_frame(ctx):
    frames = np.random.default_rng(0).random((3, 3, 8, 12)).astype(np.float32)
    focus = np.array([0.6, 1.5, 8.0])
    out = fx.make("focus_brightness", coefficient=1.0).stack(frames, focus, ctx, np.random.default_rng(0))
    np.testing.assert_allclose(out, frames * irradiance_gains(focus, ctx)[:, None, None, None].astype(np.float32),
                               rtol=1e-6)
    assert "focus_brightness" in fx.names()
