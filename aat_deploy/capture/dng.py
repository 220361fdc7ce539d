"""Write a Bayer-mosaic DNG that real RAW readers (LibRaw/rawpy, exifread, exiftool) accept.

The virtual camera saves simulated frames exactly like a real camera's RAW captures, so the runtime
reads them through the same path (rawpy for pixels, exifread for EXIF). We write the TIFF ourselves
because tifffile's DNG writer has no EXIF sub-IFD, and DNG has no focus-distance tag of its own: the
distance lives in EXIF SubjectDistance (0x9206), plus XMP aux:ApproximateFocusDistance as Adobe's
converter writes it.
"""

from __future__ import annotations

import math
import os
import re
import struct
from fractions import Fraction
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_bytes_atomic

BYTE, ASCII, SHORT, LONG, RATIONAL, UNDEFINED, SRATIONAL = 1, 2, 3, 4, 5, 7, 10
_FMT = {BYTE: "B", SHORT: "H", LONG: "I", UNDEFINED: "B"}
_BAYER = {"RGGB", "BGGR", "GRBG", "GBRG"}
_MIN_SIDE = 22  # LibRaw refuses images smaller than this on either side ("unsupported file format")


def _rational(x: float, what: str, signed: bool = False) -> tuple[int, int]:
    """x as (num, den) fitting 32-bit TIFF (S)RATIONAL; exact for decimal-ish values like 0.35 or 1/250."""
    top = 2**31 - 1 if signed else 2**32 - 1
    if not math.isfinite(x) or abs(x) > top:
        raise ValueError(f"{what}={x!r} cannot be stored as a TIFF rational")
    f = Fraction(x).limit_denominator(max(1, min(1_000_000, int(top // max(abs(x), 1.0)))))
    return f.numerator, f.denominator


def _ifd(entries: list[tuple[int, int, object]], offset: int) -> bytes:
    """One IFD at file `offset`: entries (tag, type, values) sorted by tag, out-of-line values after it."""
    entries = sorted(entries, key=lambda e: e[0])
    data_at = offset + 2 + 12 * len(entries) + 4
    head, tail = [struct.pack("<H", len(entries))], b""
    for tag, typ, vals in entries:
        if typ == ASCII:
            raw, count = vals.encode("ascii") + b"\0", len(vals) + 1
        elif typ in (RATIONAL, SRATIONAL):
            flat = [v for pair in vals for v in pair]
            raw, count = struct.pack(f"<{len(flat)}{'i' if typ == SRATIONAL else 'I'}", *flat), len(vals)
        elif isinstance(vals, bytes):
            raw, count = vals, len(vals)
        else:
            raw, count = struct.pack(f"<{len(vals)}{_FMT[typ]}", *vals), len(vals)
        if len(raw) <= 4:  # fits in the entry itself, left-justified
            head.append(struct.pack("<HHI", tag, typ, count) + raw.ljust(4, b"\0"))
        else:
            head.append(struct.pack("<HHII", tag, typ, count, data_at + len(tail)))
            tail += raw + b"\0" * (len(raw) % 2)  # TIFF wants values on word boundaries
    return b"".join(head) + struct.pack("<I", 0) + tail  # next-IFD offset 0: a single image


def _xmp(distance: tuple[int, int]) -> bytes:
    return ('<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n'
            '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
            '<rdf:Description rdf:about="" xmlns:aux="http://ns.adobe.com/exif/1.0/aux/" '
            f'aux:ApproximateFocusDistance="{distance[0]}/{distance[1]}"/></rdf:RDF></x:xmpmeta>\n'
            '<?xpacket end="w"?>').encode()


def _positive(name: str, x: float) -> float:
    if not (isinstance(x, (int, float, np.floating, np.integer)) and math.isfinite(x) and x > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {x!r}")
    return float(x)


def _text(name: str, s: str) -> str:
    if not isinstance(s, str) or not s or not s.isascii() or "\0" in s:
        raise ValueError(f"{name} must be a non-empty ASCII string without NUL, got {s!r}")
    return s


def write_dng(path: str | os.PathLike, cfa: np.ndarray, *, cfa_pattern: str = "RGGB", black_level: int,
              white_level: int, color_matrix: np.ndarray, as_shot_neutral: tuple[float, float, float] = (1, 1, 1),
              subject_distance_m: float, focal_length_mm: float, f_number: float, make: str, model: str,
              lens_model: str, exposure_time_s: float | None = None, iso: int | None = None,
              datetime: str | None = None, force: bool = False) -> None:
    """Write one uncompressed Bayer-mosaic DNG (1.4) with an EXIF sub-IFD, atomically.

    cfa: (H, W) uint16 linear raw values in DN, H and W even and >= 22 (LibRaw's minimum), row 0 = top.
    cfa_pattern: colours of the top-left 2x2 cell read row by row (RGGB, BGGR, GRBG or GBRG).
    black_level, white_level: DN; every cfa value must be <= white_level (values below black are allowed: noise).
    color_matrix: (3, 3) DNG ColorMatrix1, XYZ (D65, calibration illuminant 21) -> camera RGB.
    as_shot_neutral: camera-RGB response to the scene white (> 0, typically max 1).
    subject_distance_m: focus distance in metres (EXIF SubjectDistance + XMP aux:ApproximateFocusDistance).
    focal_length_mm: mm; f_number: dimensionless; exposure_time_s: seconds; iso: ISO speed (1..65535).
    datetime: EXIF "YYYY:MM:DD HH:MM:SS" for DateTimeOriginal. Optional fields left None are omitted.
    Raises FileExistsError if path exists and not force; ValueError (one line) for invalid inputs.
    """
    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists (pass force=True to overwrite)")
    cfa = np.asarray(cfa)
    if cfa.ndim != 2 or cfa.dtype != np.uint16:
        raise ValueError(f"cfa must be a 2-D uint16 array, got shape {cfa.shape} dtype {cfa.dtype}")
    h, w = cfa.shape
    if h % 2 or w % 2 or h < _MIN_SIDE or w < _MIN_SIDE:
        raise ValueError(f"cfa is {h}x{w}; both sides must be even and >= {_MIN_SIDE}")
    if cfa_pattern not in _BAYER:
        raise ValueError(f"cfa_pattern must be one of {sorted(_BAYER)}, got {cfa_pattern!r}")
    if not (0 <= int(black_level) < int(white_level) <= 65535):
        raise ValueError(f"need 0 <= black_level < white_level <= 65535, got {black_level}, {white_level}")
    if int(cfa.max()) > white_level:
        raise ValueError(f"cfa max {int(cfa.max())} exceeds white_level {white_level}")
    cm = np.asarray(color_matrix, dtype=float)
    if cm.shape != (3, 3) or not np.all(np.isfinite(cm)) or abs(np.linalg.det(cm)) < 1e-12:
        raise ValueError(f"color_matrix must be a finite, invertible 3x3 matrix, got shape {cm.shape}")
    neutral = [_positive("as_shot_neutral", v) for v in as_shot_neutral]
    if len(neutral) != 3:
        raise ValueError(f"as_shot_neutral must have 3 values, got {len(neutral)}")
    if iso is not None and not (isinstance(iso, (int, np.integer)) and 1 <= iso <= 65535):
        raise ValueError(f"iso must be an integer in 1..65535, got {iso!r}")
    if datetime is not None and not re.fullmatch(r"\d{4}:\d\d:\d\d \d\d:\d\d:\d\d", str(datetime)):
        raise ValueError(f"datetime must look like 'YYYY:MM:DD HH:MM:SS', got {datetime!r}")
    dist = _rational(_positive("subject_distance_m", subject_distance_m), "subject_distance_m")
    make, model, lens_model = _text("make", make), _text("model", model), _text("lens_model", lens_model)

    exif = [(33437, RATIONAL, [_rational(_positive("f_number", f_number), "f_number")]),
            (36864, UNDEFINED, b"0231"),  # ExifVersion
            (37382, RATIONAL, [dist]),  # SubjectDistance, metres
            (37386, RATIONAL, [_rational(_positive("focal_length_mm", focal_length_mm), "focal_length_mm")]),
            (42036, ASCII, lens_model)]
    if exposure_time_s is not None:
        exif.append((33434, RATIONAL, [_rational(_positive("exposure_time_s", exposure_time_s), "exposure_time_s")]))
    if iso is not None:
        exif.append((34855, SHORT, [int(iso)]))
    if datetime is not None:
        exif.append((36867, ASCII, str(datetime)))

    pixels = cfa.astype("<u2", copy=False).tobytes()

    def ifd0(exif_at: int, pixels_at: int) -> list[tuple[int, int, object]]:
        return [(254, LONG, [0]), (256, LONG, [w]), (257, LONG, [h]), (258, SHORT, [16]),
                (259, SHORT, [1]),  # uncompressed
                (262, SHORT, [32803]),  # PhotometricInterpretation = CFA
                (271, ASCII, make), (272, ASCII, model), (273, LONG, [pixels_at]), (274, SHORT, [1]),
                (277, SHORT, [1]), (278, LONG, [h]), (279, LONG, [len(pixels)]), (284, SHORT, [1]),
                (305, ASCII, "aat virtual camera"), (700, BYTE, _xmp(dist)),
                (33421, SHORT, [2, 2]), (33422, BYTE, bytes("RGB".index(c) for c in cfa_pattern)),
                (34665, LONG, [exif_at]),
                (50706, BYTE, [1, 4, 0, 0]), (50707, BYTE, [1, 1, 0, 0]),  # nothing newer than DNG 1.1 is used
                (50708, ASCII, f"{make} {model}"), (50710, BYTE, [0, 1, 2]), (50711, SHORT, [1]),
                (50714, LONG, [int(black_level)]), (50717, LONG, [int(white_level)]),
                (50721, SRATIONAL, [_rational(v, "color_matrix", signed=True) for v in cm.ravel()]),
                (50728, RATIONAL, [_rational(v, "as_shot_neutral") for v in neutral]),
                (50778, SHORT, [21])]  # CalibrationIlluminant1 = D65

    # Sizes do not depend on offsets (pointers are inline LONGs), so lay out with dummies, then for real.
    exif_at = 8 + len(_ifd(ifd0(0, 0), 8))
    pixels_at = exif_at + len(_ifd(exif, exif_at))
    blob = (b"II*\0" + struct.pack("<I", 8) + _ifd(ifd0(exif_at, pixels_at), 8) + _ifd(exif, exif_at) + pixels)
    assert len(blob) == pixels_at + len(pixels)

    write_bytes_atomic(path, blob, fsync=True)
