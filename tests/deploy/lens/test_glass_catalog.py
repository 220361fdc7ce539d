"""Checks of aat_deploy/lens/data/glasses.json that need neither optiland nor shared/."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

CATALOG = Path(__file__).resolve().parents[3] / "aat_deploy" / "lens" / "data" / "glasses.json"
LAMBDA_D, LAMBDA_F, LAMBDA_C = 0.5875618, 0.4861327, 0.6562725  # um

# Published catalogue nd / Vd, hard-coded so the test runs without shared/.
REFERENCE = {
    # Zemax "Double Gauss Experimental Arrangement" sample (deeplens_zemax_double_gaussian.zmx),
    # GCAT SCHOTT: Zemax wrote the catalogue's nd/Vd next to each GLAS name.
    "N-SK2": (1.60738, 56.65),
    "N-SK16": (1.62041, 60.32),
    "F5": (1.60342, 38.03),
    # sdirt_rf50mm_f1.8.zmx, for the names whose nd/Vd there are the glass's own.
    "SF6": (1.80518, 25.4),
    "SF5": (1.6727, 32.1),
    # That same file lists the Canon patent's nd/Vd next to N-LASF41 (1.83481/42.7),
    # N-LASF43 (1.79952/42.2), K5G20 (1.5311/55.9) and N-LAK10 (1.734/51.5): those are
    # OHARA-type glasses (S-LAH55V, S-LAH52, ..., S-LAL59), not these SCHOTT glasses,
    # so the SCHOTT catalogue (SCHOTT.AGF, December 2024) is the reference here.
    "N-LASF41": (1.83501, 43.13),
    "N-LASF43": (1.80610, 40.61),
    "K5G20": (1.52344, 56.76),
    "N-LAK10": (1.72003, 50.62),
    "N-BK7": (1.51680, 64.17),
    "N-SF2": (1.64769, 33.82),
    "F2": (1.62004, 36.37),
    "N-F2": (1.62005, 36.43),
    # DiffOptics' material table (from SUMITA.AGF) used with its US 2,532,751 double Gauss.
    "SSK4": (1.61770, 55.116),
    "SK1": (1.61030, 56.712),
    "SK16": (1.62040, 60.306),
    "F15": (1.60570, 37.831),
}
REQUIRED = set(REFERENCE) | {"PMMA", "POLYCARB", "COC", "OKP4"}


@pytest.fixture(scope="module")
def glasses() -> dict[str, dict]:
    return json.loads(CATALOG.read_text(encoding="utf-8"))["glasses"]


def sellmeier_index(g: dict, lam: float) -> float:
    terms = sum(b * lam**2 / (lam**2 - c) for b, c in zip(g["B"], g["C"], strict=True))
    return math.sqrt(1 + g["A"] + terms)


def test_catalog_has_required_glasses(glasses: dict[str, dict]) -> None:
    assert REQUIRED <= set(glasses)
    assert all(name == name.upper() for name in glasses)  # lookups upper-case the name
    for name, g in glasses.items():
        assert g["model"] in ("sellmeier", "nd_vd", "schott"), name
        assert 1.3 < g["nd"] < 2.1 and 15 < g["vd"] < 100, name
        assert g["source"], name


def test_schott_entries_reproduce_stored_nd_vd(glasses: dict[str, dict]) -> None:
    for name, g in glasses.items():
        if g["model"] != "schott":
            continue
        a = g["coefficients"]
        n = lambda lam: math.sqrt(a[0] + a[1] * lam**2 + sum(a[k] * lam ** (-2 * (k - 1)) for k in range(2, 6)))
        nd, nf, nc = n(LAMBDA_D), n(LAMBDA_F), n(LAMBDA_C)
        assert nd == pytest.approx(g["nd"], abs=1e-6), name
        assert (nd - 1) / (nf - nc) == pytest.approx(g["vd"], abs=1e-3), name


def test_sellmeier_entries_reproduce_stored_nd_vd(glasses: dict[str, dict]) -> None:
    for name, g in glasses.items():
        if g["model"] != "sellmeier":
            continue
        lo, hi = g["range_um"]
        assert lo <= LAMBDA_F and LAMBDA_C <= hi, name
        nd, nf, nc = (sellmeier_index(g, lam) for lam in (LAMBDA_D, LAMBDA_F, LAMBDA_C))
        # stored nd and vd carry 6 and 3 decimals (float64 Sellmeier sums round ~1e-16)
        assert nd == pytest.approx(g["nd"], abs=1e-6), name
        assert (nd - 1) / (nf - nc) == pytest.approx(g["vd"], abs=1e-3), name


@pytest.mark.parametrize("name", sorted(REFERENCE))
def test_catalog_matches_published_nd_vd(glasses: dict[str, dict], name: str) -> None:
    nd, vd = REFERENCE[name]
    # the references print nd to 4-5 decimals and vd to 1-2, from other catalogue editions: not a rounding bound
    assert glasses[name]["nd"] == pytest.approx(nd, abs=2e-4)
    assert glasses[name]["vd"] == pytest.approx(vd, abs=0.3)
