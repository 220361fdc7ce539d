"""Where a camera calibration measured what is in focus, and where its map is extrapolated (`measured_mask`):
beyond the farthest tile's field radius, outside the calibrated focus range, or at objects no chart showed."""

from __future__ import annotations

import numpy as np

from aat_deploy.calibrate import CameraCalibration, CameraIdentity, FieldPoly, FocusError, measured_mask
from aat_deploy.calibrate.format import field_grid, field_radius_of, in_focus_diopters

W, H = 64, 48


def calibration(radius_max=0.8, object_range_d=(0.9, 2.6)) -> CameraCalibration:
    """A field term of +1 D x rho^4-like curvature (x^4 + y^4 ... as monomials x^2, y^2 squared), calibrated over
    on-axis focus 1-2 D, held beyond radius_max."""
    terms = np.array([[2, 0], [0, 2], [4, 0], [0, 4], [2, 2]])
    coef = np.array([[0.0], [0.0], [0.5], [0.5], [1.0]])  # 0.5 (x^2 + y^2)^2 ... nearer at the edge
    fit = {} if object_range_d is None else {"object_range_d": list(object_range_d)}
    return CameraCalibration(CameraIdentity(), (W, H), FocusError(),
                             FieldPoly(terms, coef, (1.0, 2.0), radius_max, W / H), fit=fit)


def test_beyond_the_farthest_tile_and_the_focus_range_is_flagged():
    cal = calibration(object_range_d=None)
    m = measured_mask(cal, [1 / 1.5, 1 / 3.0], H, W)  # 1.5 D inside the focus range, 3 D beyond it
    assert m.shape == (2, H, W) and m.dtype == bool
    x, y = field_grid(H, W)
    rad = field_radius_of(x, y, W / H)
    np.testing.assert_array_equal(m[0], rad <= 0.8)  # the corners (radius > 0.8) are extrapolated
    assert not m[1].any()  # a frame focused outside the calibrated range: all extrapolated
    assert measured_mask(calibration(radius_max=None, object_range_d=None), [1 / 1.5], H, W).all()


def test_objects_no_chart_showed_are_flagged():
    cal = calibration(radius_max=None, object_range_d=(0.9, 2.0))
    d = in_focus_diopters(cal, [1 / 1.8], H, W)[0]
    m = measured_mask(cal, [1 / 1.8], H, W)[0]
    assert (d > 2.0).any() and (d <= 2.0).any()  # the edge's in-focus objects are nearer than any chart's
    np.testing.assert_array_equal(m, d <= 2.0 + 1e-9)


def test_the_focus_method_warns_when_the_map_is_extrapolated():
    from aat_deploy.focus import classical_depth

    rng = np.random.default_rng(0)
    stack = rng.random((4, 3, H, W)).astype(np.float32)
    focus = 1 / np.array([1.2, 1.4, 1.6, 1.8])
    warned = classical_depth(stack, focus, calibration=calibration()).warnings
    assert any("measured nothing" in w for w in warned), warned
    quiet = classical_depth(stack, focus, calibration=calibration(radius_max=None, object_range_d=None))
    assert not any("measured nothing" in w for w in quiet.warnings)
