"""The focus measures' registry (aat_deploy.focus.measures.MEASURES): a new measure is one entry that the method's
configuration and its estimator take, with nothing else touched."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from aat_deploy.focus import measures
from aat_deploy.focus.method import FocusConfig


def test_entries_and_their_exponents():
    assert set(measures.MEASURES) == {"lape", "sml", "mlap2", "tenengrad", "multiscale", "narrowband"}
    assert FocusConfig(measure="sml").tail_exponent == 0.5 and FocusConfig(measure="mlap2").tail_exponent == 1.0
    with pytest.raises(ValueError, match="unknown measure 'fog'.*lape"):
        FocusConfig(measure="fog")


def test_a_new_measure_is_one_entry(monkeypatch):
    def brightness(g, window_px, step, levels):  # not a good measure: it only has to be called
        return np.abs(g).astype(np.float32)

    monkeypatch.setitem(measures.MEASURES, "brightness", measures.FocusMeasure(brightness, tail_exponent=0.25))
    stack = np.random.default_rng(0).random((3, 3, 8, 8), dtype=np.float32)
    vol = measures.focus_volume(stack, "brightness")
    np.testing.assert_array_equal(vol, measures.grey(stack))
    assert FocusConfig(measure="brightness").tail_exponent == 0.25


def _astigmatic_stack(tex: np.ndarray, focus_d: np.ndarray, fx_d: float, fy_d: float) -> np.ndarray:
    """(F, H, W) frames of a grey texture blurred as by an astigmatic lens: along x sharpest at fx_d, along y at
    fy_d (Gaussian sigma 0.6 px + 0.15 px per diopter from each focus: slow, as an aberrated phone lens off axis)."""
    return np.stack([cv2.GaussianBlur(tex, (0, 0), sigmaX=0.6 + 0.15 * abs(f - fx_d),
                                      sigmaY=0.6 + 0.15 * abs(f - fy_d), borderType=cv2.BORDER_REFLECT)
                     for f in focus_d])


def _peak(vol: np.ndarray, focus_d: np.ndarray) -> float:
    c = vol[:, 16:-16, 16:-16].mean((1, 2)).astype(np.float64)
    i = int(np.clip(np.argmax(c), 1, len(c) - 2))
    y0, y1, y2 = np.log(c[i - 1:i + 2])
    return float(focus_d[i] + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2) * (focus_d[1] - focus_d[0]))


def test_narrowband_peak_does_not_follow_the_textures_orientation():
    """Sagittal and tangential foci 1 D apart (x sharpest at 0, y at 1 D): a texture of mostly vertical stripes
    (detail along x) and one of mostly horizontal stripes, each with a little isotropic detail. mlap2 weighs the
    two directions by the texture's energy, so each texture peaks at its dominant direction's focus (1 D apart);
    narrowband weighs its orientations alike at each pixel: both textures peak at the same focus."""
    rng = np.random.default_rng(0)
    noise = lambda: rng.random((96, 96)).astype(np.float32) - 0.5  # noqa: E731
    along_x = cv2.GaussianBlur(noise(), (0, 0), sigmaX=0.3, sigmaY=6.0)  # varies fast along x: vertical stripes
    along_y = cv2.GaussianBlur(noise(), (0, 0), sigmaX=6.0, sigmaY=0.3)
    iso = cv2.GaussianBlur(noise(), (0, 0), 0.3)
    tex = {"x": along_x / along_x.std() + 0.2 * iso / iso.std(), "y": along_y / along_y.std() + 0.2 * iso / iso.std()}
    focus = np.linspace(-3.0, 4.0, 71)
    peaks = {m: {k: _peak(measures.focus_volume(_astigmatic_stack(t, focus, 0.0, 1.0), m, 15.0), focus)
                 for k, t in tex.items()} for m in ("mlap2", "narrowband")}
    moved = {m: abs(p["x"] - p["y"]) for m, p in peaks.items()}
    assert moved["mlap2"] > 0.8, peaks  # the broad-band measure follows the texture
    assert moved["narrowband"] < 0.05, peaks
    assert all(-0.1 < p < 1.1 for p in peaks["narrowband"].values()), peaks


def test_narrowband_hand_cases():
    """A flat frame adds nothing; a stack's values are at most the number of orientations; the
    Gabor pair has no DC and unit response at its band, as a quadrature pair."""
    g = np.random.default_rng(1).random((3, 32, 32)).astype(np.float32)
    v = measures.narrowband(g, 9)
    assert v.shape == g.shape and v.dtype == np.float32 and float(v.max()) <= measures.NARROWBAND_ORIENTATIONS + 1e-5
    assert float(v.max(0).min()) >= 1 - 1e-5  # each orientation reaches 1 in some frame
    even, odd = measures.gabor_pair(0.35, 0.0)
    assert abs(float(even.sum())) < 1e-5
    xx = np.arange(even.shape[1]) - even.shape[1] // 2
    wave = np.exp(2j * np.pi * 0.35 * xx)[None, :]
    e, o = abs(float((even * wave).sum().real)), abs(float((odd * wave).sum().imag))
    np.testing.assert_allclose(e, o, rtol=0.05)  # a quadrature pair: the energy does not depend on the phase
    flat = np.full((4, 32, 32), 0.5, np.float32)
    assert float(measures.narrowband(flat, 9).max()) < 0.01  # float rounding of the flat frame only
