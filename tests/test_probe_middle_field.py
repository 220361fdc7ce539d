"""benchmarks/probes/middle_field: the render-truth map read with a cubic in radius reproduces a field that is cubic in
radius where the map's linear reading does not; the leave-one-out check of the radial reading finds a curved field's
bias with the linear reading and none with the cubic; the mean of two maps is their mean."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks import render_truth_map as rtm
from benchmarks.probes import middle_field as mf
from benchmarks.probes import render_truth as rt

PHONE_BASE = "lenses/best_focus/cellphone_asphere.json"
EDGES = tuple(float(v) for v in np.round(np.arange(0.0, 0.951, 0.05), 3))


def _field(r):  # a field offset (D) cubic in radius, curved like the phone's middle field
    return -3.0 * r ** 3 + 1.5 * r ** 2 - 0.2 * r


def _map(offset=_field) -> rtm.RenderTruthMap:
    setup = rt.Setup(r_edges=EDGES)
    mids = 0.5 * (np.array(EDGES[:-1]) + np.array(EDGES[1:]))
    rows = [{"object_d": od, "r": float(r), "ok": True, "peak_frame_d": od - offset(r), "se_object_d": 0.01,
             "se_peak_frame_d": 0.01, "n_draws": 10} for r in mids for od in (5.0, 8.0, 11.0, 14.0)]
    probe = {"setup": dataclasses.asdict(setup), "setup_key": setup.key(), "objects_d": [5.0, 8.0, 11.0, 14.0],
             "rows": rows}
    return rtm.RenderTruthMap(rtm.build(probe, "probe.json", PHONE_BASE, "test"))


def test_the_cubic_reading_reproduces_a_field_cubic_in_radius_and_the_linear_does_not():
    m = _map()
    r = np.linspace(0.1, 0.85, 61)
    f = np.full(r.size, 9.0)
    want = f + _field(r)  # the object in focus: the frame plus the field's offset (the points lie on a line in F)
    lin = m.object_d(r, f)
    cub = mf.CubicRadial(m).object_d(r, f)
    assert np.abs(cub - want).max() < 1e-6  # the map stores its points to 1e-6 D
    val, measured = mf.CubicRadial(m).evaluate(r, f)  # what bench_calibrate's part a reads (Rig.truth_measured)
    assert np.array_equal(val, cub) and np.array_equal(measured, m.evaluate(r, f)[1])
    between = np.abs(((r - 0.025) / 0.05) % 1 - 0.5) < 0.4  # away from the annuli's mids
    assert np.abs(lin - want)[between].max() > 1e-3  # the linear reading misses a curved field between mids
    # the mean of two maps
    m2 = _map(lambda x: _field(x) + 0.1)
    assert mf.Mean([m, m2]).object_d(r, f) == pytest.approx(0.5 * (m.object_d(r, f) + m2.object_d(r, f)))


def test_the_radial_check_finds_the_linear_readings_bias_and_not_the_cubics():
    c = mf.radial_check(_map())
    lin, cub = c["linear from the two neighbours"], c["cubic from the four nearest others"]
    # f'' = -18 r + 3 < 0 beyond r = 1/6: a chord lies below the field there, by -f'' h^2 / 2 = 0.0225 D at r 0.4
    assert lin["0.33-0.5"]["mean_d"] == pytest.approx(0.5 * (-18 * 0.4 + 3) * 0.05 ** 2, abs=2e-3)
    assert abs(cub["0.33-0.5"]["mean_d"]) < 1e-6 and cub["all"]["rms_d"] < 1e-6


def test_lagrange4_is_exact_for_cubics_and_linear_with_fewer_points():
    xs = np.array([0.0, 0.1, 0.25, 0.4, 0.6])
    x = np.linspace(0.0, 0.6, 25)
    assert mf._lagrange4(xs, xs ** 3 - xs, x) == pytest.approx(x ** 3 - x, abs=1e-12)
    assert mf._lagrange4(xs[:3], xs[:3] ** 2, x[:5]) == pytest.approx(np.interp(x[:5], xs[:3], xs[:3] ** 2))


def test_annuli_against_reads_another_truths_points_at_the_same_annulus():
    m = _map()
    got = mf.annuli_against(_map(lambda x: _field(x) + 0.1), m)  # in focus 0.1 D farther at every frame
    inner = {r: v for r, v in got.items() if float(r) < 0.8}  # beyond, m's points end first: its base map reads
    assert len(inner) == 16 and all(v["mean_d"] == pytest.approx(0.1, abs=1e-5) for v in inner.values())
    assert all(abs(v["mean_d"]) < 1e-5 for v in mf.annuli_against(m, m).values())
