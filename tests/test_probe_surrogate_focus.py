"""benchmarks/probes/surrogate_focus.py: the PSF's RMS radius about its centroid, by hand."""

import numpy as np
import pytest

from benchmarks.probes.surrogate_focus import rms_radius_px


def test_rms_radius_by_hand():
    k = np.zeros((3, 5, 5))
    k[0, 2, 2] = 1.0  # a point: 0
    k[1, 2, 1] = k[1, 2, 3] = 0.5  # two halves 2 cells apart: 1 cell from their centroid
    k[2, 0, 0] = 3.0  # a point off-centre: still 0 about its own centroid
    k[2, 4, 4] = 1.0  # ... plus a quarter of the weight 4 * sqrt(2) cells away: sqrt(0.75 * 0.25) * 4 * sqrt(2)
    got = rms_radius_px(k, np.array([1.0, 2.0, 1.0]))
    assert got[0] == pytest.approx(0.0, abs=1e-12)
    assert got[1] == pytest.approx(2.0)  # 1 cell of 2 px
    assert got[2] == pytest.approx(np.sqrt(0.75 * 0.25) * 4 * np.sqrt(2))
