"""Refractive-index models: air, "nd/Vd" strings (2-term Cauchy) and named glasses (Sellmeier, or the Schott
formula of Zemax catalogues for the plastics).

All indices are relative to air, as in lens-design programs and glass catalogues, so air is exactly 1.
Wavelengths are in nanometres at the public interface (the catalogue stores micrometres).

The "nd/Vd" convention is the paper's: a 2-term Cauchy model n(λ) = A + B/λ² whose Abbe number is defined
with the F (486.1 nm) and C (656.3 nm) lines and which passes through nd at 589.3 nm.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources

import numpy as np

from ..errors import AatError

# Spectral lines (nm) used by the paper's "nd/Vd" Cauchy convention.
CAUCHY_ANCHOR_NM = 589.3
LINE_F_NM = 486.1
LINE_C_NM = 656.3
# Fraunhofer lines used to report a catalogue glass's nd/Vd.
D_LINE_NM = 587.5618
F_LINE_NM = 486.1327
C_LINE_NM = 656.2725

_ND_VD = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*/\s*([0-9]*\.?[0-9]+)\s*$")
_AIR_NAMES = {"air", "vacuum", "occluder", ""}


class UnknownMaterialError(AatError):
    """A material name that is neither air, an "nd/Vd" pair nor a glass in the shipped catalogue."""


@dataclass(frozen=True)
class Material:
    """A dispersive medium; `n(wavelength_nm)` returns the refractive index relative to air."""

    name: str

    def n(self, wavelength_nm):  # pragma: no cover - interface
        raise NotImplementedError

    @property
    def is_air(self) -> bool:
        return False

    def nd_vd(self) -> tuple[float, float]:
        """(nd, Vd) at the Fraunhofer d, F and C lines."""
        nd, nf, nc = (float(self.n(w)) for w in (D_LINE_NM, F_LINE_NM, C_LINE_NM))
        return nd, (nd - 1.0) / (nf - nc) if nf != nc else float("inf")


@dataclass(frozen=True)
class Air(Material):
    name: str = "air"

    def n(self, wavelength_nm):
        return np.ones_like(np.asarray(wavelength_nm, dtype=np.float64)) * 1.0

    @property
    def is_air(self) -> bool:
        return True


@dataclass(frozen=True)
class CauchyNdVd(Material):
    """2-term Cauchy model from (nd, Vd). Defaults: the paper's convention (nd at 589.3 nm, F/C at 486.1 and
    656.3 nm); catalogue entries given only as nd/Vd use the Fraunhofer d, F, C lines instead."""

    nd: float = 1.5
    vd: float = 60.0
    anchor_nm: float = CAUCHY_ANCHOR_NM
    f_nm: float = LINE_F_NM
    c_nm: float = LINE_C_NM

    @property
    def coefficients(self) -> tuple[float, float]:
        """(A, B) of n = A + B / λ², λ in nm."""
        b = (self.nd - 1.0) / (self.vd * (1.0 / self.f_nm**2 - 1.0 / self.c_nm**2))
        a = self.nd - b / self.anchor_nm**2
        return a, b

    def n(self, wavelength_nm):
        a, b = self.coefficients
        w = np.asarray(wavelength_nm, dtype=np.float64)
        return a + b / w**2


@dataclass(frozen=True)
class Sellmeier(Material):
    """n² = 1 + A + Σ Bᵢ λ² / (λ² − Cᵢ), λ in µm, Cᵢ in µm² (catalogue glasses)."""

    A: float = 0.0
    B: tuple[float, ...] = ()
    C: tuple[float, ...] = ()
    range_um: tuple[float, float] | None = field(default=None, compare=False)
    source: str = field(default="", compare=False)

    def n(self, wavelength_nm):
        l2 = (np.asarray(wavelength_nm, dtype=np.float64) / 1000.0) ** 2
        n2 = 1.0 + self.A
        for b, c in zip(self.B, self.C):
            n2 = n2 + b * l2 / (l2 - c)
        return np.sqrt(n2)


@dataclass(frozen=True)
class SchottFormula(Material):
    """n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸, λ in µm (Zemax formula 1, "Schott"): the
    optical plastics of Zemax's MISC and PLASTIC catalogues, as DeepLens resolves "pmma", "coc", "polycarb",
    "okp4", so lens files written for DeepLens get the indices they were designed with."""

    coefficients: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    range_um: tuple[float, float] | None = field(default=None, compare=False)
    source: str = field(default="", compare=False)

    def n(self, wavelength_nm):
        l2 = (np.asarray(wavelength_nm, dtype=np.float64) / 1000.0) ** 2
        a0, a1, a2, a3, a4, a5 = self.coefficients
        return np.sqrt(a0 + a1 * l2 + a2 / l2 + a3 / l2**2 + a4 / l2**3 + a5 / l2**4)


@lru_cache(maxsize=1)
def glass_catalog() -> dict[str, dict]:
    """The shipped glass catalogue (aat_deploy/lens/data/glasses.json), keyed by upper-case name."""
    text = resources.files("aat_deploy.lens").joinpath("data/glasses.json").read_text(encoding="utf-8")
    return {k.upper(): v for k, v in json.loads(text)["glasses"].items()}


def _from_catalog(name: str, entry: dict) -> Material:
    model = entry.get("model")
    if model == "sellmeier":
        rng = entry.get("range_um")
        return Sellmeier(
            name=name,
            A=float(entry.get("A", 0.0)),
            B=tuple(float(b) for b in entry["B"]),
            C=tuple(float(c) for c in entry["C"]),
            range_um=tuple(rng) if rng else None,
            source=entry.get("source", ""),
        )
    if model == "schott":
        rng = entry.get("range_um")
        return SchottFormula(name=name, coefficients=tuple(float(a) for a in entry["coefficients"]),
                             range_um=tuple(rng) if rng else None, source=entry.get("source", ""))
    if model == "nd_vd":
        return CauchyNdVd(name=name, nd=float(entry["nd"]), vd=float(entry["vd"]),
                          anchor_nm=D_LINE_NM, f_nm=F_LINE_NM, c_nm=C_LINE_NM)
    raise UnknownMaterialError(f"glass catalogue entry {name!r} has unsupported model {model!r}")


def parse_material(spec: str) -> Material:
    """Material from a spec string: "air", "nd/Vd" such as "1.83481/42.7", or a catalogue glass name.

    Raises UnknownMaterialError with the offending name for anything else.
    """
    s = str(spec).strip()
    if s.lower() in _AIR_NAMES:
        return Air()
    m = _ND_VD.match(s)
    if m:
        nd, vd = float(m.group(1)), float(m.group(2))
        if nd < 1.0 or vd <= 0.0:
            raise UnknownMaterialError(f"material {s!r}: nd must be >= 1 and Vd > 0")
        return CauchyNdVd(name=s, nd=nd, vd=vd)
    cat = glass_catalog()
    entry = cat.get(s.upper())
    if entry is None:
        raise UnknownMaterialError(
            f"unknown glass {s!r}: not 'air', not 'nd/Vd', and not in the shipped catalogue "
            f"({', '.join(sorted(cat))})"
        )
    return _from_catalog(s.upper(), entry)
