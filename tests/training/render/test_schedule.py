"""Focus schedules: even in diopters, sorted, jitter keeps the order, no dependence on scene depth."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from training.render.schedule import FocusSchedule


def test_even_in_diopters_and_sorted_near_to_far():
    d = FocusSchedule(0.5, 5.0, 8).distances()
    assert d[0] == pytest.approx(0.5) and d[-1] == pytest.approx(5.0)
    assert np.allclose(np.diff(1 / d), np.diff(1 / d)[0])
    assert np.all(np.diff(d) > 0)


def test_jitter_keeps_order_and_bounds():
    s = FocusSchedule(0.4, 10.0, 10, jitter_d=0.45)
    rng = np.random.default_rng(0)
    base = s.distances()
    for _ in range(200):
        d = s.distances(rng)
        assert np.all(np.diff(d) > 0)
        assert np.all(np.abs(1 / d - 1 / base) <= 0.45 * s.spacing_d + 1e-12)
    assert not np.allclose(s.distances(rng), base)


def test_schedule_never_sees_depth():
    # The reference code derives test-time focus from the ground-truth depth range; ours cannot.
    params = set(inspect.signature(FocusSchedule.distances).parameters)
    assert params == {"self", "rng"}


def test_bad_schedules_are_rejected():
    with pytest.raises(ValueError):
        FocusSchedule(2.0, 1.0, 5)
    with pytest.raises(ValueError):
        FocusSchedule(0.5, 1.0, 1)


def test_scene_range_protocol_spreads_over_the_depth_range():
    from training.render.schedule import scene_range_distances

    depth = np.array([[0.0, 2.0], [3.0, 5.0]])  # 0 = unknown
    assert np.allclose(scene_range_distances(depth, 4), [2.0, 3.0, 4.0, 5.0])
    f = scene_range_distances(depth, 4, np.random.default_rng(0), perturb=0.25)
    assert np.all(np.diff(f) > 0) and np.all(np.abs(f - [2.0, 3.0, 4.0, 5.0]) <= 0.25 + 1e-12)
    with pytest.raises(ValueError, match="no valid depth"):
        scene_range_distances(np.zeros((2, 2)), 4)



def _inline_schedule(near, far, n, jitter_d, rng):
    """The copy FocusSchedule.distances held before it drew on even_diopters (kept here as the reference)."""
    inv = np.linspace(1.0 / near, 1.0 / far, n)
    if rng is not None and jitter_d > 0:
        inv = inv + rng.uniform(-1, 1, n) * jitter_d * (1.0 / near - 1.0 / far) / (n - 1)
        inv = np.clip(inv, 1.0 / far * 0.5, None)
    return 1.0 / inv


def test_schedule_is_the_one_even_in_diopters_grid_bit_for_bit():
    # FocusSchedule draws on optics.focus_table.even_diopters; its output is the inline formula it replaced, jitter
    # included (same random draws), so rendered training stacks are unchanged.
    from aat_deploy.optics.focus_table import diopter_grid

    for near, far, n, jit in ((0.5, 5.0, 8, 0.0), (0.4, 10.0, 10, 0.45), (0.3, 20.0, 5, 0.2)):
        s = FocusSchedule(near, far, n, jitter_d=jit)
        assert np.array_equal(s.distances(), diopter_grid(near, far, n))
        for seed in range(5):
            got = s.distances(np.random.default_rng(seed))
            assert np.array_equal(got, _inline_schedule(near, far, n, jit, np.random.default_rng(seed)))
