"""What a frame file is, read from its bytes (never its name), and the size its header claims, checked against the
pixel limit before anything is decoded.

- Kind (`frame_kind`): "jpeg", "png", "tiff" or "raw", by magic bytes (containers.container_of). A TIFF container
  is a camera RAW when its content says so: a DNGVersion tag, Canon's CR2 signature, the ORF/RW2 variants of the
  TIFF magic, or a CFA / LinearRaw image in any IFD (NEF, ARW, PEF ...); CR3, CRW, MRW, RAF and X3F are RAWs by
  their own magic. Only where the bytes cannot tell, the name may: a TIFF container without RAW evidence, or
  unrecognised bytes, named with a RAW extension go to LibRaw (raw.load_frame falls back to TIFF when LibRaw
  declines a TIFF container). Anything else is one CaptureError line naming the file.
- Size (`claimed_size`): from the JPEG frame header, PNG IHDR, TIFF/BigTIFF IFD0, or LibRaw's parse of a RAW
  (LibRaw unpacks nothing until asked).
- Pixel limit (`check_pixels`): a header claiming more than the limit (default 200 megapixels, above the largest
  camera and phone sensors; environment variable AAT_MAX_MEGAPIXELS, or `--max-megapixels` / max_megapixels=) is
  refused before decoding, with the file and its size in one line: a 700-byte JPEG can claim 20000 x 20000 px and
  make a decoder allocate gigabytes.
"""

from __future__ import annotations

import io
import os
import struct
from pathlib import Path

from ..errors import CaptureError
from .containers import container_of
from .tiff import TiffBuffer

RAW_EXTENSIONS = {".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".raf", ".orf", ".rw2",
                  ".pef", ".kdc", ".dcr", ".mrw", ".x3f", ".iiq", ".3fr", ".erf", ".mef", ".mos", ".srw", ".rwl",
                  ".raw", ".fff"}
IMAGE_EXTENSIONS = {".tif", ".tiff", ".png", ".jpg", ".jpeg"}
FRAME_EXTENSIONS = RAW_EXTENSIONS | IMAGE_EXTENSIONS  # which files of a folder are frames (their content decides how)

DEFAULT_MAX_MEGAPIXELS = 200.0
ENV_MAX_MEGAPIXELS = "AAT_MAX_MEGAPIXELS"
_RAW_CONTAINERS = {"cr3", "crw", "mrw", "raf", "x3f"}
_UNSUPPORTED = {"heif": "a HEIF/HEIC/AVIF image", "webp": "a WebP image", "gif": "a GIF image", "bmp": "a BMP image",
                "jpeg2000": "a JPEG 2000 image", "jpegxl": "a JPEG XL image"}
_DNG_VERSION, _PHOTOMETRIC, _SUB_IFDS = 0xC612, 262, 0x014A
_RAW_PHOTOMETRIC = (32803, 34892)  # CFA, LinearRaw


def is_raw_name(path: Path) -> bool:
    """True if the file's extension names a camera RAW format (a hint, used only where the bytes cannot tell)."""
    return Path(path).suffix.lower() in RAW_EXTENSIONS


def _tiff_is_raw(buf: bytes) -> bool:
    """A TIFF container whose content shows a camera RAW (see the module docstring)."""
    if buf[8:11] == b"CR\x02" or buf[:4] in (b"IIRO", b"IIRS", b"MMOR", b"IIU\0"):
        return True
    hdr = TiffBuffer.from_header(buf, 0)
    if hdr is None:
        return False
    tb, first = hdr
    todo, seen = [first], set()
    while todo and len(seen) < 32:
        off = todo.pop()
        if off in seen or off <= 0:
            continue
        seen.add(off)
        try:
            ifd = tb.ifd(off)
            if _DNG_VERSION in ifd or tb.number(ifd, _PHOTOMETRIC) in _RAW_PHOTOMETRIC:
                return True
            if _SUB_IFDS in ifd and ifd[_SUB_IFDS].type in (4, 13):
                todo += [int(v) for v in tb.values(ifd[_SUB_IFDS])[:8]]
            todo.append(tb.next_ifd(off))
        except (struct.error, IndexError, ValueError, OverflowError):
            continue
    return False


def frame_kind(path: Path, buf: bytes) -> str:
    """"jpeg", "png", "tiff" or "raw" from the file's bytes; CaptureError naming the file for anything else."""
    c = container_of(buf)
    if c in ("jpeg", "png"):
        return c
    if c == "tiff":
        return "raw" if _tiff_is_raw(buf) or is_raw_name(path) else "tiff"
    if c == "bigtiff":
        return "tiff"
    if c in _RAW_CONTAINERS:
        return "raw"
    if c in _UNSUPPORTED:
        raise CaptureError(f"{path}: is {_UNSUPPORTED[c]}, which aat does not read (convert it to JPEG, PNG or TIFF)")
    if is_raw_name(path):
        return "raw"  # RAW formats without a magic of their own: LibRaw knows them, or says it does not
    head = buf[:8].hex(" ")
    raise CaptureError(f"{path}: unknown content, not a JPEG, PNG, TIFF or camera RAW file (starts with {head})")


def _jpeg_size(buf: bytes) -> tuple[int, int] | None:
    i = 2
    while i + 9 < len(buf):
        if buf[i] != 0xFF:
            return None
        marker = buf[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # markers without a length
            i += 2
            continue
        (length,) = struct.unpack(">H", buf[i + 2:i + 4])
        if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
            h, w = struct.unpack(">HH", buf[i + 5:i + 9])
            return w, h
        if marker in (0xDA, 0xD9) or length < 2:
            return None
        i += 2 + length
    return None


def _bigtiff_size(buf: bytes) -> tuple[int, int] | None:
    e = "<" if buf[:2] == b"II" else ">"
    if len(buf) < 16:
        return None
    (off,) = struct.unpack(e + "Q", buf[8:16])
    if off + 8 > len(buf):
        return None
    (n,) = struct.unpack(e + "Q", buf[off:off + 8])
    dims = {}
    for k in range(min(n, 4096)):
        at = off + 8 + 20 * k
        if at + 20 > len(buf):
            break
        tag, typ, count = struct.unpack(e + "HHQ", buf[at:at + 12])
        if tag in (256, 257) and count == 1 and typ in (3, 4, 16):
            code = {3: "H", 4: "I", 16: "Q"}[typ]
            dims[tag] = struct.unpack(e + code, buf[at + 12:at + 12 + struct.calcsize(code)])[0]
    return (dims[256], dims[257]) if len(dims) == 2 else None


def _raw_sizes(buf: bytes) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """((width, height) developed, (width, height) of the sensor data) from LibRaw's parse (nothing unpacked), or
    None if LibRaw cannot open the bytes."""
    import rawpy

    try:
        with rawpy.imread(io.BytesIO(buf)) as r:
            s = r.sizes
            w, h = int(s.width), int(s.height)
            return ((h, w) if s.flip in (5, 6) else (w, h)), (int(s.raw_width), int(s.raw_height))
    except (rawpy.LibRawError, OSError):
        return None


def raw_size(buf: bytes) -> tuple[int, int] | None:
    """(width, height) a RAW file will be developed to (LibRaw's parse, nothing unpacked), or None."""
    sizes = _raw_sizes(buf)
    return None if sizes is None else sizes[0]


def claimed_size(buf: bytes, kind: str) -> tuple[int, int] | None:
    """(width, height) in pixels the header of a file of this kind claims, without decoding; None if unknown."""
    try:
        if kind == "jpeg":
            return _jpeg_size(buf)
        if kind == "png":
            return struct.unpack(">II", buf[16:24]) if len(buf) >= 24 and buf[12:16] == b"IHDR" else None
        if kind == "tiff":
            if container_of(buf) == "bigtiff":
                return _bigtiff_size(buf)
            hdr = TiffBuffer.from_header(buf, 0)
            if hdr is None:
                return None
            tb, first = hdr
            ifd = tb.ifd(first)
            w, h = tb.number(ifd, 256), tb.number(ifd, 257)
            return (int(w), int(h)) if w is not None and h is not None else None
        if kind == "raw":
            return raw_size(buf)
    except (struct.error, IndexError, ValueError, OverflowError):
        return None
    return None


def max_megapixels(limit: float | None = None) -> float:
    """The pixel limit in megapixels: `limit` if given, else $AAT_MAX_MEGAPIXELS, else the default."""
    if limit is not None:
        return float(limit)
    env = os.environ.get(ENV_MAX_MEGAPIXELS)
    if env:
        try:
            v = float(env)
        except ValueError:
            raise CaptureError(f"{ENV_MAX_MEGAPIXELS}={env!r}: not a number of megapixels") from None
        if not v > 0:
            raise CaptureError(f"{ENV_MAX_MEGAPIXELS}={env!r}: must be a positive number of megapixels")
        return v
    return DEFAULT_MAX_MEGAPIXELS


def check_pixels(path: Path, size: tuple[int, int], limit: float | None = None,
                 error: type[CaptureError] = CaptureError) -> None:
    """`error` naming the file and its size if width x height exceeds the pixel limit (max_megapixels)."""
    w, h = (int(v) for v in size)
    lim = max_megapixels(limit)
    if w * h > lim * 1e6:
        raise error(f"{path}: its header claims {w} x {h} px ({w * h / 1e6:.0f} MP), beyond the limit of {lim:g} MP "
                           f"(raise it with --max-megapixels or {ENV_MAX_MEGAPIXELS} if the image is real)")


def frame_header(path: Path, buf: bytes, limit: float | None = None) -> tuple[str, tuple[int, int] | None]:
    """A frame file's kind and claimed size, refused (CaptureError) if unknown or beyond the pixel limit."""
    kind = frame_kind(path, buf)
    if kind == "raw":  # the sensor data is checked too: LibRaw allocates it before developing
        sizes = _raw_sizes(buf)
        if sizes is None:  # a RAW LibRaw cannot open is reported by its decoder
            return kind, None
        check_pixels(path, sizes[1], limit)
        size = sizes[0]
    else:
        size = claimed_size(buf, kind)
        if size is None:
            raise CaptureError(f"{path}: damaged {kind.upper()} header (no image size in it)")
    check_pixels(path, size, limit)
    return kind, size
