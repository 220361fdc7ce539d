"""The paper's legacy lens JSON (AAT / DeepLens style), read from a parsed dict."""

from __future__ import annotations

from pathlib import Path

from ..check import lens_file_error as _err
from ..check import validate
from ..materials import UnknownMaterialError, parse_material
from ..schema import Lens, Sensor, Surface

# Working resolution used when a file gives only a sensor half-diagonal (the paper's simulation: 480x640).
DEFAULT_LEGACY_RESOLUTION = (640, 480)


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
