"""benchmarks/probes/corners.py (issue 33): each pixel beyond the farthest tile's radius moved along its ray to that
radius, and the split of the map's error there into the edge's own error, the truth's rise and the continuation,
by hand; its one-line refusals (the fits and renders are the probe's own minutes, not tested here)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.probes import corners as C


def test_ray_points_move_only_the_points_beyond_to_the_radius_on_their_ray():
    from aat_deploy.calibrate.format import field_radius_of

    a = 4 / 3
    x, y = np.array([0.1, 1.0, -1.0, 0.9]), np.array([0.2, 1.0, 0.5, -0.99])
    xq, yq = C.ray_points(x, y, a, 0.9)
    r = field_radius_of(x, y, a)
    assert (xq[0], yq[0]) == (0.1, 0.2)  # inside: unchanged
    out = r > 0.9
    assert out.sum() == 2 and np.allclose(field_radius_of(xq, yq, a)[out], 0.9)
    assert np.allclose(xq[out] / x[out], yq[out] / y[out])  # along the ray from the centre


def test_split_along_rays_adds_up_by_hand():
    pred_q = np.array([[1.0, 2.0], [0.0, 0.5]])
    truth_q = np.array([[0.5, 2.5], [0.0, 0.0]])
    truth_p = np.array([[1.5, 3.5], [0.5, 0.0]])
    held = C.split_along_rays(pred_q, pred_q, truth_p, truth_q)
    assert held["edge"]["mean_d"] == pytest.approx(np.mean([0.5, -0.5, 0.0, 0.5]))
    assert held["rise"]["mean_d"] == pytest.approx(np.mean([1.0, 1.0, 0.5, 0.0]))
    assert held["error"]["mean_d"] == pytest.approx(held["edge"]["mean_d"] - held["rise"]["mean_d"])
    assert held["continuation"] == {"rms_d": 0.0, "mean_d": 0.0}
    assert held["per_frame"][1]["error"]["rms_d"] == pytest.approx(np.sqrt((0.25 + 0.25) / 2))
    cont = C.split_along_rays(pred_q + 0.25, pred_q, truth_p, truth_q)  # continued 0.25 D beyond everywhere
    assert cont["continuation"]["mean_d"] == pytest.approx(0.25)
    assert cont["error"]["mean_d"] == pytest.approx(held["error"]["mean_d"] + 0.25)


@pytest.mark.parametrize("args, says", [
    (["--variants", "nominl"], "--variants: nominl not of"),
    (["--variants", ""], "nothing to run"),
    (["--beyond", "held"], "--beyond 'held': one of linear"),
])
def test_corners_refuses_bad_arguments_in_one_line_before_reading_the_truth(tmp_path, capsys, args, says):
    with pytest.raises(SystemExit):
        C.main(["--truth", str(tmp_path / "no_truth.json"), *args, "--out", str(tmp_path / "o.json")])
    assert says in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "o.json").exists()


def test_outside_rectangle_by_hand():
    x = np.array([0.0, 0.9, 0.91, -0.8, -0.81, 0.5])
    y = np.array([0.0, 0.6, 0.0, -0.7, 0.0, 0.61])
    assert C.outside_rectangle(x, y, (-0.8, 0.9, -0.7, 0.6)).tolist() == [False, False, True, False, True, True]
