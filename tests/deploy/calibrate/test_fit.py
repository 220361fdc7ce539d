"""Calibration from rendered chart sweeps with a known truth (aat_deploy/calibrate: chart, pose, peaks, model, fit):
the chart's pose from its markers against the rendered pose, and a sensor tilt, a decentred element's asymmetry and
a scaled reported focus recovered within stated tolerances.

Sweeps are rendered torch-free by the virtual camera (`aat_deploy.capture.virtual.shoot`) through the RF50's
prescription-free stand-in at reduced resolution: its thin-lens Gaussian PSFs (EFL, pupil and sensor of the RF50,
320 x 214 px) with the registered effects. The truth is then the effects' own per-field focus: a frame focused at
F has in best focus, at field (x, y), the object at 1 / focus_at(x, y, F) (thin-lens blur is symmetric in
diopters, so the focus measure peaks exactly there)."""

from __future__ import annotations

import dataclasses
import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT

from aat_deploy.calibrate import in_focus_diopters
from aat_deploy.calibrate.chart import ChartSpec, make_chart
from aat_deploy.calibrate.fit import fit_calibration
from aat_deploy.calibrate.peaks import TileGrid, tile_peaks
from aat_deploy.calibrate.pose import (
    ChartPose,
    best_view,
    focal_from_view,
    intrinsics_matrix,
    plane_depth_mm,
    pose_from_view,
)
from aat_deploy.calibrate.scene import chart_scene
from aat_deploy.calibrate.sweep import Sweep, SweepError, measure_sweep
from aat_deploy.capture.virtual import shoot
from aat_deploy.lens.io import load_lens
from aat_deploy.optics.focus_table import paraxial_focus_table
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.render import effects as fx

TOLERANCE_TABLE = ROOT / "models" / "tolerance_f707fa2e186c0eca.json"  # the RF50's (lens_tolerance)
W, H = 320, 214


@lru_cache(maxsize=1)
def small_rf50():
    lens = load_lens(ROOT / "lenses" / "canon_rf50mm_f1.8.json")
    lens = dataclasses.replace(lens, sensor=lens.sensor.with_resolution(W, H))
    p = paraxial_data(lens)
    return lens, p.efl_mm / lens.sensor.pixel_mm, p.total_track_mm + p.bfl_mm - p.entrance_pupil_z_mm


@lru_cache(maxsize=8)
def chart_for(distance_m: float):
    """A chart 1.4 x the frame's width at that distance (as a user prints or displays one to fill the frame)."""
    lens, f_px, _ = small_rf50()
    w_mm = 1.4 * W / f_px * 1000 * distance_m
    return make_chart(ChartSpec(size_mm=(w_mm, w_mm / 1.5), markers=(6, 4), dpi=25.4 * 3.5 * W / w_mm))


@lru_cache(maxsize=16)
def render_sweep(distance_m: float, tilt: tuple, effects: str, step_d: float = 0.04, margin_d: float = 0.3,
                 shift_d: float = 0.0, seed: int = 0):
    """(Sweep, truth focus_at function, pose, depth) of a chart sweep; frames span the chart's diopters +-margin_d
    (shifted by shift_d)."""
    lens, f_px, pupil = small_rf50()
    img, layout = chart_for(distance_m)
    pose = ChartPose(distance_m, *tilt)
    rgb, depth = chart_scene(img, layout, pose, W, H, f_px, pupil)
    d = 1.0 / depth
    focus_d = np.arange(float(d.min()) - margin_d, float(d.max()) + margin_d, step_d) + shift_d
    frames, reported = shoot(lens, rgb * 0.6, depth, 1.0 / focus_d, effects.split(",") if effects else [],
                             seed=seed, cell_px=32)
    order = np.argsort(-reported)  # far to near
    ident = {"make": "aat", "model": "virtual camera", "lens": lens.name, "focal_length_mm": 49.56, "f_number": 1.88}
    sweep = Sweep(Path(f"sweep_{distance_m}"), frames[order], reported[order], ident, (W, H), 1.0)
    return sweep, layout, pose, depth, 1.0 / focus_d[order]


def truth_fn(effects: str):
    """focus_at(x, y, F) of the effects (None: focus is F everywhere)."""
    lens, _, _ = small_rf50()
    ctx = fx.SimContext(lens, (H, W), (0, 0), None, paraxial_focus_table(lens), None)
    return fx.focus_at(fx.parse(effects.split(",") if effects else []), ctx)


def map_error(cal, effects: str, true_focus_m, reported_m) -> np.ndarray:
    """(S, H, W) calibration minus truth, diopters, for frames reported at reported_m (truly at true_focus_m)."""
    fn = truth_fn(effects)
    yy, xx = np.mgrid[0:H, 0:W]
    x, y = 2 * (xx + 0.5) / W - 1, 1 - 2 * (yy + 0.5) / H
    truth = np.stack([1.0 / fn(x, y, f) if fn else np.full((H, W), 1.0 / f) for f in true_focus_m])
    return in_focus_diopters(cal, reported_m, H, W) - truth


# -- the chart and its pose ----------------------------------------------------------------------------------------
def test_chart_layout_round_trip_and_markers_are_found_in_the_image(tmp_path):
    from aat_deploy.calibrate.chart import ChartError, load_layout, write_chart
    from aat_deploy.calibrate.pose import detect

    png, js = write_chart(tmp_path / "chart.png", ChartSpec(size_mm=(300, 200), markers=(4, 3), dpi=60))
    layout = load_layout(js)
    assert len(layout.ids) == 12 and layout.corners_mm.shape == (12, 4, 2)
    assert png.read_bytes()[12:16] == b"IHDR" and b"pHYs" in png.read_bytes()[:64]  # prints at its size
    img, _ = make_chart(ChartSpec(size_mm=(300, 200), markers=(4, 3), dpi=60))
    view = detect(img, layout)
    assert view.markers == 12 and view.rms_px < 0.5
    # the homography maps chart mm to chart pixels: px_per_mm times (mm + half the size)
    p = np.array([[[50.0, -20.0]]])
    import cv2
    got = cv2.perspectiveTransform(p, view.homography)[0, 0]
    want = (np.array([50.0, -20.0]) + np.array([150.0, 100.0])) * layout.px_per_mm - 0.5
    np.testing.assert_allclose(got, want, atol=0.3)
    with pytest.raises(ChartError, match="exists"):
        write_chart(tmp_path / "chart.png", ChartSpec(size_mm=(300, 200), markers=(4, 3), dpi=60))
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "aat-chart-v1", "size_mm": [1, 2], "markers": [{"id": 1}]}')
    with pytest.raises(ChartError, match="bad.json"):
        load_layout(bad)


def test_pose_from_markers_agrees_with_the_rendered_pose():
    """At 320 x 214 px (markers of ~19 px): rotation within 0.5 deg, distance within 0.3 %, focal length from the
    tilted chart's perspective within 4 %; every pixel's depth within 0.4 % by both paths (pose; measured distance and homography)."""
    sweep, layout, pose, depth, _ = render_sweep(0.8, (18.0, -7.0, 4.0), "")
    lens, f_px, pupil = small_rf50()
    view = best_view(sweep.frames, layout)
    assert view is not None and view.markers >= 8
    k = intrinsics_matrix(f_px, W, H)
    r, t, rms = pose_from_view(view, k)
    r0, t0 = pose.extrinsics(pupil)
    angle = math.degrees(math.acos(np.clip((np.trace(r.T @ r0) - 1) / 2, -1, 1)))
    assert angle < 0.5, angle
    assert abs(t[2] / t0[2] - 1) < 0.003
    f_fit, rel = focal_from_view(view, W, H)
    assert abs(f_fit / f_px - 1) < 0.04
    uu, vv = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    z = plane_depth_mm(r, t, k, uu, vv)
    np.testing.assert_allclose((z + pupil) / 1000, depth, rtol=0.004)
    ratio = view.depth_ratio(uu, vv, (W - 1) / 2, (H - 1) / 2)
    z_c = 1000 * pose.distance_m - pupil
    np.testing.assert_allclose((z_c * ratio + pupil) / 1000, depth, rtol=0.004)


def test_the_focal_length_from_a_chart_states_its_own_error_and_a_square_chart_gives_no_distance():
    """`focal_from_view`'s relative error is the markers' own (OpenCV's deviation read 0 % with the aspect ratio
    fixed, even square to the camera): on the tilted chart it is a few % and covers the true error; square to the
    camera it is over 10 %, and a sweep with neither a distance nor EXIF focal length is refused in one line
    naming it (before, that check could never refuse)."""
    sweep, layout, _, _, _ = render_sweep(0.8, (18.0, -7.0, 4.0), "")
    f_px = small_rf50()[1]
    f_fit, rel = focal_from_view(best_view(sweep.frames, layout), W, H)
    assert 0.001 < rel < 0.1 and abs(f_fit / f_px - 1) < 3 * rel, (f_fit / f_px, rel)
    square, layout, _, _, _ = render_sweep(0.8, (0.0, 0.0, 0.0), "")
    assert not focal_from_view(best_view(square.frames, layout), W, H)[1] < 0.1
    with pytest.raises(SweepError, match="too square to the camera") as e:
        measure_sweep(square, layout, distance_m=None, pupil_to_sensor_mm=small_rf50()[2])
    assert str(square.path) in str(e.value) and "\n" not in str(e.value)


def test_a_measured_sweep_moved_to_another_distance_is_measured_there():
    """`SweepMeasurement.at_distance` (what the fit does with a chart distance it finds) gives the tiles' objects
    that measuring at that distance gives, and `object_dz` is their derivative per mm; every chart distance to be
    fitted is refused (the reported focus's error needs one measured)."""
    sweep, layout, _, _, _ = render_sweep(0.7, (12.0, 3.0, 0.0), "")
    pupil = small_rf50()[2]
    a = measure_sweep(sweep, layout, distance_m=0.7, pupil_to_sensor_mm=pupil, fit_distance=True)
    b = measure_sweep(sweep, layout, distance_m=0.72, pupil_to_sensor_mm=pupil)
    moved = a.at_distance(0.72, "fitted")
    np.testing.assert_allclose(moved.object_d, b.object_d, rtol=1e-5)
    assert moved.chart_distance_m == 0.72 and moved.geometry.how == "fitted" and moved.fit_distance
    np.testing.assert_allclose(a.object_dz() * 20.0, b.object_d - a.object_d, rtol=0.05)
    with pytest.raises(SweepError, match="at least one sweep needs a measured distance"):
        fit_calibration([a], n_boot=0)


def test_tiles_reach_the_frames_corners():
    """With to_edges the tiles run from edge to edge: on a 640 x 480 frame in 27 px tiles (the benchmark's phone) the
    outermost are flush with the borders and the farthest tile centre lies at field radius 0.953 (the fit's centred
    grid: 23 x 17 tiles, a 9-10 px border never measured, 0.920). Each tile's mean is its own pixels'; a tile that
    divides the frame gives the centred grid, unchanged; the blur growth runs on either."""
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.peaks import relative_blur_px

    centred = TileGrid(480, 640, 27)
    assert centred.shape == (17, 23) and centred.starts[0][0] == 10 and centred.starts[1][0] == 9
    x, y = centred.field()
    assert float(field_radius_of(x, y, 640 / 480).max()) == pytest.approx(0.9198, abs=2e-4)
    g = TileGrid(480, 640, 27, to_edges=True)
    rows, cols = g.starts
    assert g.shape == (18, 24) and rows[0] == cols[0] == 0 and rows[-1] == 480 - 27 and cols[-1] == 640 - 27
    assert np.all(np.diff(rows) >= 26) and np.all(np.diff(cols) >= 26)  # overlaps under a pixel's worth
    x, y = g.field()
    assert float(field_radius_of(x, y, 640 / 480).max()) == pytest.approx(0.9528, abs=2e-4)
    img = np.random.default_rng(0).random((2, 480, 640))
    m = g.mean(img)
    for i in (0, 7, 17):
        for j in (0, 11, 23):
            np.testing.assert_allclose(m[:, i, j], img[:, rows[i]:rows[i] + 27, cols[j]:cols[j] + 27].mean((-2, -1)))
    r, c = g.owner()  # every pixel belongs to a tile that holds it
    assert np.all((np.arange(480) >= rows[r]) & (np.arange(480) < rows[r] + 27))
    assert np.all((np.arange(640) >= cols[c]) & (np.arange(640) < cols[c] + 27))
    even = TileGrid(640, 960, 40, to_edges=True)
    assert even.contiguous and even.shape == (16, 24) and even.starts[1].tolist() == TileGrid(640, 960, 40).starts[1].tolist()
    np.testing.assert_array_equal(even.starts[1], np.arange(24) * 40)
    img = img[:, :400, :600]
    np.testing.assert_array_equal(TileGrid(400, 600, 40, to_edges=True).mean(img),
                                  img.reshape(2, 10, 40, 15, 40).mean((-3, -1)))
    # the blur growth's tiles: a frame blurred by a known sigma from the sharp one reads that sigma in every tile
    import cv2

    sharp = np.random.default_rng(1).random((96, 130)).astype(np.float32)
    frames = np.stack([np.repeat(f[None], 3, 0) for f in (sharp, cv2.GaussianBlur(sharp, (0, 0), 2.0))])
    for grid in (TileGrid(96, 130, 27), TileGrid(96, 130, 27, to_edges=True)):
        sig = relative_blur_px(frames, np.zeros(grid.shape, np.int64), grid)
        assert sig.shape == (2,) + grid.shape and np.all(np.abs(sig[1] - 2.0) < 0.2) and np.all(sig[0] < 0.2)


def test_a_tile_grid_refuses_tiles_the_frame_cannot_hold():
    """TileGrid refuses a tile size of 0 or one larger than the frame's shorter side (either grid): without it the
    centred grid had no tiles and the edge grid a negative start. A tile as large as the shorter side is one row."""
    for to_edges in (False, True):
        for bad in (0, 481):
            with pytest.raises(ValueError, match="px frame"):
                TileGrid(480, 640, bad, to_edges=to_edges)
        g = TileGrid(480, 640, 480, to_edges=to_edges)
        assert g.shape[0] == 1 and g.starts[0].tolist() == [0]


def test_tile_peaks_of_a_thin_lens_sweep_are_the_chart_distance():
    """Thin-lens blur is symmetric in diopters: each tile's peak is its object's diopters (RMS 0.003 D, all within
    0.01 D, no bias beyond 0.001 D)."""
    sweep, layout, _, depth, _ = render_sweep(0.8, (18.0, -7.0, 4.0), "")
    grid = TileGrid(H, W, 16)
    pk = tile_peaks(sweep.frames, sweep.reported_d, grid, np.ones(grid.shape, bool))
    err = pk.peak_d - grid.mean(1.0 / depth.astype(np.float64))
    assert np.isfinite(err).sum() > 0.8 * err.size
    assert np.nanmax(np.abs(err)) < 0.01 and abs(np.nanmean(err)) < 0.001
    assert float(np.sqrt(np.nanmean(err ** 2))) < 0.003


# -- the fit against a known truth ---------------------------------------------------------------------------------
COPY = "sensor_tilt:tilt_x_deg=0.8:tilt_y_deg=-0.4,focus_metadata:bias_d=0:scale=1.1,noise"


def fit_copy(effects: str, distances=((0.7, (12.0, 3.0, 0.0)), (1.6, (-10.0, 0.0, 0.0))), n_boot=20, **kw):
    measures = []
    for dist, tilt in distances:
        sweep, layout, _, _, _ = render_sweep(dist, tilt, effects, **kw)
        measures.append(measure_sweep(sweep, layout, distance_m=dist, pupil_to_sensor_mm=small_rf50()[2]))
    return fit_calibration(measures, n_boot=n_boot)


def test_recovers_sensor_tilt_and_focus_scale():
    """A tilted sensor (0.8 deg about the vertical axis, -0.4 about the horizontal) and a reported focus 1.1 x the
    true distance: the map within 0.01 D RMS of the truth over 0.6-2 m, the scale family chosen with 1.1 inside its
    interval (+-0.01), and the tilt's left-to-right difference within 10 %."""
    res = fit_copy(COPY)
    cal = res.calibration
    assert cal.focus_error.family == "scale"
    lo, hi = cal.focus_error.intervals["scale"]
    assert lo - 0.01 <= 1.1 <= hi + 0.01 and abs(cal.focus_error.scale - 1.1) < 0.01
    true_m = np.array([0.6, 0.8, 1.0, 1.4, 2.0])
    err = map_error(cal, COPY, true_m, 1.1 * true_m)
    assert float(np.sqrt(np.mean(err ** 2))) < 0.01
    fn = truth_fn(COPY)
    rep = 1.1 * 1.0
    d = in_focus_diopters(cal, [rep], H, W)[0]
    got = float(d[H // 2, -1] - d[H // 2, 0])
    want = float(1 / fn(np.array(1 - 1 / W), np.array(0.0), 1.0) - 1 / fn(np.array(-1 + 1 / W), np.array(0.0), 1.0))
    assert abs(got - want) < 0.1 * abs(want), (got, want)
    assert cal.residuals["rms_d"] < 0.01
    # the field term is held beyond the farthest tile the fit used, and the file says how far that is
    from aat_deploy.calibrate.format import field_radius_of

    o = res.observations
    assert cal.best_focus.radius_max == pytest.approx(float(np.max(field_radius_of(o.x, o.y, o.aspect))))
    assert cal.best_focus.aspect == pytest.approx(W / H) and cal.fit["field_radius_max"] == cal.best_focus.radius_max
    # and the objects its tiles showed: beyond them (or that radius) `measured_mask` says the map is extrapolated
    assert cal.fit["object_range_d"] == pytest.approx([float(o.object_d.min()), float(o.object_d.max())], abs=1e-6)
    from aat_deploy.calibrate import measured_mask

    m = measured_mask(cal, [1.1], H, W)[0]
    assert m[H // 2, W // 2] and not m[0, 0]  # the corner lies beyond the farthest tile's radius
    # and a calibration that knows nothing of the copy (the thin lens's own focus) is far off
    assert float(np.sqrt(np.mean(map_error(cal.__class__(cal.camera, cal.size_px, type(cal.focus_error)(),
                                                         dataclasses.replace(cal.best_focus, coefficients=0 *
                                                                             cal.best_focus.coefficients)),
                                           COPY, true_m, 1.1 * true_m) ** 2))) > 0.05


DECENTRE = f"lens_tolerance:element=2:decentre_x_mm=0.15:table={TOLERANCE_TABLE}"


@pytest.mark.skipif(not TOLERANCE_TABLE.is_file(), reason="the RF50's tolerance table is not in models/")
def test_recovers_a_decentred_elements_asymmetry():
    """A decentred element tilts and bends the focal surface: the fitted left-right and top-bottom asymmetry of
    the map (the odd part in x) within 0.005 D RMS of the truth's, and the whole map within 0.01 D RMS."""
    res = fit_copy(DECENTRE + ",noise")
    cal = res.calibration
    true_m = np.array([0.7, 1.0, 1.5])
    fn = truth_fn(DECENTRE)
    yy, xx = np.mgrid[0:H, 0:W]
    x, y = 2 * (xx + 0.5) / W - 1, 1 - 2 * (yy + 0.5) / H
    truth = np.stack([1 / fn(x, y, f) for f in true_m])
    got = in_focus_diopters(cal, true_m, H, W)
    odd_truth = truth - truth[:, :, ::-1]
    odd_got = got - got[:, :, ::-1]
    assert float(np.sqrt(np.mean(odd_truth ** 2))) > 0.02  # the decentre makes a real asymmetry
    assert float(np.sqrt(np.mean((odd_got - odd_truth) ** 2))) < 0.005
    assert float(np.sqrt(np.mean((got - truth) ** 2))) < 0.01


def test_blur_growth_is_the_thin_lens_slope():
    """Rendered with thin-lens Gaussians of diameter b (sigma b / 4): the measured blur growth is the thin-lens
    px per diopter (`thin_lens_defocus_scale_px_per_d`) within 10 % at the centre."""
    from aat_deploy.calibrate import defocus_scale_px_per_d, thin_lens_defocus_scale_px_per_d

    res = fit_copy("")
    lens, _, _ = small_rf50()
    p = paraxial_data(lens)
    k = defocus_scale_px_per_d(res.calibration, H, W, focus_m=1.0)
    want = thin_lens_defocus_scale_px_per_d(p.efl_mm, p.efl_mm / p.entrance_pupil_mm, lens.sensor.pixel_mm * 1000,
                                            1.0)
    assert abs(float(k[H // 2, W // 2]) / want - 1) < 0.1, (float(k[H // 2, W // 2]), want)


# -- what makes a sweep unusable -----------------------------------------------------------------------------------
def test_sweep_not_bracketing_the_chart_is_refused():
    sweep, layout, _, _, _ = render_sweep(0.8, (10.0, 0.0, 0.0), "", margin_d=0.05, shift_d=0.2)
    with pytest.raises(SweepError, match="does not bracket the chart") as e:
        measure_sweep(sweep, layout, distance_m=0.8)
    assert "\n" not in str(e.value)


def test_markers_of_another_chart_are_not_found():
    sweep, layout, _, _, _ = render_sweep(0.8, (10.0, 0.0, 0.0), "")
    other = dataclasses.replace(layout, ids=layout.ids + 100)
    with pytest.raises(SweepError, match="chart markers not found"):
        measure_sweep(sweep, other, distance_m=0.8)


def test_too_few_textured_tiles_is_refused():
    """A small chart (a quarter of the frame's width, large markers) in front of a blank wall."""
    lens, f_px, pupil = small_rf50()
    w_mm = 0.25 * W / f_px * 1000 * 0.8
    img, layout = make_chart(ChartSpec(size_mm=(w_mm, w_mm / 1.5), markers=(2, 2), marker_mm=0.33 * w_mm / 1.5,
                                       dpi=25.4 * 12 * W / w_mm))
    rgb, depth = chart_scene(img, layout, ChartPose(0.8, 8.0), W, H, f_px, pupil)
    d = 1 / depth
    focus_d = np.arange(float(d.min()) - 0.3, float(d.max()) + 0.3, 0.05)
    frames, reported = shoot(lens, rgb * 0.6, depth, 1 / focus_d, [], cell_px=32)
    order = np.argsort(-reported)
    sweep = Sweep(Path("small"), frames[order], reported[order], {}, (W, H), 1.0)
    with pytest.raises(SweepError, match="too few textured tiles") as e:
        measure_sweep(sweep, layout, distance_m=0.8)
    assert "\n" not in str(e.value)


def test_focus_method_takes_per_pixel_frame_diopters():
    """`classical_depth(frame_diopters=...)` (the oracle's and the calibration's path): the nominal focus given
    per pixel gives the thin-lens mapping's depth exactly; a per-pixel shift moves the depth by it."""
    from aat_deploy.focus import FocusConfig, classical_depth

    sweep, _, _, depth, _ = render_sweep(0.8, (18.0, -7.0, 4.0), "")
    stack, f = sweep.frames[::3], sweep.reported_m[::3]
    thin = classical_depth(stack, f)
    fd = np.broadcast_to((1 / f)[:, None, None], (len(f), H, W)).astype(np.float32)
    same = classical_depth(stack, f, frame_diopters=fd)
    np.testing.assert_allclose(same.depth_m, thin.depth_m, rtol=1e-5)
    assert same.info["mapping"] == "per_pixel"
    raw = FocusConfig(fill="none")
    shifted = classical_depth(stack, f, frame_diopters=fd + 0.05, config=raw)
    plain = classical_depth(stack, f, config=raw)
    np.testing.assert_allclose(1 / shifted.depth_m, 1 / plain.depth_m + 0.05, atol=1e-4)
    with pytest.raises(ValueError, match="frame_diopters"):
        classical_depth(stack, f, frame_diopters=fd[:, :10])
