"""One frame's metadata: camera, lens, exposure geometry and the focus distance with where it came from.

Focus distance precedence inside a file (the capture folder's `capture.json` sidecar overrides all of
this, see `folder.py`):

1. maker notes (the lens's distance encoder): Canon FocusDistanceUpper/Lower (combined as the midpoint in
   diopters, an infinite upper bound counting as 0 D; Upper alone when Lower is 0, "not recorded"), Nikon LensData FocusDistance, Olympus FocusInfo,
   Minolta CameraSettings, FLIR CameraInfo FocusDistance, Casio ObjectDistance;
2. EXIF SubjectDistance (0x9206, in the EXIF IFD or IFD0);
3. XMP aux:ApproximateFocusDistance (written by DNG converters and by our virtual camera);
4. ExifTool (`exiftool -j -n`) when it is installed and nothing above was found.

All distances are metres (from the sensor plane, as cameras report them).
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..io.files import read_input_bytes
from . import exiftool, makernotes
from .containers import Blocks, find_blocks
from .imagefile import claimed_size
from .tiff import TiffBuffer

EXIF_POINTER, MAKER_NOTE, SUBJECT_DISTANCE = 0x8769, 0x927C, 0x9206
MAKE, MODEL, FOCAL_LENGTH, F_NUMBER, LENS_MODEL = 0x010F, 0x0110, 0x920A, 0x829D, 0xA434
DNG_LENS_MODEL = 0xC62A  # LensInfo is 0xC630; DNG writers put LensModel in EXIF 0xA434 too
FOCAL_LENGTH_35MM, FOCAL_PLANE_X_RES, FOCAL_PLANE_UNIT = 0xA405, 0xA20E, 0xA210
FOCAL_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # ResolutionUnit: inch, cm, mm, um -> mm per unit


@dataclass
class FrameMeta:
    """Metadata of one frame file. focus_tags maps exiftool-style tag names to metres (exiftool -n values)."""

    file: str
    focus_m: float | None = None
    focus_source: str | None = None
    make: str | None = None
    model: str | None = None
    lens: str | None = None
    focal_length_mm: float | None = None
    f_number: float | None = None
    width: int | None = None
    height: int | None = None
    focal_length_35mm: float | None = None  # EXIF FocalLengthIn35mmFilm: the focal length times the crop factor
    focal_plane_px_per_mm: float | None = None  # EXIF FocalPlaneXResolution in pixels per mm of the sensor
    container: str | None = None
    focus_tags: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def as_json(self) -> dict:
        """JSON-safe dict: infinite distances become the string "inf"."""
        d = asdict(self)
        fix = lambda v: "inf" if isinstance(v, float) and math.isinf(v) else v
        d["focus_m"] = fix(d["focus_m"])
        d["focus_tags"] = {k: fix(v) for k, v in d["focus_tags"].items()}
        return d


def _xmp_focus(xmp: bytes) -> float | None:
    m = re.search(rb"ApproximateFocusDistance(?:=\"|>)\s*([0-9.]+)(?:/([0-9.]+))?", xmp)
    if not m:
        return None
    try:
        num = float(m.group(1))
        den = float(m.group(2)) if m.group(2) else 1.0
    except ValueError:  # e.g. "1.2.3"
        return None
    if num == 4294967295:
        return math.inf
    return num / den if den and num > 0 else None


def read_metadata(path: str | Path, use_exiftool: bool = True, buf: bytes | None = None) -> FrameMeta:
    """Read one file's metadata (raises CaptureError for unreadable files); buf: its bytes, if already read."""
    path = Path(path)
    buf = read_input_bytes(path) if buf is None else buf
    meta = FrameMeta(file=str(path))
    try:
        blocks = find_blocks(buf)
    except (struct.error, IndexError, ValueError, OverflowError):
        blocks = Blocks(container="damaged")
        meta.notes.append("damaged container structure; metadata not read")
    meta.container = blocks.container
    maker_tags: dict[str, float] = {}
    maker_name = ""
    subject: float | None = None
    for role, tb, first in blocks.tiffs:
        try:
            sub, maker = _read_tiff(buf, tb, first, role, meta)
        except (struct.error, IndexError, ValueError, OverflowError, RecursionError):
            meta.notes.append(f"damaged {role} metadata block skipped")
            continue
        if sub is not None and subject is None:
            subject = sub
        for k, v in maker[0].items():
            maker_tags.setdefault(k, v)
        maker_name = maker_name or maker[1]
    if blocks.ciff:
        try:
            c = makernotes.ciff(*blocks.ciff)
        except (struct.error, IndexError, ValueError, OverflowError):
            c = {}
            meta.notes.append("damaged CRW (CIFF) metadata skipped")
        meta.make = meta.make or c.get("Make")
        meta.model = meta.model or c.get("Model")
        for k in ("FocusDistanceUpper", "FocusDistanceLower"):
            if k in c:
                maker_tags.setdefault(k, c[k])
        maker_name = maker_name or "Canon CRW ShotInfo"
    if blocks.flir:
        try:
            fl = makernotes.flir(blocks.flir)
        except (struct.error, IndexError, ValueError, OverflowError):
            fl = {}
            meta.notes.append("damaged FLIR metadata skipped")
        for k, v in fl.items():
            maker_tags.setdefault(k, v)
        if fl:
            maker_name = maker_name or "FLIR CameraInfo"
    xmp = next((v for v in (_xmp_focus(x) for x in blocks.xmp) if v is not None), None)

    meta.focus_tags.update(maker_tags)
    if subject is not None:
        meta.focus_tags["SubjectDistance"] = subject
    if xmp is not None:
        meta.focus_tags["ApproximateFocusDistance"] = xmp

    # precedence (see module docstring)
    if "FocusDistance" in maker_tags:
        v = maker_tags["FocusDistance"]
        if maker_name.startswith("Minolta") and v == 0:
            v = math.inf  # Minolta stores infinity as 0
        meta.focus_m, meta.focus_source = v, f"maker note: {maker_name} FocusDistance"
    elif "FocusDistanceUpper" in maker_tags:
        meta.focus_m, how = makernotes.canon_focus_m(maker_tags["FocusDistanceUpper"],
                                                     maker_tags.get("FocusDistanceLower", 0.0))
        meta.focus_source = f"maker note: {maker_name} FocusDistanceUpper/Lower ({how})"
    elif "ObjectDistance" in maker_tags:
        meta.focus_m, meta.focus_source = maker_tags["ObjectDistance"], f"maker note: {maker_name} ObjectDistance"
    elif subject is not None:
        meta.focus_m, meta.focus_source = subject, "EXIF SubjectDistance"
    elif xmp is not None:
        meta.focus_m, meta.focus_source = xmp, "XMP aux:ApproximateFocusDistance"
    elif use_exiftool and exiftool.available():
        et = exiftool.read(path)
        meta.focus_tags.update(et.focus_tags)
        if et.focus_m is not None:
            meta.focus_m, meta.focus_source = et.focus_m, f"exiftool {et.focus_source}"
        meta.make = meta.make or et.make
        meta.model = meta.model or et.model
        meta.lens = meta.lens or et.lens
        meta.focal_length_mm = meta.focal_length_mm or et.focal_length_mm
        meta.f_number = meta.f_number or et.f_number
        meta.focal_length_35mm = meta.focal_length_35mm or et.focal_length_35mm
        meta.focal_plane_px_per_mm = meta.focal_plane_px_per_mm or et.focal_plane_px_per_mm
    if meta.width is None and blocks.container in ("jpeg", "png"):
        meta.width, meta.height = claimed_size(buf, blocks.container) or (None, None)
    return meta


def _read_tiff(buf: bytes, tb: TiffBuffer, first: int, role: str, meta: FrameMeta
               ) -> tuple[float | None, tuple[dict[str, float], str]]:
    """Fill camera fields from one TIFF block; returns (EXIF SubjectDistance or None, (maker tags, maker name))."""
    if role == "canon_makernote":  # CR3 CMT3: the IFD0 is Canon's maker note
        ifd = tb.ifd(first)
        meta.lens = meta.lens or makernotes.canon_lens(tb, ifd)
        return None, (makernotes.canon(tb, ifd, meta.model or ""), "Canon")
    ifd0 = tb.ifd(first)
    exif = ifd0 if role == "exif" else {}
    if role == "main":
        meta.make = meta.make or tb.text(ifd0, MAKE)
        meta.model = meta.model or tb.text(ifd0, MODEL)
        meta.lens = meta.lens or tb.text(ifd0, DNG_LENS_MODEL)
        ptr = tb.number(ifd0, EXIF_POINTER)
        exif = tb.ifd(int(ptr)) if ptr else {}
        if meta.width is None and 0x0100 in ifd0 and not exif:
            meta.width, meta.height = int(tb.number(ifd0, 0x0100) or 0) or None, int(tb.number(ifd0, 0x0101) or 0) or None
    meta.lens = meta.lens or tb.text(exif, LENS_MODEL)
    for attr, tag in (("focal_length_mm", FOCAL_LENGTH), ("f_number", F_NUMBER)):
        if getattr(meta, attr) is None:
            v = tb.number(exif, tag) or tb.number(ifd0, tag)
            if v and math.isfinite(v):
                setattr(meta, attr, v)
    if meta.focal_length_35mm is None:
        v = tb.number(exif, FOCAL_LENGTH_35MM)
        if v and math.isfinite(v) and v > 0:
            meta.focal_length_35mm = float(v)
    if meta.focal_plane_px_per_mm is None:
        res, unit = tb.number(exif, FOCAL_PLANE_X_RES), tb.number(exif, FOCAL_PLANE_UNIT) or 2
        if res and math.isfinite(res) and res > 0 and int(unit) in FOCAL_PLANE_UNIT_MM:
            meta.focal_plane_px_per_mm = float(res) / FOCAL_PLANE_UNIT_MM[int(unit)]
    if meta.width is None:
        w, h = tb.number(exif, 0xA002), tb.number(exif, 0xA003)
        if w and h:
            meta.width, meta.height = int(w), int(h)
    subject = None
    for ifd in (exif, ifd0):
        e = ifd.get(SUBJECT_DISTANCE)
        if e is not None and e.type in (5, 10) and len(e.data) >= 8:
            num, den = struct.unpack(tb.endian + "II", e.data[:8])
            if num == 0xFFFFFFFF:
                subject = math.inf
            elif num and den:
                subject = num / den
            if subject is not None:
                break
    mn = exif.get(MAKER_NOTE)
    maker: tuple[dict[str, float], str] = ({}, "")
    if mn is not None:
        maker = _maker_note(buf, tb, mn, meta)
    return subject, maker


def _maker_note(buf: bytes, tb: TiffBuffer, mn, meta: FrameMeta) -> tuple[dict[str, float], str]:
    """(maker tags, maker-note name) from the decoder registered for the camera's make (makernotes.DECODERS)."""
    decoder = makernotes.decoder_for(meta.make)
    if decoder is None:
        return {}, ""
    return decoder.decode(buf, tb, mn, meta), decoder.name
