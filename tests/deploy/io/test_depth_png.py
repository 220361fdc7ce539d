"""The one mm-PNG encoder (aat_deploy.io.depth_png): its policy on hand-made cases, round trips through a PNG and
the reader of ground truth, and properties over any float map (hypothesis)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from aat_deploy.gt.read import read_depth_file
from aat_deploy.io.depth_png import M_PER_MM, MAX_MM, encode_mm16
from aat_deploy.io.images import imwrite


def test_policy_by_hand():
    x = np.array([[np.nan, -np.inf, -1.0, 0.0, 0.0004],
                  [0.0006, 1.0, 1.2344, 65.535, 65.5356],
                  [70.0, np.inf, 2.5, 1e9, 0.001]], np.float32)
    mm, clipped = encode_mm16(x)
    assert mm.dtype == np.uint16
    assert mm.tolist() == [[0, 0, 0, 0, 0],                     # unknown, and below 0.5 mm
                           [1, 1000, 1234, 65535, 65535],
                           [65535, 65535, 2500, 65535, 1]]
    assert clipped == 4  # 65.5356, 70, +inf, 1e9 m: clipped, and counted


def test_float32_maps_round_as_float32():
    # the writers always handed float32 maps; the same bits as rounding in float32 (no float64 detour)
    x = np.array([1.0005, 2.0015, 0.0025], np.float32)
    assert encode_mm16(x)[0].tolist() == np.rint(x * np.float32(1000)).astype(np.uint16).tolist()


def test_round_trip_through_the_ground_truth_reader(tmp_path):
    depth = np.array([[0.5, 1.25, np.nan], [10.0, 65.0, 80.0]], np.float32)
    mm, clipped = encode_mm16(depth)
    p = tmp_path / "gt_depth_mm.png"
    assert imwrite(p, mm)
    back = read_depth_file(p) * M_PER_MM
    assert back[0, 0] == 0.5 and back[0, 1] == 1.25 and back[0, 2] == 0  # 0 = unknown
    assert back[1, 2] == MAX_MM * M_PER_MM and clipped == 1


@settings(max_examples=200, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(1, 6), st.integers(1, 6)),
              elements=st.floats(width=32, allow_nan=True, allow_infinity=True)))
def test_properties(x):
    mm, clipped = encode_mm16(x)
    assert mm.shape == x.shape and mm.dtype == np.uint16
    known = np.isfinite(x) & (x > 0)
    assert (mm[~known & (x != np.inf)] == 0).all()  # unknown -> 0
    with np.errstate(over="ignore"):
        far = (x * np.float32(1000) >= MAX_MM + 0.5) & (x > 0)  # +inf included
    assert (mm[far] == MAX_MM).all() and clipped == int(far.sum())
    near = known & ~far
    assert (np.abs(mm[near].astype(np.float64) - x[near].astype(np.float64) * 1000) <= 0.5 + 1e-3).all()
