"""Zemax sequential .zmx files. The stop is sized paraxially from ENPD/FNUM, so this reader sits above `optics/`."""

from __future__ import annotations

import math
from pathlib import Path

from ...optics.paraxial import paraxial_data, stop_semi_diameter_for_epd
from ..check import lens_file_error as _err
from ..check import validate
from ..materials import UnknownMaterialError, parse_material
from ..schema import Lens, Sensor, Surface

# Working resolution for .zmx files, which give only the image-surface semi-diameter (3:2 like full frame).
DEFAULT_ZMX_RESOLUTION = (960, 640)
_ZMX_UNITS = {"MM": 1.0, "CM": 10.0, "METER": 1000.0, "M": 1000.0, "IN": 25.4, "INCH": 25.4}


def _read_zmx_text(path: Path) -> str:
    raw = path.read_bytes()
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return raw.decode("utf-16")
    if raw[:3] == b"\xef\xbb\xbf":
        return raw[3:].decode("utf-8")
    if len(raw) > 1 and raw[1:2] == b"\x00":  # UTF-16 LE without BOM
        return raw.decode("utf-16-le")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def load_zmx(path, resolution=DEFAULT_ZMX_RESOLUTION) -> Lens:
    """Zemax sequential .zmx (ASCII or UTF-16): STANDARD, EVENASPH and PARAXIAL surfaces;
    CURV, DISZ, DIAM (semi-diameter), CONI, PARM, GLAS (catalogue name, ___BLANK/MODEL nd vd), STOP,
    UNIT, ENPD/FNUM (stop semi-diameter is rescaled to honour them, as Zemax does).
    Surface 0 is the object, the last surface the image plane (the sensor).
    """
    path = Path(path)
    text = _read_zmx_text(path)
    scale = 1.0
    enpd = fnum = None
    blocks: list[dict] = []
    cur = None
    for lineno, line in enumerate(text.splitlines(), start=1):
        tok = line.split()
        if not tok:
            continue
        key = tok[0]
        if key == "UNIT":
            unit = tok[1].upper() if len(tok) > 1 else "MM"
            if unit not in _ZMX_UNITS:
                raise _err(path, f"line {lineno}: unsupported lens unit {unit!r}")
            scale = _ZMX_UNITS[unit]
        elif key == "ENPD" and len(tok) > 1:
            enpd = float(tok[1])
        elif key == "FNUM" and len(tok) > 1:
            fnum = float(tok[1])
        elif key == "SURF":
            cur = {"line": lineno, "type": "STANDARD", "curv": 0.0, "disz": 0.0, "diam": None,
                   "coni": 0.0, "parm": {}, "glas": None, "stop": False}
            blocks.append(cur)
        elif cur is None:
            continue
        elif key == "TYPE":
            cur["type"] = tok[1].upper()
            cur["type_line"] = lineno
        elif key == "CURV":
            cur["curv"] = float(tok[1])
        elif key == "DISZ":
            cur["disz"] = math.inf if tok[1].upper().startswith("INF") else float(tok[1])
        elif key == "DIAM":
            cur["diam"] = float(tok[1])
        elif key == "CONI":
            cur["coni"] = float(tok[1])
        elif key == "PARM":
            cur["parm"][int(tok[1])] = float(tok[2])
        elif key == "STOP":
            cur["stop"] = True
        elif key == "GLAS":
            cur["glas"] = (tok[1:], lineno)
    if len(blocks) < 3:
        raise _err(path, "fewer than 3 surfaces (object, a lens surface, image)")
    for b in blocks:
        if b["type"] not in ("STANDARD", "EVENASPH", "PARAXIAL"):
            raise _err(
                path,
                f"line {b.get('type_line', b['line'])}: surface type {b['type']} is not supported "
                "(STANDARD, EVENASPH, PARAXIAL)",
            )
    lens_blocks = blocks[1:-1]
    image = blocks[-1]
    surfaces, stop = [], None
    for i, b in enumerate(lens_blocks):
        mat = "air"
        if b["glas"] is not None:
            g, gl = b["glas"]
            name = g[0]
            if name.upper() in ("___BLANK", "MODEL"):
                try:
                    nd, vd = float(g[3]), float(g[4])
                except (IndexError, ValueError):
                    raise _err(path, f"line {gl}: model glass needs nd and vd") from None
                mat = f"{nd}/{vd}"
            elif name.upper() == "MIRROR":
                raise _err(path, f"line {gl}: mirrors are not supported")
            else:
                mat = name
            try:
                parse_material(mat)
            except UnknownMaterialError as e:
                raise _err(path, f"line {gl}: {e}") from None
        if b["stop"]:
            stop = i
        if b["diam"] is None or b["diam"] <= 0:
            raise _err(path, f"line {b['line']}: surface {i + 1} has no positive DIAM (semi-diameter)")
        kind, f = "standard", None
        asph: tuple[float, ...] = ()
        if b["type"] == "EVENASPH":
            n = max(b["parm"], default=0)
            asph = tuple(b["parm"].get(j, 0.0) / scale ** (2 * j - 1) for j in range(1, n + 1))
            while asph and asph[-1] == 0.0:
                asph = asph[:-1]
        elif b["type"] == "PARAXIAL":
            kind, f = "ideal", b["parm"].get(1, 0.0) * scale
        surfaces.append(
            Surface(
                curvature_per_mm=b["curv"] / scale if kind == "standard" else 0.0,
                thickness_mm=b["disz"] * scale,
                semi_diameter_mm=b["diam"] * scale,
                material=mat,
                conic=b["coni"] if kind == "standard" else 0.0,
                asphere_from_r2=asph,
                kind=kind,
                focal_length_mm=f,
            )
        )
    if stop is None:
        raise _err(path, "no STOP surface")
    if any(math.isinf(s.thickness_mm) for s in surfaces):
        raise _err(path, "infinite thickness inside the lens")
    half_diag = (image["diam"] or 0.0) * scale
    if half_diag <= 0:
        raise _err(path, f"line {image['line']}: image surface has no DIAM (sensor half-diagonal)")
    lens = Lens(
        name=path.stem,
        surfaces=tuple(surfaces),
        stop_index=stop,
        sensor=Sensor.from_half_diagonal(half_diag, *resolution),
        provenance={"source_file": path.name, "format": "Zemax .zmx"},
    )
    validate(lens, path)
    # Zemax sizes the stop from the system aperture; do the same so F-number matches the file.
    if enpd:
        lens = lens.with_stop_semi_diameter(stop_semi_diameter_for_epd(lens, enpd * scale))
        lens.provenance["aperture"] = f"stop sized for ENPD {enpd * scale} mm"
    elif fnum:
        efl = paraxial_data(lens).efl_mm
        lens = lens.with_stop_semi_diameter(stop_semi_diameter_for_epd(lens, efl / fnum))
        lens.provenance["aperture"] = f"stop sized for FNUM {fnum}"
    return lens
