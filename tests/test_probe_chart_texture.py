"""benchmarks/probes/chart_texture: the textures' statistics (power by band, orientation) by hand, and the probe's
textures: `leaves-blur0` is the chart's own dead leaves, `soft leaves` the chart bench_calibrate now shoots."""

from __future__ import annotations

import numpy as np
import pytest

from aat_deploy.calibrate.chart import ChartSpec, chart_px, dead_leaves, make_chart
from benchmarks.probes import chart_texture as ct


def test_band_shares_and_orientation_by_hand():
    rng = np.random.default_rng(0)
    noise = rng.random((256, 256)).astype(np.float32) + 1.0
    s = ct.statistics(noise)
    # white noise: power spread evenly over the frequency square, so a band's share is its area there
    assert s["band_power_share"]["0.25-0.5"] == pytest.approx(np.pi * (0.5 ** 2 - 0.25 ** 2), abs=0.04)
    assert s["band_power_share"]["0-0.03"] == pytest.approx(np.pi * 0.03 ** 2, abs=0.01)
    import cv2

    smooth = cv2.GaussianBlur(noise, (0, 0), 3.0)
    assert ct.statistics(smooth)["band_power_share"]["0.25-0.5"] < 0.01
    stripes = np.tile(np.sin(np.arange(256) * 0.4)[None, :], (256, 1)).astype(np.float32) + 2.0
    assert ct.statistics(stripes)["axis_gradient_share"] == pytest.approx(1.0)


def test_the_probes_textures_are_the_charts():
    spec = ChartSpec(size_mm=(80.0, 60.0), markers=(3, 2), dpi=25.4 * 3 * 200 / (80 / 1.3), seed=70)
    wp, hp = chart_px(spec)
    leaves = dead_leaves(hp, wp, 1.5, 0.1 * 60 * spec.px_per_mm, np.random.default_rng(70))
    np.testing.assert_array_equal(ct.texture_for("leaves-blur0", spec, 3), leaves)
    other = ct.texture_for("leaves-blur0@1", spec, 3)
    assert other.shape == leaves.shape and np.mean(other != leaves) > 0.5  # another draw
    soft = ct.texture_for("leaves-blur0.7", spec, 3)
    # the adopted chart (aat-calibrate chart --frame-px) is the probe's leaves-blur0.7, markers aside
    import dataclasses

    from aat_deploy.calibrate.chart import texture_sigma_for

    img, _ = make_chart(dataclasses.replace(spec, texture_sigma_mm=texture_sigma_for(80 / 1.3, 200)))
    img_probe, _ = make_chart(spec, soft)
    assert np.mean(img == img_probe) > 0.999
    with pytest.raises(ValueError, match="unknown chart texture"):
        ct.texture_for("checkerboard", spec, 3)
