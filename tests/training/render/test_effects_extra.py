"""The focus-metadata and sensor-tilt effects, effect settings on the command line, and the simulator's split
into optics and post-processing."""

import cv2
import numpy as np
import pytest
import torch
from conftest import assert_close

from aat_deploy.lens.io import load_lens
from aat_deploy.render import effects as fx
from aat_deploy.render.effects.focus_metadata import quantise_focus_m
from aat_deploy.render.effects.sensor_tilt import tilted_focus_m
from training.render.layered import LayeredConfig
from training.render.simulator import Simulator
from training.render.sources import thin_lens_source


@pytest.fixture(scope="module")
def lens():
    return load_lens("lenses/canon_rf50mm_f1.8.json")


def test_tilt_moves_focus_linearly_in_sensor_position(lens):
    f = tilted_focus_m(lens, np.array([-1.0, 0.0, 1.0]), np.zeros(3), 2.0, 0.5, 0.0)
    assert f[1] == pytest.approx(2.0, rel=1e-6)
    # the right edge is 18 mm * tan(0.5 deg) = 0.157 mm further from the lens: focused nearer; left farther
    assert f[2] < 2.0 < f[0]
    # hand check with the thin-lens relation near focus: d(1/u) = dz / f^2 (f = 50 mm EFL, dz in m)
    dz = 0.018 * np.tan(np.radians(0.5))
    assert 1 / f[2] - 1 / f[1] == pytest.approx(dz / 0.05 ** 2, rel=0.15)
    # no tilt, no change; vertical tilt acts on y only
    assert np.allclose(tilted_focus_m(lens, np.array([1.0]), np.array([1.0]), 2.0, 0.0, 0.0), 2.0)
    fy = tilted_focus_m(lens, np.array([1.0, 1.0]), np.array([-1.0, 1.0]), 2.0, 0.0, 0.5)
    assert fy[1] < 2.0 < fy[0]


def test_focus_metadata_bias_and_its_inverse(lens):
    e = fx.make("focus_metadata", bias_d=0.1)
    ctx = fx.SimContext(lens, (640, 960))
    true = np.array([0.5, 1.0, 2.0, 5.0])
    rep = e.report_focus(true, ctx, np.random.default_rng(0))
    assert np.allclose(1 / rep - 1 / true, 0.1)
    assert np.allclose(e.twin_focus(rep, ctx, np.random.default_rng(0)), true)


def test_focus_bias_past_infinity_reports_the_far_end(lens):
    # a -0.1 D bias at 10 m (0.1 D) would report 1/0 m; at 5 m (0.2 D) it reports 10 m as usual
    e = fx.make("focus_metadata", bias_d=-0.1)
    ctx = fx.SimContext(lens, (640, 960))
    rep = e.report_focus(np.array([5.0, 10.0, 50.0]), ctx, np.random.default_rng(0))
    assert np.all(np.isfinite(rep)) and rep[0] == pytest.approx(10.0) and np.allclose(rep[1:], 100.0)


def test_nikon_quantisation_matches_the_maker_note_formula():
    # Nikon LensData stores v with distance 0.01 * 10^(v/40) m (integer v)
    v = np.round(40 * np.log10(100 * 1.23))
    assert quantise_focus_m(np.array([1.23]), "nikon", 0)[0] == pytest.approx(0.01 * 10 ** (v / 40))
    q = quantise_focus_m(np.geomspace(0.5, 10, 50), "nikon", 0)
    assert np.all(np.abs(np.log10(q * 100) * 40 - np.round(np.log10(q * 100) * 40)) < 1e-9)
    assert quantise_focus_m(np.array([2.0]), "diopter", 0.3)[0] == pytest.approx(1 / 0.6)
    with pytest.raises(ValueError, match="quantise"):
        fx.make("focus_metadata", quantise="canon")


def test_effect_settings_round_trip_through_text():
    e = fx.parse("noise:full_well_e=3000,sensor_tilt:tilt_y_deg=-0.3:tilt_x_deg=0")
    by = {x.name: x for x in e}
    assert by["noise"].params["full_well_e"] == 3000.0
    assert by["sensor_tilt"].params == {"tilt_x_deg": 0.0, "tilt_y_deg": -0.3}
    again = fx.parse(",".join(fx.spec(x) for x in e))
    assert [x.params for x in again] == [x.params for x in e]
    with pytest.raises(ValueError, match="key=value"):
        fx.parse("noise:3000")
    assert fx.is_post(fx.make("noise")) and fx.is_post(fx.make("focus_breathing"))
    assert not fx.is_post(fx.make("sensor_tilt")) and not fx.is_post(fx.make("focus_metadata"))
    for name in fx.names():  # every effect's candidate settings are valid
        for c in fx.make(name).candidates:
            fx.make(name, **c)


def test_tilt_changes_the_rendered_stack_and_post_effects_reuse_the_optics(lens):
    rng = np.random.default_rng(0)
    rgb = torch.from_numpy(rng.random((3, 64, 96), dtype=np.float32))
    depth = torch.full((64, 96), 2.0)
    small = lens.__class__(**{**lens.__dict__, "sensor": lens.sensor.__class__(36.0, 24.0, 96, 64)})
    cfg = LayeredConfig(cell_px=32)
    plain = Simulator(small, None, [], cfg, thin_lens_source(small))
    tilt = Simulator(small, None, [fx.make("sensor_tilt", tilt_x_deg=5.0)], cfg, thin_lens_source(small))
    a = plain.render_stack(rgb, depth, [2.0]).frames[0]
    b = tilt.render_stack(rgb, depth, [2.0]).frames[0]
    # focused at 2 m on axis: the centre columns agree; at the edges 5 deg is +-0.6 D, about 2 px of blur here
    diff = (a - b).abs().mean(dim=(0, 1))
    assert diff[40:56].mean() < 0.5 * min(diff[:12].mean(), diff[-12:].mean())
    sharp = lambda x: float((x[:, :, 1:] - x[:, :, :-1]).abs().mean())  # noqa: E731
    assert sharp(b[:, :, :12]) < 0.8 * sharp(a[:, :, :12]) and sharp(b[:, :, -12:]) < 0.8 * sharp(a[:, :, -12:])
    noisy = Simulator(small, None, [fx.make("noise")], cfg, thin_lens_source(small))
    ctx = noisy.context()
    full = noisy.render_stack(rgb, depth, [2.0], rng=np.random.default_rng(3)).frames
    split = noisy.post(plain.optical(rgb, depth, np.array([2.0]), ctx), np.array([2.0]), ctx, np.random.default_rng(3))
    assert torch.equal(full, split)  # the same optics and the same draws in one process: bit for bit


@pytest.mark.numerics
def test_raw_pipeline_demosaic_by_hand(lens):
    from aat_deploy.render.effects.raw_pipeline import demosaic_bilinear

    # bilinear interpolation reproduces flat colours everywhere and linear ramps away from the border
    flat = np.broadcast_to(np.array([0.2, 0.5, 0.7], np.float32)[:, None, None], (3, 8, 10)).copy()
    e = fx.make("raw_pipeline", demosaic="bilinear")
    ctx = fx.SimContext(lens, (8, 10))
    # OpenCV's float32 weighted means of equal values: exact up to a few ulps (SIMD paths differ between CPUs)
    assert np.allclose(e.sensor(flat, ctx, np.random.default_rng(0)), flat, rtol=1e-6, atol=0)
    yy, xx = np.mgrid[0:12, 0:16].astype(np.float32)
    ramp = np.stack([0.01 * xx + 0.02 * yy, 0.03 * xx, 0.5 - 0.01 * yy])
    out = e.sensor(ramp, ctx, np.random.default_rng(0))
    assert_close(out[:, 1:-1, 1:-1], ramp[:, 1:-1, 1:-1], 4e-6, what="ramp")  # a few float32 ulps
    # measured photosites are kept: R at (even, even), B at (odd, odd)
    from aat_deploy.capture.virtual import mosaic_rggb
    rnd = np.random.default_rng(1).random((3, 6, 6)).astype(np.float32)
    dm = demosaic_bilinear(mosaic_rggb(rnd))
    assert np.array_equal(dm[0, 0::2, 0::2], rnd[0, 0::2, 0::2]) and np.array_equal(dm[2, 1::2, 1::2], rnd[2, 1::2, 1::2])
    # a crop at an odd origin keeps the sensor's colour phase: the same pixels as cropping the full result
    full = e.sensor(rnd, fx.SimContext(lens, (6, 6)), None)
    crop = e.sensor(np.ascontiguousarray(rnd[:, 1:, 1:]), fx.SimContext(lens, (6, 6), (1, 1)), None)
    assert_close(crop[:, 1:-1, 1:-1], full[:, 2:-1, 2:-1], 1e-6, what="crop")  # the same sums, maybe other SIMD paths


def test_raw_pipeline_libraw_is_the_runtimes_development(lens, tmp_path):
    """The default development is the runtime's: a frame through the effect equals the same frame written by the
    virtual camera as a DNG and read back by aat_deploy (LibRaw), pixel for pixel; odd sizes and crops work."""
    from aat_deploy.capture.raw import load_raw
    from aat_deploy.capture.virtual import write_capture

    rng = np.random.default_rng(2)
    frame = cv2.GaussianBlur(rng.random((40, 60, 3)).astype(np.float32), (0, 0), 1.5).transpose(2, 0, 1) * 0.8
    frame = np.ascontiguousarray(frame)
    e = fx.make("raw_pipeline")
    out = e.sensor(frame, fx.SimContext(lens, (40, 60)), None)
    write_capture(tmp_path / "cap", frame[None], [1.0], lens, None, None, {})
    ref, _ = load_raw(tmp_path / "cap" / "frame_00.dng")
    # bit for bit: the same 14-bit DN through the same LibRaw decode
    assert out.shape == frame.shape and np.array_equal(out, ref.transpose(2, 0, 1))
    assert np.abs(out - frame).mean() < 0.02  # a development, not a different picture
    odd = e.sensor(np.ascontiguousarray(frame[:, 1:20, 1:16]), fx.SimContext(lens, (40, 60), (1, 1)), None)
    assert odd.shape == (3, 19, 15) and np.all(np.isfinite(odd))
    with pytest.raises(ValueError, match="demosaic"):
        fx.make("raw_pipeline", demosaic="vng")


def test_raw_pipeline_spreads_one_noise_draw_per_photosite(lens):
    """Noise then raw_pipeline on a flat field: red is measured at 1 photosite in 4 and interpolated from 2 or 4
    others elsewhere, so its variance is (1 + 1/2 + 1/2 + 1/4) / 4 = 0.5625 of the photosite's (hand count)."""
    ctx = fx.SimContext(lens, (256, 256))
    flat = np.full((3, 256, 256), 0.5, np.float32)
    effects = fx.parse("noise:full_well_e=1000:read_noise_e=0,raw_pipeline:demosaic=bilinear")
    rng = np.random.default_rng(0)
    out = flat
    for e in effects:
        out = e.sensor(out, ctx, rng)
    per_site = 0.5 / 1000  # Poisson: variance = mean electrons / full_well^2, in white-level units
    inner = out[0, 2:-2, 2:-2]
    assert inner.var() == pytest.approx(0.5625 * per_site, rel=0.05)
    assert inner.mean() == pytest.approx(0.5, rel=2e-3)  # the mean's standard error is 1.3e-4 of it


def test_focus_metadata_scale_and_curve_and_their_inverses(lens):
    """A distance-scale error (reported = 1.05 x true) and a monotone curve invert exactly; the curve is linear
    between its knots and keeps its end errors beyond them; text specs carry the knots as a '/' list."""
    ctx = fx.SimContext(lens, (640, 960))
    true = np.array([0.5, 1.0, 2.0, 5.0])
    e = fx.make("focus_metadata", bias_d=0.0, scale=1.05)
    rep = e.report_focus(true, ctx, np.random.default_rng(0))
    assert np.allclose(rep, 1.05 * true)
    assert np.allclose(e.twin_focus(rep, ctx, np.random.default_rng(0)), true)
    # knots: reported 0.2 D is really 0.25 D, reported 2 D really 2.1 D
    c = fx.make("focus_metadata", bias_d=0.0, map_d=[0.2, 0.25, 2.0, 2.1])
    got = 1 / c.twin_focus(1 / np.array([0.1, 0.2, 1.1, 2.0, 3.0]), ctx, np.random.default_rng(0))
    assert np.allclose(got, [0.15, 0.25, 1.175, 2.1, 3.1])
    assert np.allclose(c.twin_focus(c.report_focus(true, ctx, None), ctx, np.random.default_rng(0)), true)
    again = fx.parse(fx.spec(c))[0]
    assert again.params["map_d"] == [0.2, 0.25, 2.0, 2.1] and fx.spec(c) == "focus_metadata:bias_d=0.0:map_d=0.2/0.25/2/2.1"
    with pytest.raises(ValueError, match="pairs"):
        fx.make("focus_metadata", map_d=[0.2, 0.25, 2.0])
    with pytest.raises(ValueError, match="rise"):
        fx.make("focus_metadata", map_d=[0.2, 0.25, 0.1, 2.1])


def test_sensor_shifts_add_up_through_the_focus_table(lens):
    """Tilts about the two axes given as two effects are one tilt of the summed shift (the registry adds sensor shifts before the
    focus-table lookup), and one tilt equals tilted_focus_m."""
    from aat_deploy.optics.focus_table import paraxial_focus_table

    ctx = fx.SimContext(lens, (640, 960), table=paraxial_focus_table(lens))
    x, y = np.array([-1.0, 0.0, 0.7]), np.array([0.2, 0.0, -0.9])
    one = fx.focus_at([fx.make("sensor_tilt", tilt_x_deg=0.4, tilt_y_deg=-0.2)], ctx)(x, y, 2.0)
    assert np.allclose(one, tilted_focus_m(lens, x, y, 2.0, 0.4, -0.2, ctx.table))
    two = fx.focus_at([fx.make("sensor_tilt", tilt_x_deg=0.4, tilt_y_deg=0.0),
                       fx.make("sensor_tilt", tilt_x_deg=0.0, tilt_y_deg=-0.2)], ctx)
    assert fx.focus_at([], ctx) is None and np.allclose(two(x, y, 2.0), one)


def test_breathing_coefficient_scales_the_magnification_change(lens):
    """coefficient 0 = no breathing, 1 = the lens's model (unchanged default), 2 = twice the change."""
    from aat_deploy.optics.focus_table import paraxial_focus_table
    from aat_deploy.render.effects.focus_breathing import breathing_scale, scale_about_axis

    ctx = fx.SimContext(lens, (64, 96), table=paraxial_focus_table(lens))
    frame = np.random.default_rng(0).random((3, 64, 96)).astype(np.float32)
    s = float(breathing_scale(lens, 0.5, ctx.table, ctx.exit_pupil_z_mm))
    assert s != 1.0
    assert np.array_equal(fx.make("focus_breathing").warp(frame, 0.5, ctx), scale_about_axis(frame, s, ctx))
    assert np.array_equal(fx.make("focus_breathing", coefficient=0.0).warp(frame, 0.5, ctx), frame)
    assert np.allclose(fx.make("focus_breathing", coefficient=2.0).warp(frame, 0.5, ctx),
                       scale_about_axis(frame, 1 + 2 * (s - 1), ctx))


def test_exposure_scales_each_frame_before_the_noise(lens):
    """Fixed gains multiply frame i by gains[i]; per-capture gains follow ctx.capture; random gains have the
    asked spread; the training form is the fitted gains' spread."""
    ctx = fx.SimContext(lens, (8, 12), capture="a")
    frames = np.ones((3, 3, 8, 12), np.float32)
    e = fx.make("exposure", gains=[1.0, 1.1, 0.9])
    out = fx.post_stack([e], frames, np.array([1.0, 2.0, 3.0]), ctx, np.random.default_rng(0))
    assert np.allclose(out[:, 0, 0, 0], [1.0, 1.1, 0.9])
    by = fx.make("exposure", by_capture={"a": [0.8, 1.0, 1.25], "b": [1.0, 1.0, 1.0]})
    assert np.allclose(by.stack(frames, None, ctx, None)[:, 0, 0, 0], [0.8, 1.0, 1.25])
    g = fx.make("exposure", sigma_log=0.1).frame_gains(20000, ctx, np.random.default_rng(1))
    assert np.std(np.log(g)) == pytest.approx(0.1, rel=0.03)
    assert by.training_spec() == f"exposure:sigma_log={np.std(np.log([0.8, 1.0, 1.25, 1.0, 1.0, 1.0])):.4g}"
    with pytest.raises(ValueError, match="3 gains for a stack of 2"):
        e.stack(frames[:2], None, ctx, None)
    assert fx.is_post(e) and fx.parse(fx.spec(e))[0].params["gains"] == [1.0, 1.1, 0.9]


def test_misalignment_moves_each_frame(lens):
    """by_capture warps move frame content by (dx, dy) px (right, down); phase correlation sees the same
    direction; binning halves the shifts."""
    import cv2

    ctx = fx.SimContext(lens, (64, 96), capture="c")
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.random((64, 96)).astype(np.float32), (0, 0), 1.5)
    frames = np.stack([np.repeat(img[None], 3, 0)] * 2)
    e = fx.make("misalignment", by_capture={"c": [0.0, 0.0, 1.0, 2.0, -1.0, 1.0]})
    out = fx.post_stack([e], frames, np.array([1.0, 2.0]), ctx, np.random.default_rng(0))
    assert np.array_equal(out[0], frames[0])
    # content moved 2 px right and 1 px up: out[r, c] = frame[r + 1, c - 2] (integer shifts are exact)
    assert np.allclose(out[1, :, 5:-5, 5:-5], frames[1, :, 6:-4, 3:-7], atol=1e-6)
    (dx, dy), _ = cv2.phaseCorrelate(np.ascontiguousarray(frames[1, 0]), np.ascontiguousarray(out[1, 0]))
    assert dx > 1.2 and dy < -0.6  # what the fitter measures: the same direction (biased low on smooth content)
    assert e.binned(2).params["by_capture"]["c"] == [0.0, 0.0, 1.0, 1.0, -0.5, 1.0]
    assert "sigma_px=" in e.training_spec() and fx.is_post(e)
    r = fx.make("misalignment", sigma_px=1.0).frame_warps(5000, ctx, np.random.default_rng(2))
    assert np.std(r[:, :2]) == pytest.approx(1.0, rel=0.05) and np.all(r[:, 2] == 1.0)


def test_phone_jpeg_reaches_the_training_simulator_after_the_noise(lens):
    """The torch simulator applies phone_jpeg through the shared post hooks, after the sensor's noise: its frames
    equal the noise-only simulator's (same draws) developed by the effect by hand."""
    from aat_deploy.render.effects.phone_jpeg import develop

    rng = np.random.default_rng(0)
    rgb = torch.from_numpy(cv2.GaussianBlur(rng.random((64, 96, 3), dtype=np.float32), (0, 0), 1.5).transpose(2, 0, 1).copy())
    depth = torch.full((64, 96), 2.0)
    small = lens.__class__(**{**lens.__dict__, "sensor": lens.sensor.__class__(36.0, 24.0, 96, 64)})
    cfg = LayeredConfig(cell_px=32)
    phone = fx.make("phone_jpeg", quality=85.0)
    noisy = Simulator(small, None, [fx.make("noise")], cfg, thin_lens_source(small))
    both = Simulator(small, None, fx.parse(["phone_jpeg:quality=85", "noise"]), cfg, thin_lens_source(small))
    a = both.render_stack(rgb, depth, [1.5, 3.0], rng=np.random.default_rng(5)).frames
    n = noisy.render_stack(rgb, depth, [1.5, 3.0], rng=np.random.default_rng(5)).frames
    ref = np.stack([develop(fr.numpy(), phone.params, (64, 96)) for fr in n])
    assert a.dtype == n.dtype and np.array_equal(a.numpy(), ref)
    assert float((a - n).abs().mean()) > 0.01  # the phone changed the frames
