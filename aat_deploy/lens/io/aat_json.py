"""Our lens format, "aat-lens-v1" JSON (docs/contracts.md): read from a parsed dict, written atomically."""

from __future__ import annotations

import json
import math
from pathlib import Path

from ...io.atomic import write_text_atomic
from ..check import lens_file_error as _err
from ..check import validate
from ..schema import SURFACE_KINDS, Lens, Sensor, Surface


def _num(path, where: str, d: dict, key: str, default=None, required=True) -> float:
    if key not in d or d[key] is None:
        if required and default is None:
            raise _err(path, f"{where}: missing '{key}'")
        return default
    v = d[key]
    if isinstance(v, str) and v.strip().lower() in ("inf", "infinity"):
        return math.inf
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise _err(path, f"{where}: '{key}' must be a number, got {v!r}") from None
    if math.isnan(v):
        raise _err(path, f"{where}: '{key}' is NaN")
    return v


def lens_from_dict(d: dict, path="<dict>") -> Lens:
    """Build and validate a Lens from our JSON schema."""
    if d.get("format") != "aat-lens-v1":
        raise _err(path, f"not an aat-lens-v1 file (format={d.get('format')!r})")
    if d.get("units", "mm") != "mm":
        raise _err(path, f"units must be 'mm', got {d.get('units')!r}")
    raw = d.get("surfaces")
    if not isinstance(raw, list) or len(raw) < 1:
        raise _err(path, "'surfaces' must be a non-empty list")
    surfaces = []
    for i, s in enumerate(raw):
        where = f"surface {i}"
        if not isinstance(s, dict):
            raise _err(path, f"{where}: must be an object")
        kind = s.get("kind", "standard")
        if kind not in SURFACE_KINDS:
            raise _err(path, f"{where}: unknown kind {kind!r} (expected one of {SURFACE_KINDS})")
        if "curvature_per_mm" in s:
            c = _num(path, where, s, "curvature_per_mm")
        else:
            r = s.get("radius_mm", None)
            r = math.inf if r is None else _num(path, where, s, "radius_mm")
            c = 0.0 if (math.isinf(r) or r == 0) else 1.0 / r
        asph = s.get("asphere_from_r2", [])
        if not isinstance(asph, list):
            raise _err(path, f"{where}: 'asphere_from_r2' must be a list of numbers")
        surfaces.append(
            Surface(
                curvature_per_mm=c,
                thickness_mm=_num(path, where, s, "thickness_mm"),
                semi_diameter_mm=_num(path, where, s, "semi_diameter_mm"),
                material=str(s.get("material", "air")),
                conic=_num(path, where, s, "conic", 0.0, required=False),
                asphere_from_r2=tuple(float(a) for a in asph),
                kind=kind,
                focal_length_mm=_num(path, where, s, "focal_length_mm", required=kind == "ideal")
                if kind == "ideal"
                else None,
            )
        )
    sen = d.get("sensor")
    if not isinstance(sen, dict):
        raise _err(path, "missing 'sensor' object {width_mm, height_mm, width_px, height_px}")
    sensor = Sensor(
        width_mm=_num(path, "sensor", sen, "width_mm"),
        height_mm=_num(path, "sensor", sen, "height_mm"),
        width_px=int(_num(path, "sensor", sen, "width_px")),
        height_px=int(_num(path, "sensor", sen, "height_px")),
    )
    if "stop_index" not in d:
        raise _err(path, "missing 'stop_index'")
    lens = Lens(
        name=str(d.get("name", Path(str(path)).stem)),
        surfaces=tuple(surfaces),
        stop_index=int(d["stop_index"]),
        sensor=sensor,
        design_wavelength_nm=_num(path, "lens", d, "design_wavelength_nm", 587.5618, required=False),
        provenance=dict(d.get("provenance", {})),
    )
    validate(lens, path)
    return lens


def save_lens(lens: Lens, path, force: bool = False) -> None:
    """Write our JSON format atomically; refuses to overwrite unless force=True."""
    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path}: exists (use force=True / --force to overwrite)")
    write_text_atomic(path, json.dumps(lens.to_dict(), indent=2) + "\n")
