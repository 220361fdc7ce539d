"""The phone_jpeg effect against its definitions (aat_deploy/render/effects/phone_jpeg.py): JPEG at quality 100 is
the identity within rounding, unsharp masking raises a grating's contrast by the Gaussian's transfer function, the
tone mapping's fixed point and power law, denoising that keeps edges, the sensor's block grid, determinism."""

import numpy as np
import pytest
from conftest import LENSES

from aat_deploy.io.color import linear_to_srgb, srgb_to_linear
from aat_deploy.lens.io import load_lens
from aat_deploy.render import effects as fx
from aat_deploy.render.effects.phone_jpeg import RANGES, random_settings

OFF = {"tone": 0.0, "denoise": 0.0, "sharpen": 0.0}


@pytest.fixture(scope="module")
def lens():
    return load_lens(LENSES / "canon_rf50mm_f1.8.json")


def smooth_image(h, w, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 2.0).transpose(2, 0, 1)
    return np.ascontiguousarray(0.05 + 0.9 * (img - img.min()) / (img.max() - img.min()))


def run(lens, frame, origin=(0, 0), sensor_hw=None, **params):
    ctx = fx.SimContext(lens, sensor_hw or frame.shape[1:], origin)
    return fx.make("phone_jpeg", **params).sensor(frame, ctx, None)


def dn(linear):
    """8-bit sRGB code values of linear frames (float, unrounded)."""
    return linear_to_srgb(linear).astype(np.float64) * 255


def test_quality_100_is_the_identity_within_jpeg_rounding(lens):
    x = srgb_to_linear(np.rint(dn(smooth_image(64, 96))) / 255)  # on the 8-bit grid: only the JPEG's rounding
    err = {q: np.rint(np.abs(dn(run(lens, x, quality=q, subsampling="444", **OFF)) - dn(x))) for q in (100, 90, 50)}
    # DCT and YCbCr rounding (libjpeg, 8-bit): about half a code value, a few at saturated colours
    assert err[100].mean() < 0.6 and np.percentile(err[100], 99) <= 2 and err[100].max() <= 4
    assert err[100].mean() < err[90].mean() < err[50].mean()  # coarser quantisation, larger error
    assert err[50].mean() > 1.0
    out = run(lens, x, quality=100, subsampling="444", **OFF)
    assert out.dtype == x.dtype and out.shape == x.shape


@pytest.mark.parametrize("amount,sigma,period", [(1.0, 1.0, 8), (0.6, 1.5, 12)])
def test_unsharp_masking_raises_a_gratings_contrast_by_the_stated_factor(lens, amount, sigma, period):
    """A sinusoid of period P through y + a (y - G_sigma y): contrast x 1 + a (1 - exp(-2 pi^2 sigma^2 / P^2))."""
    w = period * 12
    xx = np.arange(w)
    enc = 0.5 + 0.15 * np.sin(2 * np.pi * xx / period)
    frame = np.broadcast_to(srgb_to_linear(enc)[None, None], (3, 48, w)).astype(np.float32).copy()
    out = linear_to_srgb(run(lens, frame, sharpen=amount, sharpen_px=sigma, quality=100, subsampling="444",
                             tone=0.0, denoise=0.0))
    row = out[1, 24, period * 2:w - period * 2].astype(np.float64)  # whole periods away from the borders
    t = xx[period * 2:w - period * 2]
    amp = np.hypot(2 * np.mean(row * np.sin(2 * np.pi * t / period)), 2 * np.mean(row * np.cos(2 * np.pi * t / period)))
    expected = 1 + amount * (1 - np.exp(-2 * np.pi ** 2 * sigma ** 2 / period ** 2))
    assert amp / 0.15 == pytest.approx(expected, rel=0.01)
    assert expected > 1.1  # a change the test can see


def test_tone_mapping_power_law_on_uniform_areas(lens):
    """On a uniform area of luminance L: L^(1 - tone) 0.18^tone (mid-grey fixed, shadows lifted, highlights held)."""
    for level in (0.05, 0.18, 0.5):
        frame = np.full((3, 32, 32), level, np.float32)
        out = run(lens, frame, tone=0.5, denoise=0.0, sharpen=0.0, quality=100, subsampling="444")
        want = level ** 0.5 * 0.18 ** 0.5
        assert np.abs(dn(out) - dn(np.full_like(out, want))).max() <= 1.0, level


def test_denoising_smooths_noise_and_keeps_edges(lens):
    rng = np.random.default_rng(1)
    enc = np.where(np.arange(64)[None, :] < 32, 0.35, 0.65) + rng.normal(0, 0.01, (64, 64))
    frame = np.broadcast_to(srgb_to_linear(np.clip(enc, 0, 1))[None], (3, 64, 64)).astype(np.float32).copy()
    kw = dict(tone=0.0, sharpen=0.0, quality=100, subsampling="444")
    plain = linear_to_srgb(run(lens, frame, denoise=0.0, **kw))[1]
    den = linear_to_srgb(run(lens, frame, denoise=0.04, denoise_px=1.5, **kw))[1]
    flat = (slice(4, 60), slice(4, 26))
    assert den[flat].std() < 0.5 * plain[flat].std()
    step = den[:, 32].mean() - den[:, 31].mean()  # the edge stays a one-pixel step
    assert step == pytest.approx(0.3, abs=0.02)


@pytest.mark.parametrize("subsampling,mcu", [("444", 8), ("420", 16)])
def test_a_crop_keeps_the_sensors_block_grid(lens, subsampling, mcu):
    """Blocks lie on the full sensor's grid: a crop at an odd origin gives the full frame's pixels inside every
    block it holds whole (2 px margin: 4:2:0 upsampling reads the neighbouring chroma samples)."""
    full = smooth_image(64, 64, seed=2)
    kw = dict(quality=60, subsampling=subsampling, **OFF)
    a = run(lens, full, **kw)
    crop = run(lens, np.ascontiguousarray(full[:, 19:59, 21:61]), origin=(19, 21), sensor_hw=(64, 64), **kw)
    r0, r1 = -(-19 // mcu) * mcu, 59 // mcu * mcu  # whole blocks inside the crop, sensor rows/cols
    c0, c1 = -(-21 // mcu) * mcu, 61 // mcu * mcu
    assert r1 > r0 and c1 > c0
    m = 2
    inner_full = a[:, r0 + m:r1 - m, c0 + m:c1 - m]
    inner_crop = crop[:, r0 - 19 + m:r1 - 19 - m, c0 - 21 + m:c1 - 21 - m]
    assert np.array_equal(inner_full, inner_crop)
    # without the phase the blocks would differ
    shifted = run(lens, np.ascontiguousarray(full[:, 19:59, 21:61]), **kw)
    assert not np.array_equal(shifted[:, r0 - 19 + m:r1 - 19 - m, c0 - 21 + m:c1 - 21 - m], inner_full)


def test_seeded_determinism_and_order_after_the_noise(lens):
    frames = np.stack([smooth_image(40, 48, seed=s) for s in range(3)])
    effects = fx.parse("phone_jpeg,noise:full_well_e=2000")
    assert [e.name for e in effects] == ["noise", "phone_jpeg"]  # the phone sees the sensor's noise
    ctx = fx.SimContext(lens, (40, 48))
    a = fx.post_stack(effects, frames, [1.0, 2.0, 3.0], ctx, np.random.default_rng(3))
    b = fx.post_stack(effects, frames, [1.0, 2.0, 3.0], ctx, np.random.default_rng(3))
    c = fx.post_stack(effects, frames, [1.0, 2.0, 3.0], ctx, np.random.default_rng(4))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    # the JPEG's decoded values: 8-bit sRGB code values
    codes = dn(a)
    assert np.abs(codes - np.rint(codes)).max() < 1e-2
    grey = run(lens, frames[0, :1])
    assert grey.shape == (1, 40, 48)


def test_settings_text_ranges_and_errors():
    e = fx.parse("phone_jpeg:quality=100:subsampling=444:sharpen=1.2")[0]
    assert e.params["subsampling"] == "444" and e.params["quality"] == 100.0
    assert fx.parse(fx.spec(e))[0].params == e.params
    for bad in ("phone_jpeg:quality=0", "phone_jpeg:quality=90.5", "phone_jpeg:subsampling=422",
                "phone_jpeg:tone=-0.1", "phone_jpeg:colour=1", "phone_jpeg:sharpen=x"):
        with pytest.raises(ValueError, match="phone_jpeg"):
            fx.parse(bad)
    rng = np.random.default_rng(0)
    for _ in range(20):
        s = random_settings(rng)
        fx.make("phone_jpeg", **s)  # valid
        assert all(RANGES[k][0] <= s[k] <= RANGES[k][1] for k in RANGES)
    # the diagnosis tries every candidate; all valid and distinct
    cands = fx.make("phone_jpeg").candidates
    made = [fx.make("phone_jpeg", **c).params for c in cands]
    assert len(made) >= 3 and all(made[i] != made[j] for i in range(len(made)) for j in range(i))
    assert fx.make("phone_jpeg").binned(2) is None and fx.make("phone_jpeg").binned(1) is not None
