"""benchmarks/probes/phone_map_budget: a tile's ideal peak (where the truth has its object in focus) and the truth at
a measured peak, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.probes import phone_map_budget as pb


def test_ideal_peak_inverts_the_truth_and_the_truth_at_it_is_the_object():
    f = pb.F_GRID_D
    # two tiles: in focus 0.5 D nearer than the frame's focus, and 2 D farther; a third never in focus (too near)
    t = np.stack([f + 0.5, f - 2.0, np.minimum(f, 20.0)], 1)
    obj = np.array([10.0, 6.0, 30.0])
    ideal = pb.ideal_reported_d(t, obj, 1.1)
    assert ideal[0] == pytest.approx(9.5 / 1.1, abs=1e-9) and ideal[1] == pytest.approx(8.0 / 1.1, abs=1e-9)
    assert np.isnan(ideal[2])
    back = pb.truth_at_reported(t, ideal, 1.1)
    np.testing.assert_allclose(back[:2], obj[:2], atol=1e-9)
    assert np.isnan(back[2])
    # a tile peaking 0.3 D of reported focus late reads the truth's object 0.33 D nearer than its own (+ bias)
    assert pb.truth_at_reported(t[:, :1], ideal[:1] + 0.3, 1.1)[0] - obj[0] == pytest.approx(0.33, abs=1e-9)
