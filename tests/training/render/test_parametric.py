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



@pytest.mark.parametrize("focus_m", [2.0, 5.0, 20.0])
def test_blur_grows_with_the_diopters_from_the_maps_best_focus_even_beyond_infinity(focus_m):
    """Field curvature of -0.3 D at the corner: frames focused at 5 m and 20 m put the corner's best focus beyond
    infinity (-0.1 D, -0.25 D; as a real field-curved lens focused far does). An object at 40 m (0.025 D) is then
    blurred by its distance to that focus, as the map the net is told says; the renderer used to focus such frames
    at 10 km instead, which rendered the object nearly sharp (one render in ten disagreed with its own map)."""
    cam = Camera(35.0, 1.8, (400, 600), 0.02, Aberrations(c2=-0.3, b0_px=0.0, shape_p=2.0))
    x, y = 1.0, 1.0  # the corner: r = 1
    best = float(cam.frame_diopters([focus_m], 1, 1, (0, 599))[0, 0, 0])
    assert best == pytest.approx(1 / focus_m - 0.3, abs=0.01)
    src = ParametricSource(cam, [focus_m], size=41)
    ker, s = src(np.array([x]), np.array([y]), np.array([40.0]), np.array([focus_m]))
    vx, vy, _ = _moments(ker[0], float(s[0]))
    blur = 4 * np.sqrt(0.5 * (vx + vy) - s[0] ** 2 / 16)  # sigma = blur / 4, minus the half-cell floor
    expected = cam.defocus_px_per_diopter(1e3) * abs(0.025 - (1 / focus_m - 0.3))
    assert blur == pytest.approx(expected, rel=0.08)
