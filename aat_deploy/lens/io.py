"""Load and save lenses: our JSON ("aat-lens-v1"), the paper's legacy JSON, Zemax .zmx, DiffOptics .txt.

`load_lens(path)` picks the reader from the file's suffix and content. Every reader raises `LensFileError`
with the file name (and line or surface) and the problem in one line.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from ..io.atomic import write_text_atomic
from ..optics.paraxial import paraxial_data, stop_semi_diameter_for_epd
from .materials import UnknownMaterialError, parse_material
from .schema import SURFACE_KINDS, Lens, Sensor, Surface

# Working resolution used when a file gives only a sensor half-diagonal (the paper's simulation: 480x640).
DEFAULT_LEGACY_RESOLUTION = (640, 480)
# Working resolution for .zmx files, which give only the image-surface semi-diameter (3:2 like full frame).
DEFAULT_ZMX_RESOLUTION = (960, 640)


class LensFileError(ValueError):
    """A lens file that cannot be read; the message names the file and the problem."""


def _err(path, msg: str) -> LensFileError:
    return LensFileError(f"{path}: {msg}")


# ------------------------------------------------------------------------------------------------
# Our format
# ------------------------------------------------------------------------------------------------
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


def validate(lens: Lens, path="<lens>") -> None:
    """Check a lens for problems that would make tracing meaningless; raise LensFileError naming them."""
    n = len(lens.surfaces)
    if not 0 <= lens.stop_index < n:
        raise _err(path, f"stop_index {lens.stop_index} outside 0..{n - 1}")
    for i, s in enumerate(lens.surfaces):
        if not (s.semi_diameter_mm > 0 and math.isfinite(s.semi_diameter_mm)):
            raise _err(path, f"surface {i}: semi-diameter must be positive, got {s.semi_diameter_mm}")
        if not math.isfinite(s.thickness_mm):
            raise _err(path, f"surface {i}: thickness must be finite, got {s.thickness_mm}")
        if s.kind == "ideal" and not (s.focal_length_mm and math.isfinite(s.focal_length_mm)):
            raise _err(path, f"surface {i}: ideal surface needs a finite non-zero focal_length_mm")
        try:
            parse_material(s.material)
        except UnknownMaterialError as e:
            raise _err(path, f"surface {i}: {e}") from None
    sen = lens.sensor
    if min(sen.width_mm, sen.height_mm) <= 0 or min(sen.width_px, sen.height_px) <= 0:
        raise _err(path, "sensor size and resolution must be positive")
    px_w, px_h = sen.width_mm / sen.width_px, sen.height_mm / sen.height_px
    if abs(px_w - px_h) > 0.005 * px_w:
        raise _err(path, f"sensor pixels are not square ({px_w * 1e3:.2f} x {px_h * 1e3:.2f} um)")


def save_lens(lens: Lens, path, force: bool = False) -> None:
    """Write our JSON format atomically; refuses to overwrite unless force=True."""
    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path}: exists (use force=True / --force to overwrite)")
    write_text_atomic(path, json.dumps(lens.to_dict(), indent=2) + "\n")


# ------------------------------------------------------------------------------------------------
# The paper's legacy JSON (AAT / DeepLens style)
# ------------------------------------------------------------------------------------------------
def _get(s: dict, key: str):
    """Legacy files mark optimisable values as "(key)"; accept both spellings."""
    if key in s:
        return s[key]
    return s.get(f"({key})")


def _legacy_asphere(s: dict) -> tuple[float, ...]:
    named = [_get(s, f"ai{2 * i}") for i in range(1, 9)]
    if any(v is not None for v in named):  # explicit ai2, ai4, ... keys are unambiguous
        coeffs = [float(v or 0.0) for v in named]
    else:
        # The paper's `ai` list starts at r^2 (DeepLens files of that vintage keep that layout too).
        coeffs = [float(v) for v in (s.get("ai") or [])]
    while coeffs and coeffs[-1] == 0.0:
        coeffs.pop()
    return tuple(coeffs)


def load_legacy_json(d: dict, path="<legacy>", resolution=DEFAULT_LEGACY_RESOLUTION) -> Lens:
    """The paper's lens JSON: absolute vertex `d` (used when every surface has it, else `d_next`),
    `c` curvature, `r` semi-diameter, `mat2` medium after the surface, `ai` from r^2, sensor from the
    half-diagonal `r_last`/`r_sensor` at `resolution` (W, H), sensor z `d_sensor`.
    """
    raw = d.get("surfaces")
    if not isinstance(raw, list) or not raw:
        raise _err(path, "no 'surfaces' list")
    zs = [_get(s, "d") for s in raw]
    if all(z is not None for z in zs):
        zs = [float(z) for z in zs]
    else:
        if any(_get(s, "d_next") is None for s in raw):
            raise _err(path, "surfaces need either absolute 'd' or 'd_next' everywhere")
        zs, z = [], 0.0
        for s in raw:
            zs.append(z)
            z += float(_get(s, "d_next"))
    d_sensor = _get(d, "d_sensor")
    if d_sensor is None:
        if _get(raw[-1], "d_next") is None:
            raise _err(path, "no 'd_sensor' and no 'd_next' on the last surface: sensor position unknown")
        d_sensor = zs[-1] + float(_get(raw[-1], "d_next"))
    zs.append(float(d_sensor))

    surfaces, stop = [], None
    for i, s in enumerate(raw):
        typ = str(s.get("type", "Spheric"))
        mat = str(s.get("mat2", "air"))
        if mat.lower() == "occluder":
            mat = "air"
        if typ in ("Stop", "Aperture"):
            stop = i if stop is None else stop
            c = 0.0
        elif typ in ("Spheric", "Aspheric", "Plane"):
            c = float(_get(s, "c") or 0.0)
            if c == 0.0 and _get(s, "roc") not in (None, 0):
                c = 1.0 / float(_get(s, "roc"))
        else:
            raise _err(path, f"surface {i}: unsupported surface type {typ!r} (Spheric, Aspheric, Stop, Aperture)")
        if _get(s, "r") is None:
            raise _err(path, f"surface {i}: missing semi-diameter 'r'")
        try:
            parse_material(mat)
        except UnknownMaterialError as e:
            raise _err(path, f"surface {i}: {e}") from None
        surfaces.append(
            Surface(
                curvature_per_mm=c,
                thickness_mm=zs[i + 1] - zs[i],
                semi_diameter_mm=float(_get(s, "r")),
                material=mat,
                conic=float(_get(s, "k") or 0.0),
                asphere_from_r2=_legacy_asphere(s) if typ == "Aspheric" else (),
            )
        )
    if stop is None:
        # The paper's rule: the stop is the first surface with air on both sides.
        media = ["air"] + [s.material for s in surfaces]
        for i in range(len(surfaces)):
            if parse_material(media[i]).is_air and parse_material(media[i + 1]).is_air:
                stop = i
                break
    if stop is None:
        raise _err(path, "no stop: no surface of type Stop/Aperture and none with air on both sides")
    half_diag = _get(d, "r_last") or _get(d, "r_sensor")
    if half_diag is None:
        raise _err(path, "no sensor half-diagonal ('r_last' or 'r_sensor')")
    sensor = Sensor.from_half_diagonal(float(half_diag), *resolution)
    size = d.get("sensor_size")
    if isinstance(size, list) and len(size) == 2 and size[0] != size[1]:
        # An explicit rectangular size (H, W) wins over the half-diagonal; keep square pixels.
        h, w = sorted(float(v) for v in size)
        wpx = resolution[0]
        sensor = Sensor(w, h, wpx, int(round(wpx * h / w)))
    name = str(d.get("info") or Path(str(path)).stem)
    lens = Lens(
        name=name,
        surfaces=tuple(surfaces),
        stop_index=stop,
        sensor=sensor,
        provenance={"source_file": Path(str(path)).name, "format": "legacy paper JSON"},
    )
    validate(lens, path)
    return lens


# ------------------------------------------------------------------------------------------------
# Zemax .zmx
# ------------------------------------------------------------------------------------------------
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


# ------------------------------------------------------------------------------------------------
# DiffOptics .txt (type distance roc diameter material [asphere...])
# ------------------------------------------------------------------------------------------------
def load_diffoptics_txt(path, resolution=DEFAULT_ZMX_RESOLUTION) -> Lens:
    """DiffOptics text format: rows `O|S|A|I distance roc diameter material [k a2 a4 ...]`, where
    `distance` is the gap from the previous row, `diameter` the full clear diameter."""
    path = Path(path)
    rows = []
    for lineno, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
        tok = line.split()
        if tok and tok[0] in ("O", "S", "A", "I"):
            try:
                rows.append((lineno, tok[0], [float(t) for t in tok[1:4]], tok[4], [float(t) for t in tok[5:]]))
            except (ValueError, IndexError):
                raise _err(path, f"line {lineno}: expected 'type distance roc diameter material'") from None
    if not rows or rows[-1][1] != "I" or not any(r[1] in "SA" for r in rows):
        raise _err(path, "not a DiffOptics lens: needs S/A rows and a final I (image) row")
    lens_rows = [r for r in rows if r[1] in ("S", "A")]
    surfaces, stop = [], None
    for i, (lineno, typ, (_gap, roc, diam), mat, extra) in enumerate(lens_rows):
        nxt = rows[rows.index(lens_rows[i]) + 1]
        mat = "air" if mat.upper() in ("AIR", "VACUUM", "OCCLUDER") else mat
        try:
            parse_material(mat)
        except UnknownMaterialError as e:
            raise _err(path, f"line {lineno}: {e}") from None
        if typ == "A":
            stop = i
        k = extra[0] if extra else 0.0
        surfaces.append(
            Surface(
                curvature_per_mm=0.0 if roc == 0 else 1.0 / roc,
                thickness_mm=nxt[2][0],
                semi_diameter_mm=diam / 2.0,
                material=mat,
                conic=k,
                asphere_from_r2=tuple(extra[1:]),
            )
        )
    if stop is None:
        raise _err(path, "no aperture row 'A'")
    lens = Lens(
        name=path.stem,
        surfaces=tuple(surfaces),
        stop_index=stop,
        sensor=Sensor.from_half_diagonal(rows[-1][2][2] / 2.0, *resolution),
        provenance={"source_file": path.name, "format": "DiffOptics .txt"},
    )
    validate(lens, path)
    return lens


# ------------------------------------------------------------------------------------------------
def load_lens(path) -> Lens:
    """Read any supported lens file; errors name the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise _err(path, "no such file")
    suffix = path.suffix.lower()
    if suffix == ".zmx":
        return load_zmx(path)
    if suffix == ".json":
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise _err(path, f"invalid JSON ({e})") from None
        if not isinstance(d, dict):
            raise _err(path, "top level must be a JSON object")
        if d.get("format") == "aat-lens-v1":
            return lens_from_dict(d, path)
        if "surfaces" in d:
            return load_legacy_json(d, path)
        raise _err(path, "JSON is neither aat-lens-v1 nor a legacy lens file (no 'surfaces')")
    if suffix == ".txt":
        return load_diffoptics_txt(path)
    raise _err(path, f"unsupported lens file type {suffix!r} (.json, .zmx, .txt)")
