"""Focus distance from camera maker notes (which exifread does not decode).

Every decoder returns {exiftool tag name: value} with values in exiftool's numeric (`-n`) convention,
metres for distances, so they can be compared one to one with `exiftool -j -n`. Layouts follow the public
ExifTool tag documentation (Canon, Nikon, Olympus, Minolta, Casio, FLIR tag tables):

| maker | where | value |
|---|---|---|
| Canon | ShotInfo (0x0004) [19] upper, [20] lower, int16u; FileInfo (0x0093) [20]/[21]; CameraInfo (0x000d) of the 1D Mk III / 40D at 0x43/0x45 (big-endian int16u) | /100 m; upper > 655.345 = infinity; used only when upper != 0; lower 0 = not recorded |
| Canon CRW | ShotInfo as CIFF record 0x102a | as above |
| Nikon | LensData (0x0098) version 0101 byte 0x09 (v0201-0204 are encrypted: not decoded) | 0.01·10^(raw/40) m |
| Olympus | FocusInfo (0x2050) tag 0x0305, rational | numerator/1000 m; numerator 0xffffffff = infinity |
| Minolta | CameraSettings (0x0001 / 0x0003, big-endian int32u) [19] | /1000 m; 0 = infinity |
| Casio | type 1 tag 0x0006, type 2 ("QVC") tag 0x2022 ObjectDistance | mm /1000 |
| FLIR | APP1 FFF CameraInfo record: float FocusDistance at 0x45c, ObjectDistance at 0x24 | m |

The EXIF maker note (tag 0x927C) is decoded by the entry of `DECODERS` whose make matches the file's EXIF Make:
a new maker's decoder is one function and one entry there (`decoder_for` picks it).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

from .tiff import Entry, TiffBuffer

INF = math.inf


CANON_INFINITY_M = 655.345  # an upper bound above this (655.35 = 0xffff / 100) means infinity


def canon_focus_m(upper: float, lower: float) -> tuple[float, str]:
    """The focus distance (metres) from Canon's FocusDistanceUpper/Lower and how it was made.

    Lower = 0 means "not recorded" (PowerShot compacts write only Upper; ExifTool shows it as 0 m): Upper alone.
    Otherwise the bracket's midpoint in diopters, an upper bound at infinity counting as 0 D."""
    inv_up = 0.0 if upper > CANON_INFINITY_M else 1.0 / upper
    if lower <= 0:
        return (math.inf if inv_up == 0 else 1.0 / inv_up), "Upper alone, Lower not recorded"
    inv_lo = 0.0 if lower > CANON_INFINITY_M else 1.0 / lower
    mid = 0.5 * (inv_up + inv_lo)
    return (math.inf if mid == 0 else 1.0 / mid), "diopter midpoint"


def _canon_pair(upper_raw: int, lower_raw: int) -> dict[str, float]:
    if not upper_raw:
        return {}
    return {"FocusDistanceUpper": upper_raw / 100.0, "FocusDistanceLower": lower_raw / 100.0}


def canon(tb: TiffBuffer, ifd: dict[int, Entry], model: str) -> dict[str, float]:
    """Canon maker-note IFD → FocusDistanceUpper/Lower in metres (first source that has them)."""
    e = ifd.get(0x0004)  # ShotInfo: int16 array, element 0 is its byte size
    if e is not None:
        a = tb.array(e, "H")
        if len(a) > 20 and (tags := _canon_pair(a[19], a[20])):
            return tags
    e = ifd.get(0x0093)  # FileInfo
    if e is not None:
        a = tb.array(e, "H")
        if len(a) > 21 and (tags := _canon_pair(a[20], a[21])):
            return tags
    e = ifd.get(0x000D)  # CameraInfo: model-specific binary block
    if e is not None and any(m in model for m in ("1D Mark III", "1Ds Mark III", "40D")):
        d = e.data
        if len(d) >= 0x47:
            up, lo = struct.unpack(">HH", d[0x43:0x45] + d[0x45:0x47])
            return _canon_pair(up, lo)
    return {}


def canon_lens(tb: TiffBuffer, ifd: dict[int, Entry]) -> str | None:
    """Canon maker-note LensModel (0x0095), or None."""
    return tb.text(ifd, 0x0095)


def ciff(buf: bytes, start: int, length: int, depth: int = 0) -> dict[str, object]:
    """Walk a Canon CIFF heap (CRW): returns {"FocusDistanceUpper", "FocusDistanceLower", "Make", "Model",
    "FocalLength", "FNumber"?} for what is present."""
    out: dict[str, object] = {}
    if depth > 8 or length < 4 or start + length > len(buf):
        return out
    (table,) = struct.unpack_from("<I", buf, start + length - 4)
    t = start + table
    if t + 2 > len(buf):
        return out
    (n,) = struct.unpack_from("<H", buf, t)
    for i in range(min(n, 1000)):
        p = t + 2 + 10 * i
        if p + 10 > len(buf):
            break
        tag, size, off = struct.unpack_from("<HII", buf, p)
        kind = tag & 0x3800
        if tag & 0xC000 == 0x4000:  # data stored in the directory entry itself
            data_at, size = p + 2, 8
        else:
            data_at = start + off
        data = buf[data_at:data_at + size]
        if kind in (0x2800, 0x3000):  # sub-heap
            for k, v in ciff(buf, data_at, size, depth + 1).items():
                out.setdefault(k, v)
            continue
        tid = tag & 0x3FFF
        if tid == 0x102A and len(data) >= 42:  # CanonShotInfo
            a = struct.unpack_from("<21H", data)
            for k, v in _canon_pair(a[19], a[20]).items():
                out.setdefault(k, v)
        elif tid == 0x080A:  # "Make\0Model\0"
            parts = data.split(b"\0")
            if len(parts) >= 2:
                out.setdefault("Make", parts[0].decode("latin-1").strip())
                out.setdefault("Model", parts[1].decode("latin-1").strip())
    return out


def nikon(buf: bytes, exif_tb: TiffBuffer, mn: Entry) -> tuple[dict[str, float], str | None]:
    """Nikon maker note → ({"FocusDistance": m}, note); note explains why nothing was decoded."""
    d = mn.data
    if d.startswith((b"Nikon\0\x02", b"Nikon\0\x03")):
        hdr = TiffBuffer.from_header(buf, mn.data_offset + 10)
        if not hdr:
            return {}, None
        tb, first = hdr
        ifd = tb.ifd(first)
    elif d.startswith(b"Nikon\0\x01"):
        tb, ifd = exif_tb, exif_tb.ifd(mn.data_offset + 8, absolute=True)
    else:
        tb, ifd = exif_tb, exif_tb.ifd(mn.data_offset, absolute=True)
    e = ifd.get(0x0098)
    if e is None or len(e.data) < 4:
        return {}, None
    version = e.data[:4].decode("latin-1")
    if version == "0101" and len(e.data) > 0x09:
        raw = e.data[0x09]
        return ({"FocusDistance": 0.01 * 10 ** (raw / 40.0)} if raw else {}), None
    if version.startswith(("02", "04", "08")):
        return {}, f"Nikon LensData version {version} is encrypted (not decoded; exiftool can)"
    return {}, None


def olympus(buf: bytes, exif_tb: TiffBuffer, mn: Entry) -> dict[str, float]:
    """Olympus maker note FocusInfo → {"FocusDistance": m} (inf for 0xffffffff)."""
    d = mn.data
    if d.startswith((b"OLYMPUS\0", b"OM SYSTEM\0")):
        head = 8 if d.startswith(b"OLYMPUS\0") else 12
        endian = "<" if d[head:head + 2] == b"II" else ">"
        tb = TiffBuffer(buf, mn.data_offset, endian)
        ifd = tb.ifd(head + 4)
    elif d.startswith((b"OLYMP\0", b"EPSON\0")):
        tb, ifd = exif_tb, exif_tb.ifd(mn.data_offset + 8, absolute=True)
    else:
        return {}
    e = ifd.get(0x2050)
    if e is None:
        return {}
    if e.type in (4, 13):  # sub-IFD offset
        sub = tb.ifd(tb.values(e)[0])
    else:  # sub-IFD stored inline as undefined bytes
        sub = tb.ifd(e.data_offset, absolute=True)
    fd = sub.get(0x0305)
    if fd is None or fd.type != 5 or len(fd.data) < 8:
        return {}
    num = struct.unpack(tb.endian + "I", fd.data[:4])[0]
    if num == 0:
        return {}
    return {"FocusDistance": INF if num == 0xFFFFFFFF else num / 1000.0}


def minolta(tb: TiffBuffer, mn: Entry) -> dict[str, float]:
    """Minolta CameraSettings[19] → {"FocusDistance": m} (value 0 means infinity; exiftool -n reports 0)."""
    ifd = tb.ifd(mn.data_offset, absolute=True)
    for tag in (0x0003, 0x0001):
        e = ifd.get(tag)
        if e is not None and len(e.data) >= 80:
            (raw,) = struct.unpack(">I", e.data[76:80])
            return {"FocusDistance": raw / 1000.0}
    return {}


def casio(buf: bytes, tb: TiffBuffer, mn: Entry) -> dict[str, float]:
    """Casio ObjectDistance (mm) → {"ObjectDistance": m}."""
    if mn.data.startswith(b"QVC\0"):
        ifd, tag = tb.ifd(mn.data_offset + 6, absolute=True), 0x2022
    else:
        ifd, tag = tb.ifd(mn.data_offset, absolute=True), 0x0006
    v = tb.number(ifd, tag)
    return {"ObjectDistance": v / 1000.0} if v else {}


def flir(fff: bytes) -> dict[str, float]:
    """FLIR FFF record directory → CameraInfo FocusDistance and ObjectDistance (metres, float32)."""
    if not fff.startswith(b"FFF\0") or len(fff) < 40:
        return {}
    _, index, n = struct.unpack_from(">III", fff, 20)
    for i in range(min(n, 256)):
        p = index + 32 * i
        if p + 20 > len(fff):
            break
        typ, _, _, _, off, length = struct.unpack_from(">HHIIII", fff, p)
        if typ != 0x20 or off + length > len(fff):
            continue
        rec = fff[off:off + length]
        if len(rec) < 0x460:
            return {}
        endian = "<" if rec[:2] == b"\x02\x00" else ">"
        (obj,) = struct.unpack_from(endian + "f", rec, 0x24)
        (focus,) = struct.unpack_from(endian + "f", rec, 0x45C)
        out = {}
        if math.isfinite(focus) and focus > 0:
            out["FocusDistance"] = float(focus)
        if math.isfinite(obj) and obj > 0:
            out["ObjectDistance"] = float(obj)
        return out
    return {}


# ------------------------------------------------------------------------------------------------
# The EXIF maker note by camera make
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MakerNoteDecoder:
    """`decode(buf, tb, mn, meta)` -> {exiftool tag: value} for an EXIF maker note (entry `mn` of the Exif IFD
    read through `tb`) of a camera whose upper-cased EXIF Make starts with one of `makes` (or, with `anywhere`,
    contains one). `meta` is the frame's `exif.FrameMeta`: a decoder may fill `meta.lens` where it is empty and
    append to `meta.notes` (why nothing was decoded). `name` is the maker note's name in `focus_source`."""

    makes: tuple[str, ...]
    name: str
    decode: Callable[..., dict[str, float]]
    anywhere: bool = False

    def matches(self, make: str) -> bool:
        make = make.upper()
        return any(m in make for m in self.makes) if self.anywhere else make.startswith(self.makes)


def _canon_note(buf: bytes, tb: TiffBuffer, mn: Entry, meta) -> dict[str, float]:
    ifd = tb.ifd(mn.data_offset, absolute=True)
    meta.lens = meta.lens or canon_lens(tb, ifd)
    return canon(tb, ifd, meta.model or "")


def _nikon_note(buf: bytes, tb: TiffBuffer, mn: Entry, meta) -> dict[str, float]:
    tags, note = nikon(buf, tb, mn)
    if note:
        meta.notes.append(note)
    return tags


DECODERS: tuple[MakerNoteDecoder, ...] = (  # the first that matches decodes
    MakerNoteDecoder(("CANON",), "Canon", _canon_note),
    MakerNoteDecoder(("NIKON",), "Nikon LensData", _nikon_note),
    MakerNoteDecoder(("OLYMPUS", "OM DIGITAL"), "Olympus FocusInfo", lambda buf, tb, mn, meta: olympus(buf, tb, mn)),
    MakerNoteDecoder(("MINOLTA",), "Minolta CameraSettings", lambda buf, tb, mn, meta: minolta(tb, mn),
                     anywhere=True),  # "Minolta Co., Ltd.", "KONICA MINOLTA"
    MakerNoteDecoder(("CASIO",), "Casio", lambda buf, tb, mn, meta: casio(buf, tb, mn)),
)


def decoder_for(make: str | None) -> MakerNoteDecoder | None:
    """The maker-note decoder for an EXIF Make (None: no decoder for this maker)."""
    return next((d for d in DECODERS if d.matches(make or "")), None)
