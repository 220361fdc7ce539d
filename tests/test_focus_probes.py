"""The issue-32 probes' arithmetic on hand-made cases: a frame's focus error split over regions
(`benchmarks/probes/focus_frame_regions.py`) and a family refitted to the per-frame estimates
(`benchmarks/probes/focus_family_on_estimates.py`)."""

from __future__ import annotations

import numpy as np

from benchmarks.probes import focus_family_on_estimates as fe
from benchmarks.probes import focus_frame_regions as fr


def test_a_frames_error_splits_over_its_regions_by_their_pull():
    """Quadratic region costs a_r (x - m_r)^2: the estimate is the a-weighted mean of the m_r, each region pulls
    a_r (m_r - true) / sum a, the pulls add up to the error, and leaving one out gives the others' mean."""
    xs = np.arange(0.8, 1.2 + 1e-9, 0.0005)
    a, m, true = np.array([1.0, 3.0, 0.5]), np.array([1.05, 0.98, 1.10]), 1.0
    costs = a * (xs[:, None] - m) ** 2
    dec = fr.decompose(costs, xs, true)
    est = float(np.sum(a * m) / a.sum())
    assert abs(dec["est"] - est) <= 0.0005
    assert np.allclose(dec["pull"], a * (m - true) / a.sum(), atol=2e-3)
    assert abs(dec["pull"].sum() - (dec["est"] - true)) < 1e-9  # exact by construction of the secant
    assert np.allclose(dec["own"], m, atol=0.0005)
    loo0 = np.sum(a[1:] * m[1:]) / a[1:].sum()
    assert abs(dec["loo"][0] - loo0) <= 0.0005
    assert int(np.argmax(np.abs(dec["pull"]))) == 1  # the heavy region, though region 2 sits farther off


def test_a_family_refitted_to_the_estimates_is_their_weighted_least_squares():
    """An offset row: the refit is the reported focus less the inverse-variance weighted mean of (reported -
    estimate); a frame with a 10x smaller variance dominates it."""
    rep = np.array([1.6, 1.2, 0.8, 0.4])
    est = rep - np.array([0.05, 0.06, 0.04, 0.10])
    sd = np.array([0.01, 0.01, 0.01, 0.01])
    sys_d = np.array([0.01, 0.01, 0.01, 0.1])  # the last frame barely counts
    row = {"family": "offset", "frame_focus_sd_d": [sd.tolist()], "frame_systematic_d": [sys_d.tolist()],
           "families": [{"family": "none", "true_d": [rep.tolist()]},
                        {"family": "offset", "true_d": [(rep - 0.06).tolist()]},
                        {"family": "per_frame", "true_d": [est.tolist()]}]}
    w = 1 / (sd ** 2 + sys_d ** 2)
    b = np.sum(w * (rep - est)) / w.sum()
    assert np.allclose(fe.refit(row), rep - b)
    assert abs(b - 0.05) < 0.002
    assert fe.refit(dict(row, family="quantisation")) is None  # not linear in its parameters: not refitted
