#!/usr/bin/env python3
"""Build aat_deploy/lens/data/glasses.json from the refractiveindex.info database.

The database (CC0) ships as YAML files inside the optiland package
(optiland/database/data-nk); optiland is used only to find that folder, so the
JSON it writes needs neither optiland nor PyYAML. Rerun with:

    python -m scripts.build_glass_catalog
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
from pathlib import Path

import numpy as np
import yaml

OUT = Path(__file__).resolve().parents[1] / "aat_deploy" / "lens" / "data" / "glasses.json"
LAMBDA_D, LAMBDA_F, LAMBDA_C = 0.5875618, 0.4861327, 0.6562725  # Fraunhofer d, F, C lines [um]

# Catalog name -> YAML file under data-nk/. Schott's own data wherever the database has it.
DATABASE_FILES = {
    "N-LASF41": "glass/schott/N-LASF41.yml",
    "N-LASF43": "glass/schott/N-LASF43.yml",
    "SF6": "glass/schott/SF6.yml",
    "SF5": "glass/schott/SF5.yml",
    "K5G20": "glass/schott/K5G20.yml",
    "N-LAK10": "glass/schott/N-LAK10.yml",
    "N-SK2": "glass/schott/N-SK2.yml",
    "N-SK16": "glass/schott/N-SK16.yml",
    "F5": "glass/schott/F5.yml",
    "F2": "glass/schott/F2.yml",
    "N-F2": "glass/schott/N-F2.yml",
    # No Schott SK16 in the database: Hikari's glass of the same name and code (620603).
    "SK16": "glass/hikari/SK16.yml",
    "N-BK7": "glass/schott/N-BK7.yml",
    "N-SF2": "glass/schott/N-SF2.yml",
}

# Optical plastics by the names lens files use (DeepLens, Zemax): the Zemax catalogues' Schott-formula
# coefficients (CD line) and nd/Vd (NM line), as shipped in deeplens-core 2.5.6 (deeplens/material/MISC.AGF,
# PLASTIC2022.AGF), which is how DeepLens resolves "pmma", "coc", "polycarb" and "okp4". A lens designed in
# DeepLens gets the indices it was designed with (refractiveindex.info's PMMA/PC/Zeonex fits differ by up to
# 0.003 in nd: the cellphone lens's EFL moved by 1 %).
_ZEMAX = "Zemax {} as shipped in deeplens-core 2.5.6 (deeplens/material/{}): Schott formula, NM line nd {} Vd {}"
ZEMAX_SCHOTT = {
    "PMMA": ((2.1864582, -2.4475348e-4, 1.4155787e-2, -4.4329781e-4, 7.7664259e-5, -2.9936382e-6),
             _ZEMAX.format("MISC.AGF", "MISC.AGF", "1.491756", "57.440791") + "; Handbook of Optics Vol. II"),
    "COC": ((2.28448546, 1.02952211e-2, 3.73493703e-2, -9.28409653e-3, 1.73289808e-3, -1.15203047e-4),
            _ZEMAX.format("MISC.AGF", "MISC.AGF", "1.533732", "56.227932") + "; Hoechst Celanese spec sheet"),
    "POLYCARB": ((2.42838566, -3.86116645e-5, 2.87574474e-2, -1.97897366e-4, 1.48358968e-4, 1.38651935e-6),
                 _ZEMAX.format("MISC.AGF", "MISC.AGF", "1.585470", "29.909185") + "; Handbook of Optics Vol. II"),
    "OKP4": ((1.6768, 0.55567, 0.49774, -0.1329, 0.01906, -0.001068),
             _ZEMAX.format("PLASTIC2022.AGF", "PLASTIC2022.AGF", "1.607283", "26.645105")
             + "; OKP4, Osaka Gas Chemicals"),
}

# Not in the database (checked by name and by glass code): nd, Vd from a published catalogue.
# SCHOTT.AGF and PLASTIC2022.AGF are the Zemax catalogues shipped in deeplens-core 2.5.6 on PyPI.
_AGF = "Zemax {} (as shipped in deeplens-core 2.5.6, deeplens/material/{}), NM line nd/Vd"
NOT_IN_DATABASE = {
    "SSK4": (1.617650, 55.141867, _AGF.format("SCHOTT.AGF", "SCHOTT.AGF") + " of SSK4A (code 618551, 'old')"),
    "SK1": (1.610250, 56.712386, _AGF.format("SCHOTT.AGF", "SCHOTT.AGF") + " of SK1 (code 610567, 'old')"),
    "F15": (1.605651, 37.830856, _AGF.format("SCHOTT.AGF", "SCHOTT.AGF") + " of F15 (code 606378, 'old')"),
}

ABOUT = (
    "Optical glass catalog for aat. Lambda in micrometres. "
    "Sellmeier: n^2 = 1 + A + sum_i B[i]*l^2/(l^2 - C[i]) with C in um^2. "
    "nd_vd: 2-term Cauchy n = a + b/l^2 through nd at 587.56 nm with Abbe number vd (see materials.py). "
    "schott: n^2 = a0 + a1*l^2 + a2/l^2 + a3/l^4 + a4/l^6 + a5/l^8 (Zemax formula 1). "
    "nd, vd of every entry: at d 587.5618, F 486.1327, C 656.2725 nm, vd = (nd-1)/(nF-nC)."
)


def database_root() -> Path:
    spec = importlib.util.find_spec("optiland")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("optiland is not installed: pip install optiland")
    return Path(list(spec.submodule_search_locations)[0]) / "database" / "data-nk"


def dispersion_block(path: Path) -> dict:
    """First block of the file that gives n (the files also hold 'tabulated k' blocks)."""
    for block in yaml.safe_load(path.read_text(encoding="utf-8"))["DATA"]:
        kind = block["type"].strip()
        if kind.startswith("formula") or kind in ("tabulated n", "tabulated nk"):
            return {**block, "type": kind}
    raise ValueError(f"{path}: no refractive-index data")


def coefficients(block: dict) -> list[float]:
    return [float(x) for x in str(block["coefficients"]).split()]


def sellmeier(block: dict) -> tuple[float, list[float], list[float]] | None:
    """(A, B, C) in our form, or None when the formula is not a Sellmeier one."""
    if block["type"] not in ("formula 1", "formula 2"):
        return None
    c = coefficients(block)
    poles = c[2::2] if block["type"] == "formula 2" else [p * p for p in c[2::2]]  # formula 1 squares them
    return c[0], c[1::2], poles


def index(block: dict, lam: float) -> float:
    """Refractive index at lam [um] for the formulas these files use."""
    kind = block["type"]
    if kind in ("formula 1", "formula 2"):
        a, b, c = sellmeier(block)
        return float(np.sqrt(1 + a + sum(bi * lam**2 / (lam**2 - ci) for bi, ci in zip(b, c))))
    if kind in ("formula 3", "formula 5"):  # polynomial: n^2 (3) or n (5) = c0 + sum c_i * lam^p_i
        c = coefficients(block)
        s = c[0] + sum(ci * lam**pi for ci, pi in zip(c[1::2], c[2::2]))
        return float(np.sqrt(s)) if kind == "formula 3" else s
    if kind.startswith("tabulated"):
        table = np.array([row.split()[:2] for row in block["data"].split("\n") if row.strip()], float)
        return float(np.interp(lam, table[:, 0], table[:, 1]))
    raise ValueError(f"unsupported {kind}")


def schott_index(a: tuple[float, ...], lam: float) -> float:
    """Zemax formula 1 (Schott) at lam [um]."""
    l2 = lam * lam
    return float(np.sqrt(a[0] + a[1] * l2 + a[2] / l2 + a[3] / l2**2 + a[4] / l2**3 + a[5] / l2**4))


def wavelength_range(block: dict) -> list[float]:
    if "wavelength_range" in block:
        return [float(x) for x in str(block["wavelength_range"]).split()]
    rows = [float(r.split()[0]) for r in block["data"].split("\n") if r.strip()]
    return [min(rows), max(rows)]


def nd_vd(block: dict) -> tuple[float, float]:
    nd, nf, nc = (index(block, lam) for lam in (LAMBDA_D, LAMBDA_F, LAMBDA_C))
    return nd, (nd - 1) / (nf - nc)


def entry(root: Path, rel: str) -> dict:
    block = dispersion_block(root / rel)
    lo, hi = wavelength_range(block)
    if not (lo <= LAMBDA_F and LAMBDA_C <= hi):  # nd/vd must not be extrapolated
        raise ValueError(f"{rel}: range {lo}-{hi} um misses the F..C lines")
    nd, vd = nd_vd(block)
    coeffs = sellmeier(block)
    if coeffs is None:  # e.g. Schott/Laurent polynomial: no exact Sellmeier form, keep nd/vd only
        return {"model": "nd_vd", "nd": round(nd, 6), "vd": round(vd, 3),
                "source": f"{rel} ({block['type']}, not Sellmeier): nd, vd evaluated from it"}
    a, b, c = coeffs
    return {"model": "sellmeier", "A": a, "B": b, "C": c, "range_um": [lo, hi],
            "nd": round(nd, 6), "vd": round(vd, 3), "source": rel}


def main() -> None:
    root = database_root()
    glasses = {name: entry(root, rel) for name, rel in DATABASE_FILES.items()}
    for name, (nd, vd, source) in NOT_IN_DATABASE.items():
        glasses[name] = {"model": "nd_vd", "nd": nd, "vd": vd, "source": source}
    for name, (coeffs, source) in ZEMAX_SCHOTT.items():
        nd, nf, nc = (schott_index(coeffs, lam) for lam in (LAMBDA_D, LAMBDA_F, LAMBDA_C))
        glasses[name] = {"model": "schott", "coefficients": list(coeffs), "nd": round(nd, 6),
                         "vd": round((nd - 1) / (nf - nc), 3), "source": source}

    version = importlib.metadata.version("optiland")
    catalog = {
        "_about": ABOUT,
        "_source": f"refractiveindex.info database (CC0) as bundled in optiland {version}; "
                   "regenerate with scripts/build_glass_catalog.py",
        "glasses": glasses,
    }
    # One glass per line keeps the file readable and its diffs small.
    lines = [f"    {json.dumps(k)}: {json.dumps(v)}" for k, v in glasses.items()]
    text = json.dumps({k: v for k, v in catalog.items() if k != "glasses"}, indent=2)[:-2]
    text += ',\n  "glasses": {\n' + ",\n".join(lines) + "\n  }\n}\n"
    assert json.loads(text) == catalog
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(text, encoding="utf-8")

    print(f"{'name':10s} {'model':9s} {'nd':>9s} {'vd':>7s}  source")
    for name, g in glasses.items():
        print(f"{name:10s} {g['model']:9s} {g['nd']:9.6f} {g['vd']:7.3f}  {g['source']}")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
