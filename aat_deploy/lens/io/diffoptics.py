"""DiffOptics .txt lens files (rows `type distance roc diameter material [k a4 a6 ...]`)."""

from __future__ import annotations

from pathlib import Path

from ..check import lens_file_error as _err
from ..check import validate
from ..materials import UnknownMaterialError, parse_material
from ..schema import Lens, Sensor, Surface
from .zemax import DEFAULT_ZMX_RESOLUTION


def load_diffoptics_txt(path, resolution=DEFAULT_ZMX_RESOLUTION) -> Lens:
    """DiffOptics text format: rows `O|S|A|I distance roc diameter material [k a4 a6 ...]`, where
    `distance` is the gap from the previous row, `diameter` the full clear diameter. After the conic k the
    coefficients start at r^4 (DiffOptics' Aspheric sag adds sum_i ai[i] r^(2i+4); an r^2 term would compete with
    the radius), so they are stored behind a zero r^2 term."""
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
                asphere_from_r2=(0.0, *extra[1:]) if len(extra) > 1 else (),
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
