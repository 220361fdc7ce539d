"""benchmarks.probes.sweep_reach: which pixels lie beyond their own frames, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.probes.sweep_reach import beyond_mask, beyond_share, split_mae


def _frames(h=1, w=4):
    # 3 frames at 2, 1.5 and 1 D everywhere: spacing 0.5 D, half a spacing 0.25 D
    return np.broadcast_to(np.array([2.0, 1.5, 1.0])[:, None, None], (3, h, w)).astype(np.float32)


def test_beyond_is_more_than_half_a_spacing_past_either_end():
    # 1/depth: 2.2 D (within half a spacing of the near end), 2.5 D (beyond), 0.8 D (within), 0.5 D (beyond)
    depth = 1.0 / np.array([[2.2, 2.5, 0.8, 0.5]], np.float32)
    assert beyond_mask(depth, _frames()).tolist() == [[False, True, False, True]]
    assert beyond_share(depth, _frames()) == pytest.approx({"too_near": 0.25, "too_far": 0.25})


def test_unknown_depth_is_never_beyond_and_is_not_counted():
    depth = np.array([[0.0, 0.4, 0.0, 1.0]], np.float32)  # 2.5 D beyond, 1 D within
    assert beyond_mask(depth, _frames()).tolist() == [[False, True, False, False]]
    assert beyond_share(depth, _frames()) == pytest.approx({"too_near": 0.5, "too_far": 0.0})


def test_a_per_pixel_map_moves_the_reach():
    fd = _frames().copy()
    fd[:, 0, 1] += 1.0  # field curvature at pixel 1: its frames focus 3-2 D
    depth = 1.0 / np.array([[2.5, 2.5, 0.8, 0.5]], np.float32)
    assert beyond_mask(depth, fd).tolist() == [[True, False, False, True]]


def test_split_mae_by_hand():
    depth = np.array([[1.0, 2.0, 0.0, 4.0]], np.float32)
    pred = np.array([[1.5, 2.0, 9.0, 1.0]], np.float32)
    beyond = np.array([[False, False, False, True]])
    assert split_mae(pred, depth, beyond) == pytest.approx({"within": 0.25, "beyond": 3.0})
    assert np.isnan(split_mae(pred, depth, np.zeros_like(beyond))["beyond"])


def test_past_infinity_counts_by_hand():
    import torch

    from benchmarks.probes.anycam_past_infinity import counts

    fd = torch.tensor([2.0, 1.0, 0.5])[:, None, None].expand(3, 1, 3)  # farthest frame at 2 m
    d = torch.tensor([[0.001, 0.2, 1.0]])  # the clamp, 5 m (beyond 1.5 x 2 m), 1 m
    assert counts(d, 1.0 / d, fd, 0.001) == (1, 2, 3)
