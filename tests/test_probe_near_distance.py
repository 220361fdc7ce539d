"""benchmarks/probes/near_distance.py's pieces (its run renders nothing but needs the cached development sweeps):
the split of a fitted shift into parts adds up for a shift linear in the objects, the profile's minimum, and a
used --out or an unknown variant is refused before anything runs."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.probes import near_distance as N


class _Obs:
    def __init__(self, sweep):
        self.sweep = sweep


def test_shift_parts_add_up_for_a_linear_fit_and_name_each_part():
    rng = np.random.default_rng(0)
    n = 400
    sweep = np.repeat(np.arange(4), n // 4)
    radius = rng.uniform(0, 0.92, n)
    h = rng.normal(size=n)  # a shift linear in the objects (the least squares' row for the shift)
    shift_of = lambda obj: float(h @ obj)
    exact, tape, meas = rng.normal(size=n), rng.normal(size=n) * 0.1, rng.normal(size=n) * 0.05
    p = N.shift_parts(_Obs(sweep), exact, tape, meas, radius, shift_of)
    assert p["exact"] == pytest.approx(h @ exact)
    assert p["all"] == pytest.approx(h @ (exact + tape + meas))
    assert p["sum_of_parts"] == pytest.approx(p["all"])
    assert p["tape"][2] == pytest.approx(float(h[sweep == 2] @ tape[sweep == 2]))
    b = (sweep == 3) & (radius >= 0.5) & (radius < 0.66)
    cell = p["measurement"][3]["0.5-0.66"]
    assert cell["shift_mm"] == pytest.approx(float(h[b] @ meas[b])) and cell["tiles"] == int(b.sum())
    # a fit that is not linear in the objects does not add up: the check can fail
    q = N.shift_parts(_Obs(sweep), exact, tape, meas, radius, lambda obj: float(h @ obj) ** 2)
    assert abs(q["sum_of_parts"] - q["all"]) > 1e-3


def test_parabola_min():
    x = np.round(np.arange(54.4, 56.41, 0.2), 1)
    assert N.parabola_min(x, 2.0 * (x - 55.13) ** 2 + 3) == pytest.approx(55.13)
    assert N.parabola_min(x, x) == pytest.approx(54.4)  # the least value at an end: that end


def test_refusals(tmp_path):
    used = tmp_path / "r.json"
    used.write_text("{}")
    for argv in (["--truth", "results/render_truth_map_cellphone_19p.json", "--out", str(used)],
                 ["--truth", "results/render_truth_map_cellphone_19p.json", "--variants", "copy_s9_0",
                  "--out", str(tmp_path / "n.json")]):
        with pytest.raises(SystemExit) as e:
            N.main(argv)
        assert e.value.code == 2
    assert not (tmp_path / "n.json").exists()
