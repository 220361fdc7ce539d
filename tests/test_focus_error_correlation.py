"""The correlation length of the per-frame focus errors (benchmarks/focus_error_correlation.py) on hand-made rows:
errors drawn with a known correlation are read back, independent errors give none, rows of any capture but the
tuning capture never enter it."""

import numpy as np
import pytest

from aat_deploy.diagnose import focusfit as ff
from benchmarks import focus_error_correlation as fec

TRUE_D = np.linspace(1 / 0.6, 1 / 6.0, 8)  # the benchmark captures' focus: 0.214 D apart


def rows_drawn(length_d: float, n_sets: int, capture: str = "scene2029", seed: int = 0, scale: float = 1.3):
    """Rows as bench_diagnose_focus writes them: per-frame errors drawn Gaussian with sigma_i (bootstrap and
    systematic parts) x scale and correlation exp(-|d_i - d_j| / length_d); the per-frame estimates (the
    `per_frame` family) the truth plus them; the chosen family an offset."""
    rng = np.random.default_rng(seed)
    r = ff.error_correlation(TRUE_D[None], np.ones((1, 8)), length_d)[0]
    chol = np.linalg.cholesky(r)
    out = []
    for k in range(n_sets):
        sd = rng.uniform(0.001, 0.005, 8)
        sys_d = np.full(8, 0.01)
        sys_d[0] = 0.02
        err = scale * np.hypot(sd, sys_d) * (chol @ rng.standard_normal(8))
        est = TRUE_D + err
        off = TRUE_D + float(np.mean(err))
        out.append({"capture": capture, "kind": f"set{k}", "family": "offset", "frame_err_d": err.tolist(),
                    "frame_focus_sd_d": [sd.tolist()], "frame_systematic_d": [sys_d.tolist()],
                    "corrected_err_d": (off - TRUE_D).tolist(),
                    "families": [{"family": "none", "k": 0, "true_d": [(TRUE_D + 0.05).tolist()]},
                                 {"family": "offset", "k": 1, "true_d": [off.tolist()]},
                                 {"family": "per_frame", "k": 8, "true_d": [est.tolist()]}]})
    return out


def test_a_known_correlation_length_is_read_back_with_the_sigmas_off_by_a_factor():
    e = fec.estimate(rows_drawn(0.3, 400))
    assert 0.25 <= e["length_d"] <= 0.36 and e["interval_d"][0] <= 0.3 <= e["interval_d"][1]
    assert e["scale"] == pytest.approx(1.3, rel=0.1)  # the overall scale is profiled out, not read as correlation
    assert e["lags"][0][1] == pytest.approx(np.exp(-0.2143 / 0.3), abs=0.06)


def test_independent_errors_give_no_correlation():
    e = fec.estimate(rows_drawn(0.0, 400, seed=1))
    at_one_spacing = np.exp(-e["spacing_d"] / e["length_d"]) if e["length_d"] > 0 else 0.0
    assert at_one_spacing < 0.05 and e["interval_d"][0] == 0.0


def test_only_the_tuning_capture_enters_and_the_report_says_what_was_ignored():
    tune = rows_drawn(0.0, 60, seed=2)
    test = rows_drawn(2.0, 60, capture="scene2027", seed=3)
    assert fec.estimate(tune + test)["length_d"] == fec.estimate(tune)["length_d"]
    assert fec.estimate(tune + test, capture="scene2027")["length_d"] > 0.5  # the rows discriminate
    text = fec.report(tune + test)
    assert "rows of scene2027 ignored" in text and "60 sets" in text
    assert "| set0 | offset |" in text  # the corrected focus's z per set, independent and correlated
    with pytest.raises(SystemExit):
        fec.estimate(test)


def test_sensitivity_lists_the_flags_and_each_missed_sets_standard_error_per_length():
    rows = rows_drawn(0.0, 3, capture="scene2027", seed=4)
    rows[1]["corrected_err_d"][2] = 0.05  # a set with a frame 0.05 D off
    text = fec.sensitivity(rows, lengths=(0.0, 0.3))
    sd, sys_d = np.asarray(rows[1]["frame_focus_sd_d"]), np.asarray(rows[1]["frame_systematic_d"])
    independent = 1 / np.sqrt(np.sum(1 / (sd ** 2 + sys_d ** 2)))  # an offset: the inverse-variance mean's
    correlated = fec.row_sd(rows[1], 0.3)[2]
    assert correlated > independent  # the case discriminates
    assert f"| scene2027 set1: frame 2, 0.050 D off, its SE (D) | {independent:.4f} | {correlated:.4f} |" in text
    assert "| frames undetermined (SE >= 0.02 D) | 0 | 0 |" in text and "set0" not in text
