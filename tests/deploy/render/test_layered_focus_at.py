"""The layered renderer with focus varying over the field (`focus_at`: a tilted sensor, a decentred element): each
anchor's PSF is drawn at its own cell size. numpy backend, torch-free."""

from __future__ import annotations

import numpy as np

from aat_deploy.optics.field import field_of
from aat_deploy.render.layered import LayeredConfig, render_layered

SENSOR = (64, 128)  # rows, cols
NEAR_M, FAR_M = 1.0, 0.4  # focus on the right half / the left half of the sensor


class GaussSource:
    """Gaussian PSFs whose width follows the thin-lens defocus (6 px per diopter), stored as the surrogates store
    them: (N, k, k) energy per cell, cells of `scale` pixels growing with the blur."""

    k = 9

    def blur_px(self, depth_m, focus_m):
        return 6.0 * np.abs(1.0 / np.asarray(depth_m, np.float64) - 1.0 / np.asarray(focus_m, np.float64))

    def scale(self, depth_m, focus_m):
        return np.maximum(1.0, (self.blur_px(depth_m, focus_m) + 2.0) / (self.k - 1))

    def __call__(self, x, y, depth_m, focus_m):
        _, _, d, f = (np.asarray(a, np.float64).ravel() for a in np.broadcast_arrays(x, y, depth_m, focus_m))
        s = self.scale(d, f)
        sig = np.maximum(self.blur_px(d, f) / 4.0, 0.6) / s  # in cells
        g = np.arange(self.k) - self.k // 2
        ker = np.exp(-(g[None, :, None] ** 2 + g[None, None, :] ** 2) / (2 * sig[:, None, None] ** 2))
        return (ker / ker.sum((1, 2), keepdims=True)).astype(np.float32), s.astype(np.float32)


def _field(r, c):
    return field_of(r, c, SENSOR)


def _split_focus(x, y, focus_m):
    """Anchors on the right half (x > 0) focused at NEAR_M, the others at FAR_M, whatever the frame's focus."""
    return np.where(np.asarray(x) > 0, NEAR_M, FAR_M)


def _second_moment_px(spot: np.ndarray) -> float:
    g = np.arange(spot.shape[0]) - spot.shape[0] // 2
    p = spot / spot.sum()
    return float(np.sqrt((p * (g[:, None] ** 2 + g[None, :] ** 2)).sum()))


def test_each_anchor_psf_at_its_own_cell_size():
    """Point sources whose cells' four anchors all lie on the right half are spread exactly as in a frame focused
    everywhere at the right half's focus; before, every anchor took the first (top-left, defocused) anchor's cell
    size, which drew the right half's sharp PSFs about three times too wide."""
    h, w = SENSOR
    img = np.zeros((1, h, w), np.float32)
    pts = [(24, 88), (40, 104), (24, 104)]  # inside the cells between anchor columns 80..112 (x > 0)
    for r, c in pts:
        img[0, r, c] = 1.0
    depth = np.full((h, w), 0.9, np.float32)  # 0.11 D from the right half's focus, 1.4 D from the left's
    cfg = LayeredConfig(cell_px=16)
    split = render_layered(img, depth, FAR_M, GaussSource(), _field, cfg, focus_at=_split_focus)
    uniform = render_layered(img, depth, NEAR_M, GaussSource(), _field, cfg)
    np.testing.assert_allclose(split[0, 16:56, 80:112], uniform[0, 16:56, 80:112], rtol=0, atol=2e-6)
    # the spot is the sharp one (about 1 px), not the defocused half's cell size applied to it
    r, c = pts[0]
    spot = split[0, r - 6:r + 7, c - 6:c + 7]
    assert _second_moment_px(spot) < 1.5
    assert abs(float(split.sum()) - len(pts)) < 1e-4  # energy conserved


def test_left_half_drawn_at_its_own_focus_too():
    """The same on the left half (the first anchors): a frame focused there everywhere gives the same spots."""
    h, w = SENSOR
    img = np.zeros((1, h, w), np.float32)
    img[0, 32, 24] = 1.0
    depth = np.full((h, w), 0.9, np.float32)
    cfg = LayeredConfig(cell_px=16)
    split = render_layered(img, depth, NEAR_M, GaussSource(), _field, cfg, focus_at=_split_focus)
    uniform = render_layered(img, depth, FAR_M, GaussSource(), _field, cfg)
    np.testing.assert_allclose(split[0, :, :48], uniform[0, :, :48], rtol=0, atol=2e-6)
    assert _second_moment_px(split[0, 20:45, 12:37]) > 2.5  # the defocused half's wide spot
