"""The any-camera data's parametric PSFs (training.render.parametric) against their definition: the kernel's second
moments are the thin-lens blur about the tangential and sagittal foci, and a rendered sweep of a flat textured plane
is sharpest where the camera's best-focus map says (what the net is told)."""

import numpy as np
import pytest

from aat_deploy.focus.measures import focus_volume
from aat_deploy.optics.field import field_of
from aat_deploy.render.layered import LayeredConfig, render_layered
from training.data.scenes import texture
from training.render.parametric import Aberrations, Camera, ParametricSource


def _moments(ker, scale):
    k = ker.shape[-1]
    off = (np.arange(k) - k // 2) * scale
    cols, up = off[None, :], -off[:, None]
    m = ker / ker.sum()
    return (m * cols**2).sum(), (m * up**2).sum(), (m * cols * up).sum()


def test_gaussian_kernel_has_the_thin_lens_blur_moments_along_the_radial_and_azimuthal_axes():
    cam = Camera(50.0, 2.0, (400, 600), 0.04, Aberrations(a2=0.3, b0_px=0.0, shape_p=2.0))
    src = ParametricSource(cam, [2.0], size=31)
    depth, focus = 1.0, 2.0
    x, y = 1.0, 0.0  # on the horizontal axis: radial = x (columns), azimuthal = y (rows)
    ker, s = src(np.array([x]), np.array([y]), np.array([depth]), np.array([focus]))
    vx, vy, cxy = _moments(ker[0], float(s[0]))
    r2 = cam.radius(x, y) ** 2
    best = 1 / focus + cam.shift_diopters(x, y, focus)
    b_rad = cam.blur_px(depth, 1 / (best + 0.5 * 0.3 * r2))
    b_az = cam.blur_px(depth, 1 / (best - 0.5 * 0.3 * r2))
    # sigma = blur / 4 per axis, plus the (0.5 cell)^2 floor folded into the half-axes (sigma^2 += s^2 / 16)
    assert vx == pytest.approx((b_rad / 4) ** 2 + s[0] ** 2 / 16, rel=0.05)
    assert vy == pytest.approx((b_az / 4) ** 2 + s[0] ** 2 / 16, rel=0.05)
    assert abs(cxy) < 1e-3 * vx
    assert vx != pytest.approx(vy, rel=0.2)  # astigmatic


def test_disk_profile_is_flat_inside_the_blur_and_empty_outside():
    cam = Camera(50.0, 2.0, (400, 600), 0.04, Aberrations(b0_px=0.0, shape_p=40.0))
    src = ParametricSource(cam, [2.0], size=31)
    ker, s = src(np.array([0.0]), np.array([0.0]), np.array([1.0]), np.array([2.0]))
    b = float(cam.blur_px(1.0, 2.0))
    k = ker[0]
    off = (np.arange(31) - 15) * float(s[0])
    rr = np.hypot(off[None, :], off[:, None])
    inside, outside = k[rr < 0.35 * b], k[rr > 0.65 * b]
    assert inside.min() > 0.9 * inside.max()
    assert outside.max() < 1e-3 * inside.max()


@pytest.mark.parametrize("c2", [0.3, -0.3])
def test_sweep_of_a_flat_plane_peaks_where_the_map_says(c2):
    """A plane at 2 m seen at the sensor's corner through a camera with strong field curvature: the frame that is
    sharpest there is the one whose map value is nearest 0.5 D, not the one focused nominally at 2 m."""
    cam = Camera(35.0, 1.8, (400, 600), 0.03, Aberrations(c2=c2, b0_px=0.5, shape_p=4.0))
    spacing = 0.04
    diopters = 0.5 + spacing * np.arange(-10, 11)
    focus = 1.0 / diopters
    h = w = 64
    origin = (0, 600 - w)  # the top-right corner, r near 1
    rng = np.random.default_rng(0)
    img = texture(rng, h + 32, w + 32).transpose(2, 0, 1).copy()
    depth = np.full((h + 32, w + 32), 2.0, np.float32)
    src = ParametricSource(cam, focus)
    o = (origin[0] - 16, origin[1] - 16)
    frames = np.stack([render_layered(img, depth, float(f), src, lambda r, c: field_of(r, c, (400, 600), o),
                                      LayeredConfig(cell_px=32)) for f in focus])[:, :, 16:-16, 16:-16]
    vol = focus_volume(frames, "mlap2", 9.0, prefilter_px=0.0).mean((1, 2))
    sharpest = int(np.argmax(vol))
    maps = cam.frame_diopters(focus, h, w, origin).mean((1, 2))
    expected = int(np.argmin(np.abs(maps - 0.5)))
    nominal = int(np.argmin(np.abs(diopters - 0.5)))
    assert abs(expected - nominal) >= 5  # the curvature moves best focus by several frames here
    assert abs(sharpest - expected) <= 1
