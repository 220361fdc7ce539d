"""benchmarks/probes/tile_bias.py and exact_tiles_order.py (issue 33): their pure parts and their one-line refusals
(the renders and fits themselves are the probes' own minutes, not tested here)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.probes import exact_tiles_order as E
from benchmarks.probes import tile_bias as T


def test_bins_split_by_field_radius_keep_the_last_edge_and_skip_nan():
    r = np.array([0.1, 0.2, 0.4, 0.92, 0.93, 0.6])
    v = np.array([1.0, 3.0, -2.0, 5.0, 7.0, np.nan])
    b = T._bins(r, v)
    assert b["0-0.33"] == {"n": 2, "mean_d": 2.0, "sd_d": 1.0}
    assert b["0.33-0.5"]["mean_d"] == -2.0
    assert b["0.84-0.92"]["n"] == 1 and b["0.84-0.92"]["mean_d"] == 5.0  # 0.92 is the last bin's; 0.93 is beyond
    assert b["0.5-0.66"] == {"n": 0, "mean_d": None, "sd_d": None}  # its one value is NaN
    assert b["all"]["n"] == 5 and b["all"]["mean_d"] == pytest.approx(2.8)  # "all" holds the tile beyond 0.92 too
    assert b["all"]["rms_d"] == pytest.approx(np.sqrt(np.mean(np.array([1, 3, -2, 5, 7.0]) ** 2)))


def test_paired_matches_tiles_by_row_and_column():
    a = {"row": np.array([0, 0, 1]), "col": np.array([0, 1, 0]), "r": np.array([0.1, 0.2, 0.4])}
    b = {"row": np.array([1, 0, 5]), "col": np.array([0, 1, 5]), "r": np.array([0.4, 0.2, 0.9])}
    out = T._paired(a, b, np.array([1.0, 2.0, 3.0]), np.array([3.5, 2.25, 9.0]))
    assert out["0-0.33"] == {"n": 1, "mean_d": 0.25, "sd_d": 0.0}  # (0, 1): 2.25 - 2
    assert out["0.33-0.5"]["mean_d"] == 0.5  # (1, 0): 3.5 - 3
    assert out["all"]["n"] == 2  # (5, 5) has no partner


@pytest.mark.parametrize("args, says", [
    (["--variants", "nominal,nominl"], "--variants: nominl not of"),
    (["--renders", "0.1,ten"], "chart distances in m"),
    (["--variants", "", "--renders", ""], "nothing to run"),
    (["--until", "22"], "--until '22': a UTC time as HH:MM"),
])
def test_tile_bias_refuses_bad_arguments_in_one_line_before_reading_the_truth(tmp_path, capsys, args, says):
    with pytest.raises(SystemExit):
        T.main(["--truth", str(tmp_path / "no_truth.json"), *args, "--out", str(tmp_path / "o.json")])
    assert says in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "o.json").exists()


def test_tile_bias_and_exact_tiles_order_refuse_a_truth_that_is_not_there(tmp_path, capsys):
    for main, prog in ((T.main, "tile_bias"), (E.main, "exact_tiles_order")):
        with pytest.raises(SystemExit) as e:
            main(["--truth", str(tmp_path / "no_truth.json"), "--variants", "nominal", "--out", str(tmp_path / "o.json")])
        assert str(e.value).startswith(f"{prog}: --truth") and "\n" not in str(e.value)
    assert not (tmp_path / "o.json").exists()


def test_exact_tiles_order_refuses_an_unknown_option_or_an_existing_out(tmp_path, capsys):
    with pytest.raises(SystemExit):
        E.main(["--truth", "t.json", "--options", "as is,degree to 9", "--out", str(tmp_path / "o.json")])
    assert "not a variant or option: degree to 9" in capsys.readouterr().err.strip().splitlines()[-1]
    (tmp_path / "o.json").write_text("mine")
    with pytest.raises(SystemExit):
        E.main(["--truth", "t.json", "--out", str(tmp_path / "o.json")])
    assert "exists" in capsys.readouterr().err.strip().splitlines()[-1]


def test_patched_changes_the_model_constants_for_the_block_alone():
    from aat_deploy.calibrate import model as M

    before = (M.DEGREES, M.EDGE_POWER)
    with E.patched(E.OPTIONS["degree to 8"] | E.OPTIONS["edge from rho^6"]):
        assert M.DEGREES[-1] == 8 and M.EDGE_POWER == 6
    assert (M.DEGREES, M.EDGE_POWER) == before
    with pytest.raises(RuntimeError), E.patched({"EDGE_POWER": 4}):
        raise RuntimeError
    assert M.EDGE_POWER == before[1]



def test_patched_changes_the_formats_limits_too_for_the_block_alone():
    """The declared option "radial to 20" (docs/calibration.md): `format.NAME` keys patch aat_deploy.calibrate.format,
    the others the model, and both are restored after the block, also when it raises."""
    from aat_deploy.calibrate import format as F
    from aat_deploy.calibrate import model as M

    before = (M.RADIAL, F.MAX_DEGREE, F.MAX_TERMS)
    with E.patched(E.OPTIONS["radial to 20"]):
        assert (M.RADIAL, F.MAX_DEGREE, F.MAX_TERMS) == ((0, 8, 12, 16, 20), 20, 128)
        assert not hasattr(M, "format.MAX_DEGREE")
    assert (M.RADIAL, F.MAX_DEGREE, F.MAX_TERMS) == before
    with pytest.raises(RuntimeError), E.patched(E.OPTIONS["radial to 20"]):
        raise RuntimeError
    assert (M.RADIAL, F.MAX_DEGREE, F.MAX_TERMS) == before


def test_patched_bench_refuses_an_unknown_option_or_no_bench_arguments(capsys):
    from benchmarks.probes import patched_bench as PB

    for argv, says in ((["--option", "nope", "--", "--parts", "map"], "not of"), (["--option", "radial to 20"],
                                                                                   "after --")):
        with pytest.raises(SystemExit):
            PB.main(argv)
        assert says in capsys.readouterr().err.strip().splitlines()[-1]

def test_design_counts_its_columns_and_reaches_a_radial_power_only_when_it_holds_it():
    """`_design`: degree 6's 27 monomials (no constant) x 3 Legendre terms, rho^8..12 x 4 (the edge powers' cubic),
    3 on-axis terms = 96 (the fit's largest); a field rho^16 t is fitted exactly by the basis to rho^16 and not by
    the one to rho^12."""
    rng = np.random.default_rng(0)
    x, y, t = rng.uniform(-1, 1, 600), rng.uniform(-1, 1, 600), rng.uniform(0.5, 3.0, 600)
    assert E._design(x, y, t, 1.5, (0.5, 3.0), (6, 12, 2, 3)).shape[1] == 96
    from aat_deploy.calibrate.format import field_radius_of

    target = field_radius_of(x, y, 1.5) ** 16 * t
    resid = {}
    for b in ((6, 12, 2, 3), (6, 16, 2, 3)):
        a = E._design(x, y, t, 1.5, (0.5, 3.0), b)
        sol, *_ = np.linalg.lstsq(a, target, rcond=None)
        resid[b[1]] = float(np.sqrt(np.mean((a @ sol - target) ** 2)))
    assert resid[16] < 1e-8 < 1e-4 < resid[12]


def test_patched_changes_the_fits_beyond_mode_for_the_block_alone():
    """The declared option "beyond linear" (docs/calibration.md, "The corners beyond the farthest tile"): a `fit.NAME`
    key patches aat_deploy.calibrate.fit, restored after the block, also when it raises."""
    from aat_deploy.calibrate import fit as FIT

    before = FIT.BEYOND_TILES
    with E.patched(E.OPTIONS["beyond linear"]):
        assert FIT.BEYOND_TILES == "linear"
    assert FIT.BEYOND_TILES == before == "held"
    with pytest.raises(RuntimeError), E.patched(E.OPTIONS["beyond linear"]):
        raise RuntimeError
    assert FIT.BEYOND_TILES == before
    with E.patched(E.OPTIONS["beyond rectangle"]):  # declared 2026-11-28, "The corners held at ... rectangle"
        assert FIT.BEYOND_TILES == "rectangle"
    assert FIT.BEYOND_TILES == before
