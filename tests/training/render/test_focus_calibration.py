"""The best-focus map's calibration puts each measured offset at the frame where the focus measure peaked.

A synthetic astigmatic lens: at field radius r an object at D diopters has its tangential focus in the frame
F_T = D (1 - a r^2) and its sagittal focus in F_S = D (1 - b r^2); the PSF is a Gaussian whose x width is smallest at
F_T and whose y width is smallest at F_S. The traced map's definition (the smallest RMS spot, sigma_x^2 + sigma_y^2)
puts best focus midway, F = D (1 - (a + b) r^2 / 2). A texture of vertical stripes has detail along x only, so the
focus measure peaks exactly at F_T: the two definitions differ by D (b - a) r^2 / 2, and by more the nearer the
object, as on the phone lens (BENCHMARKS.md, "Calibrating a camera"). The calibrated map must put the object in
focus where the measure peaks, also between the calibration's focus settings.
"""

from __future__ import annotations

import types

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from aat_deploy.focus.bestfocus import BestFocusMap  # noqa: E402

A, B = 1.2, -0.4  # tangential / sagittal focus coefficients
K_PX_PER_D, SIGMA0_PX = 1.5, 0.4
RADII = (0.0, 0.5)
W, H = 400, 300


def min_rms_map() -> BestFocusMap:
    """The synthetic lens's traced map: D*(r, F) = F / (1 - (a + b) r^2 / 2)."""
    radius = np.array([0.0, 0.5, 1.0])
    fd = np.linspace(1.0, 20.0, 39)
    obj = fd[None] / (1 - (A + B) * radius[:, None] ** 2 / 2)
    return BestFocusMap(radius, fd, obj, (4.0, 3.0), lens_name="synthetic astigmatic")


def measure_frame(d_obj: float, r: float) -> float:
    """The frame where the measure peaks for stripes varying along x: the tangential focus."""
    return d_obj * (1 - A * r * r)


class AstigmaticSim:
    """Renders a patch through the synthetic lens (the interface `measure_point` uses)."""

    def render_stack(self, img, depth, focus_m, origin):
        n = img.shape[-1]
        col = origin[1] + n / 2
        r = round(2 * col / W - 1, 6)  # measure_point's patch: column (1 + r) / 2 W - n / 2
        d = 1.0 / float(depth[0, 0])
        tex = img.numpy().transpose(1, 2, 0)
        frames = []
        for f in 1.0 / np.asarray(focus_m, np.float64):
            sx = np.hypot(SIGMA0_PX, K_PX_PER_D * (f - d * (1 - A * r * r)))
            sy = np.hypot(SIGMA0_PX, K_PX_PER_D * (f - d * (1 - B * r * r)))
            frames.append(cv2.GaussianBlur(tex, (0, 0), sigmaX=sx, sigmaY=sy,
                                           borderType=cv2.BORDER_REFLECT).transpose(2, 0, 1))
        return types.SimpleNamespace(frames=torch.from_numpy(np.stack(frames).astype(np.float32)))


def stripes(rng, h, w, split="train"):
    """Vertical stripes of random widths (detail along x only)."""
    widths = rng.integers(2, 6, size=w)
    v = np.repeat(rng.random(w), widths)[:w]
    return np.repeat(np.repeat(v[None, :, None], h, 0), 3, 2).astype(np.float32)


def calibrated_map(monkeypatch):
    import training.data.textures as textures
    import training.render.focus_calibration as fc

    monkeypatch.setattr(fc, "_simulator", lambda lens, cfg: AstigmaticSim())
    monkeypatch.setattr(textures, "photo_texture", stripes)
    lens = types.SimpleNamespace(sensor=types.SimpleNamespace(width_px=W, height_px=H))
    cfg = fc.CalibrationConfig(radii=RADII, focus_m=(0.2, 0.1, 1 / 15), sweep_d=5.0, n_sweep=51, crop_px=32,
                               margin_px=16, n_textures=2, psf="trace")
    return fc.calibrate(lens, min_rms_map(), cfg, progress=False)


def test_the_two_definitions_differ_on_the_synthetic_lens(monkeypatch):
    """The premise: off axis the measure peaks at the tangential focus, diopters from the min-RMS focus."""
    _, points = calibrated_map(monkeypatch)
    for p in points:
        expect = measure_frame(p["traced_object_diopters"], p["r"])
        assert p["measure_peak_focus_diopters"] == pytest.approx(expect, abs=0.03)
    off = [p for p in points if p["r"] == 0.5]
    assert min(abs(p["peak_minus_traced_focus_diopters"]) for p in off) > 0.9  # 1.1-3.3 D


@pytest.mark.parametrize("d_obj", [5.5, 7.0, 9.0, 11.0, 13.0, 15.0])
def test_the_calibrated_map_puts_objects_in_focus_where_the_measure_peaks(monkeypatch, d_obj):
    """Between and at the calibration's focus settings, the frame in which the calibrated map has the object in
    focus is the one where the measure peaks (within 0.05 D). Offsets placed at the settings' own focus instead of
    the measure's peak frame miss it by 0.25-0.55 D here (0.01 D at 5.5 D, near a setting)."""
    fmap, _ = calibrated_map(monkeypatch)
    r = 0.5
    f = np.linspace(1.0, 20.0, 19001)
    d = fmap.frame_diopters(1.0 / f, [r])[:, 0]
    assert np.all(np.diff(d) > 0)
    assert np.interp(d_obj, d, f) == pytest.approx(measure_frame(d_obj, r), abs=0.05)
    d0 = fmap.frame_diopters(1.0 / f, [0.0])[:, 0]  # on axis both definitions agree: no offset
    assert np.interp(d_obj, d0, f) == pytest.approx(d_obj, abs=0.02)


def test_offset_grid_is_exact_at_each_points_peak_frame():
    """offset_grid alone: each point's offset is found at its measure-peak frame, held beyond the points, and
    radii without points take their neighbours'."""
    from training.render.focus_calibration import offset_grid

    fmap = min_rms_map()
    pts = [{"r": 0.0, "measure_peak_focus_diopters": 5.0, "offset_diopters": 0.1},
           {"r": 0.0, "measure_peak_focus_diopters": 9.0, "offset_diopters": 0.5},
           {"r": 0.5, "measure_peak_focus_diopters": 4.0, "offset_diopters": -1.0},
           {"r": 0.5, "measure_peak_focus_diopters": 12.0, "offset_diopters": -3.0},
           {"r": 0.5, "measure_peak_focus_diopters": float("nan"), "offset_diopters": float("nan")},
           {"r": 0.8, "offset_diopters": float("nan")}]
    off = offset_grid(fmap, pts)
    fd = fmap.focus_diopters
    assert off.shape == fmap.object_diopters.shape
    assert np.interp(9.0, fd, off[0]) == pytest.approx(0.5)
    assert np.interp(7.0, fd, off[0]) == pytest.approx(0.3)
    assert np.interp(8.0, fd, off[1]) == pytest.approx(-2.0)
    assert off[0, 0] == pytest.approx(0.1) and off[1, -1] == pytest.approx(-3.0)  # held beyond the points
    np.testing.assert_allclose(off[2], off[1])  # r = 1: beyond the last radius with points (0.8 has none)
