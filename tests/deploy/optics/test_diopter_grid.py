"""The one "even in diopters" schedule (`optics.focus_table.even_diopters` / `diopter_grid`): its definition, and
bit-identity with the inline copies it replaced (schedules, Mobile Depth's placeholders, the benchmarks' stacks), so
moving them onto it changed no output; aat-diagnose's depth bins agree to the last bits and bin every pixel alike."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from aat_deploy.eval.datasets import mobile_depth
from aat_deploy.optics.focus_table import diopter_grid, even_diopters

metres = st.floats(0.05, 200.0, allow_nan=False)


@given(metres, metres, st.integers(2, 40))
def test_grid_is_the_inline_formula_bit_for_bit(near_m, far_m, n):
    # the copies it replaced: 1.0 / np.linspace(1.0 / near, 1.0 / far, n), and the same with a literal 1
    assert np.array_equal(even_diopters(near_m, far_m, n), np.linspace(1.0 / near_m, 1.0 / far_m, n))
    assert np.array_equal(diopter_grid(near_m, far_m, n), 1.0 / np.linspace(1.0 / near_m, 1.0 / far_m, n))
    assert np.array_equal(diopter_grid(near_m, far_m, n), 1 / np.linspace(1 / near_m, 1 / far_m, n))


def test_grid_is_even_in_diopters_and_inclusive():
    d = diopter_grid(0.5, 10.0, 8)
    assert d.shape == (8,) and d[0] == 0.5 and d[-1] == 10.0
    np.testing.assert_allclose(np.diff(1 / d), (0.1 - 2.0) / 7, rtol=1e-12)


def test_literal_diopter_copies_are_the_same_bits():
    # benchmarks wrote 1 / np.linspace(2.0, 0.1, n) (bench_devices, bench_runtime): the same as the grid 0.5..10 m
    for n in (3, 5, 8, 16):
        assert np.array_equal(diopter_grid(0.5, 10.0, n), 1 / np.linspace(2.0, 0.1, n))
    # Mobile Depth's placeholders were 1.0 / np.linspace(2.0, 1.0, s)
    for s in range(2, 30):
        assert np.array_equal(diopter_grid(*mobile_depth.PLACEHOLDER_M, s), 1.0 / np.linspace(2.0, 1.0, s))


def test_bench_calibrate_inside_range_is_the_same_bits():
    for dist in ((0.6, 1.5, 4.0), (0.5, 10.0), (0.8, 2.0, 3.0, 7.5)):
        lo_d, hi_d = 1.0 / max(dist), 1.0 / min(dist)
        assert np.array_equal(diopter_grid(max(dist), min(dist), 10), 1.0 / np.linspace(lo_d, hi_d, 10))


@given(st.lists(st.floats(0.3, 50.0), min_size=20, max_size=200), st.integers(2, 12))
def test_diagnosis_depth_bins_are_the_inline_formula(depths_m, n):
    """aat-diagnose's shared depth edges (diagnose.bins.shared_edges) through the grid instead of their inline
    1 / np.linspace(hi, lo, n + 1) over the 1st and 99th percentile in diopters. Not bit for bit: the grid takes
    metres, and 1 / (1 / x) is x only to the last bit, so an edge may move by a few units in the last place
    (relative 1e-15); every pixel lands in the same bin."""
    from aat_deploy.diagnose.bins import shared_edges

    gt = np.asarray(depths_m, dtype=np.float32).reshape(1, -1)
    edges, _ = shared_edges([gt], [np.ones((3, 8, 8), np.float32)], n)
    lo, hi = np.percentile(1.0 / gt[gt > 0], [1, 99])
    inline = 1.0 / np.linspace(hi, lo, n + 1)
    inline[0], inline[-1] = 0.0, np.inf
    assert edges[0] == 0.0 and edges[-1] == np.inf and np.all(np.diff(edges) >= 0)
    np.testing.assert_allclose(edges[1:-1], inline[1:-1], rtol=1e-14, atol=0)
    assert np.array_equal(np.digitize(gt, edges), np.digitize(gt, inline))
