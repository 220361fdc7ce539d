"""The chart's texture softening (`ChartSpec.texture_sigma_mm`, `aat-calibrate chart --frame-px`): the dead leaves
blurred to photographs' share of fine detail (benchmarks/probes/chart_texture.py), the markers left sharp."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from aat_deploy.calibrate.chart import SOFT_SENSOR_PX, ChartSpec, make_chart, texture_sigma_for
from aat_deploy.cli import calibrate as cli

K = 3  # chart image pixels per camera pixel, as the benchmark's charts


def _finest_share(img_u8: np.ndarray, k: int = K) -> float:
    """Power share at 0.25-0.5 cycles per camera pixel of the chart's image seen at k image px per camera px."""
    x = cv2.resize(img_u8.astype(np.float32), (img_u8.shape[1] // k, img_u8.shape[0] // k),
                   interpolation=cv2.INTER_AREA)
    n = 32
    f = np.fft.fftfreq(n)
    fr = np.hypot(f[:, None], f[None, :])
    p = np.zeros((n, n))
    for r in range(0, x.shape[0] - n + 1, n):
        for c in range(0, x.shape[1] - n + 1, n):
            t = x[r:r + n, c:c + n]
            p += np.abs(np.fft.fft2((t - t.mean()) * np.outer(np.hanning(n), np.hanning(n)))) ** 2
    return float(p[fr > 0.25].sum() / p[fr > 0].sum())


def _spec(sigma_mm: float) -> ChartSpec:
    w_mm, frame_px = 120.0, 200  # a chart 1.3 x the frame's width, 200 camera px across that frame
    return ChartSpec(size_mm=(w_mm, w_mm / 1.5), markers=(3, 2), dpi=25.4 * K * frame_px / (w_mm / 1.3), seed=3,
                     texture_sigma_mm=sigma_mm)


def test_sigma_is_the_camera_pixels_footprint_on_the_chart():
    assert texture_sigma_for(600.0, 6000) == pytest.approx(SOFT_SENSOR_PX * 0.1)
    assert texture_sigma_for(100.0, 200, sensor_px=1.0) == pytest.approx(0.5)
    with pytest.raises(ValueError):
        texture_sigma_for(100.0, 0)
    with pytest.raises(ValueError, match="texture softening"):
        ChartSpec(texture_sigma_mm=-0.1)


def test_softening_leaves_photographs_share_of_fine_detail_and_the_markers_sharp():
    sharp, layout = make_chart(_spec(0.0))
    sigma = texture_sigma_for(120.0 / 1.3, 200)
    soft, layout_soft = make_chart(_spec(sigma))
    # the sharp dead leaves put ~15 % of their power at 0.25-0.5 cycles per camera pixel (photographs ~3 %); softened,
    # what is left there is mostly the markers' edges (drawn sharp)
    assert _finest_share(sharp) > 0.12 and _finest_share(soft) < 0.5 * _finest_share(sharp)
    assert layout_soft.spec["texture_sigma_mm"] == pytest.approx(sigma) and layout.spec["texture_sigma_mm"] == 0.0
    # every marker (with its quiet zone) is drawn after the softening: the same pixels
    px = layout.px_per_mm
    w_mm, h_mm = layout.size_mm
    for c in layout.corners_mm:
        (x0, y0), (x1, y1) = c[0], c[2]
        r0, r1 = int(np.ceil((y0 + h_mm / 2) * px)), int(np.floor((y1 + h_mm / 2) * px))
        c0, c1 = int(np.ceil((x0 + w_mm / 2) * px)), int(np.floor((x1 + w_mm / 2) * px))
        np.testing.assert_array_equal(soft[r0:r1, c0:c1], sharp[r0:r1, c0:c1])
    np.testing.assert_array_equal(layout_soft.corners_mm, layout.corners_mm)
    assert np.abs(soft.astype(int) - sharp).mean() > 5  # the texture did change


def test_the_cli_softens_to_the_frame_and_refuses_two_softenings(tmp_path, capsys):
    out = tmp_path / "chart.png"
    assert cli.main(["chart", "--out", str(out), "--size-mm", "300,200", "--dpi", "60", "--frame-px", "1200",
                     "-q"]) == 0
    layout = json.loads(out.with_suffix(".json").read_text())
    assert layout["spec"]["texture_sigma_mm"] == pytest.approx(SOFT_SENSOR_PX * 300 / 1200)
    assert json.loads(capsys.readouterr().out)["texture_sigma_mm"] == pytest.approx(0.175)
    with pytest.raises(SystemExit) as e:
        cli.main(["chart", "--out", str(tmp_path / "c2.png"), "--dpi", "60", "--frame-px", "1200",
                  "--texture-sigma-mm", "0.1"])
    assert e.value.code == 2 and not (tmp_path / "c2.png").exists()
    assert cli.main(["chart", "--out", str(tmp_path / "c3.png"), "--size-mm", "300,200", "--dpi", "60", "-q"]) == 0
    assert json.loads((tmp_path / "c3.json").read_text())["spec"]["texture_sigma_mm"] == 0.0
