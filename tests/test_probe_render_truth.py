"""benchmarks/probes/render_truth: on an ideal thin lens the measured best focus is the analytic one (the object's
own diopters, at every field radius); draws are cached and not rendered again; the bootstrap SE falls as 1/sqrt(N)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.probes import render_truth as rt

THIN = rt.Setup(lens="lenses/canon_rf50mm_f1.8.json", psf=None, fmap=None, texture="leaves", sensor_px=(96, 64),
                step_d=0.1, before_d=0.95, n_frames=20, r_edges=(0.0, 0.3, 0.6, 0.9))


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setattr(rt, "CACHE", tmp_path / "rt")
    return tmp_path / "rt"


def test_a_thin_lens_is_in_focus_where_the_thin_lens_formula_says_at_every_radius(cache):
    od = 1.37  # a plane at 0.73 m, between frames (0.42 .. 2.32 D, 0.1 D apart); ~3.7 px of blur per diopter
    got = [rt.draw(THIN, od, s) for s in (1, 2, 3)]
    rows = rt.plane_stats(THIN, od, np.stack([d["curves"] for d in got]), got[0]["frames_d"], None, 50,
                          np.random.default_rng(0))
    assert len(rows) == 3 and all(q["ok"] for q in rows)
    for q in rows:  # the Gaussian blur is field-invariant and zero at the object: the peak is the object's diopters
        assert q["peak_frame_d"] == pytest.approx(od, abs=0.01), q
        assert 0 <= q["se_object_d"] < 0.03


def test_a_draw_is_rendered_once_and_then_read(cache, monkeypatch):
    calls = []
    real = rt.ring_curves
    monkeypatch.setattr(rt, "ring_curves", lambda *a: calls.append(a) or real(*a))
    a = rt.draw(THIN, 1.0, 7)
    assert rt.draw(THIN, 1.0, 8, render=False) is None
    b = rt.draw(THIN, 1.0, 7)
    assert len(calls) == 1 and np.array_equal(a["curves"], b["curves"])
    assert rt.Setup(cell_px=32).key() != rt.Setup().key()  # another renderer is another cache


def test_the_bootstrap_se_falls_as_one_over_root_n():
    frames = np.arange(-2.0, 2.01, 0.25)
    rng = np.random.default_rng(1)
    sd = 0.1  # each draw's own peak scatters by 0.1 D; the summed curve's peak by about 0.1 / sqrt(N)
    se = {}
    for n in (4, 64):
        mu = rng.normal(0.0, sd, n)
        curves = np.exp(-0.5 * ((frames[None] - mu[:, None]) / 0.8) ** 2)[:, None, :]  # (N, R=1, S)
        setup = rt.Setup(r_edges=(0.0, 0.05))
        (q,) = rt.plane_stats(setup, 0.0, curves, frames, None, 400, np.random.default_rng(2))
        se[n] = q["se_object_d"]
        assert 0.5 < se[n] / (sd / np.sqrt(n)) < 1.6, (n, se[n])
    assert se[64] < se[4] / 2.5


def test_ring_means_averages_each_annulus_and_leaves_empty_ones_nan():
    import numpy as np

    from aat_deploy.calibrate.format import field_grid, field_radius_of
    from benchmarks.probes.render_truth import ring_means

    h, w = 24, 32
    gx, gy = field_grid(h, w)
    rad = field_radius_of(gx, gy, w / h)
    vol = np.stack([rad, 2.0 * rad + 1.0])  # two frames whose value is known at every pixel
    edges = (0.0, 0.5, 1.01, 2.0)  # the last annulus lies beyond the frame's corner (radius 1)
    got = ring_means(vol, edges)
    assert got.shape == (3, 2)
    inner = rad < 0.5
    assert np.allclose(got[0], [rad[inner].mean(), (2.0 * rad[inner] + 1.0).mean()])
    assert np.allclose(got[1], [rad[~inner].mean(), (2.0 * rad[~inner] + 1.0).mean()])
    assert np.isnan(got[2]).all()
