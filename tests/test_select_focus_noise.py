"""The rule that chose the classical method's pre-filter and estimator (benchmarks/select_focus_noise.py), on
hand-computed cases."""

import pytest


@pytest.fixture(scope="module")
def select():
    from benchmarks import select_focus_noise

    return select_focus_noise


def test_geometric_mean_weighs_cells_alike(select):
    # a halves one cell and doubles another: geometric mean 1, so the reference (1, 1) ties it and b (0.8, 0.9)
    # wins even though a has the lowest single cell
    ratios = {"x clean": {("ratio", 0.0): 1.0, ("ratio", 1.0): 0.5, ("gauss", 1.0): 0.8},
              "x noise": {("ratio", 0.0): 1.0, ("ratio", 1.0): 2.0, ("gauss", 1.0): 0.9}}
    best, gm = select.choose(ratios)
    assert best == ("gauss", 1.0)
    assert gm[("ratio", 1.0)] == pytest.approx(1.0) and gm[("gauss", 1.0)] == pytest.approx((0.8 * 0.9) ** 0.5)


def test_ties_go_to_the_first_variant_in_sorted_order(select):
    ratios = {"c": {("ratio", 0.0): 1.0, ("gauss", 2.0): 1.0}}
    assert select.choose(ratios)[0] == ("gauss", 2.0)  # "gauss" sorts before "ratio"
    assert select.name(("ratio", 0.75)) == "ratio, σ 0.75 px"
