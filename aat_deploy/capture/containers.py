"""Find the metadata blocks inside an image or RAW file: TIFF/EXIF structures, XMP packets, FLIR records,
Canon CIFF (CRW) heaps. Pure byte parsing, no pixels.

Supported containers: TIFF-based files (DNG, CR2, NEF, ARW, ORF, RW2, PEF, KDC, IIQ, plain TIFF), JPEG
(APP1 Exif / XMP / FLIR), Canon CR3 (ISO base media, CMT1..CMT3 boxes), Canon CRW (CIFF heap),
Minolta MRW (TTW block), Fujifilm RAF (its embedded JPEG), PNG (eXIf and iTXt XMP chunks).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

from .tiff import TiffBuffer

CANON_CR3_UUID = bytes.fromhex("85c0b687820f11e08111f4ce462b6a48")


@dataclass
class Blocks:
    """Metadata found in one file.

    tiffs: (role, reader, first IFD offset); role is "main" (IFD0 with EXIF pointer), "exif" (an EXIF IFD
    directly, CR3 CMT2), or "canon_makernote" (CR3 CMT3: IFD0 is a Canon maker note).
    """

    tiffs: list[tuple[str, TiffBuffer, int]] = field(default_factory=list)
    xmp: list[bytes] = field(default_factory=list)
    flir: bytes = b""
    ciff: tuple[bytes, int, int] | None = None  # (buffer, heap start, heap length) of a Canon CRW
    container: str = "unknown"


def _jpeg(buf: bytes, start: int, out: Blocks) -> None:
    i = start + 2
    flir_parts: list[tuple[int, bytes]] = []
    while i + 4 <= len(buf) and buf[i] == 0xFF:
        marker = buf[i + 1]
        if marker in (0xD9, 0xDA):  # end of image / start of scan: no more metadata segments
            break
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        (length,) = struct.unpack(">H", buf[i + 2:i + 4])
        seg_at = i + 4
        seg = buf[seg_at:i + 2 + length]
        if marker == 0xE1:
            if seg.startswith(b"Exif\0\0"):
                hdr = TiffBuffer.from_header(buf, seg_at + 6)
                if hdr:
                    out.tiffs.append(("main", *hdr))
            elif seg.startswith(b"http://ns.adobe.com/xap/1.0/\0"):
                out.xmp.append(seg[29:])
            elif seg.startswith(b"FLIR\0") and len(seg) >= 8:
                flir_parts.append((seg[6], seg[8:]))
        i += 2 + length
    if flir_parts:
        out.flir = b"".join(p for _, p in sorted(flir_parts, key=lambda x: x[0]))


def _bmff_boxes(buf: bytes, start: int, end: int):
    """Yield (type, payload start, payload end) of ISO-BMFF boxes in buf[start:end]."""
    i = start
    while i + 8 <= end:
        size, typ = struct.unpack(">I4s", buf[i:i + 8])
        head = 8
        if size == 1 and i + 16 <= end:
            size = struct.unpack(">Q", buf[i + 8:i + 16])[0]
            head = 16
        elif size == 0:
            size = end - i
        if size < head or i + size > end:
            return
        yield typ, i + head, i + size
        i += size


def _cr3(buf: bytes, out: Blocks) -> None:
    for typ, s, e in _bmff_boxes(buf, 0, len(buf)):
        if typ == b"moov":
            for t2, s2, e2 in _bmff_boxes(buf, s, e):
                if t2 == b"uuid" and buf[s2:s2 + 16] == CANON_CR3_UUID:
                    for t3, s3, _ in _bmff_boxes(buf, s2 + 16, e2):
                        role = {b"CMT1": "main", b"CMT2": "exif", b"CMT3": "canon_makernote"}.get(t3)
                        hdr = TiffBuffer.from_header(buf, s3) if role else None
                        if hdr:
                            out.tiffs.append((role, *hdr))
        elif typ == b"uuid" and buf[s:s + 16] == bytes.fromhex("be7acfcb97a942e89c71999491e3afac"):
            out.xmp.append(buf[s + 16:e])  # XMP box


def _mrw(buf: bytes, out: Blocks) -> None:
    (hlen,) = struct.unpack(">I", buf[4:8])
    i, end = 8, min(len(buf), 8 + hlen)
    while i + 8 <= end:
        name, length = struct.unpack(">4sI", buf[i:i + 8])
        if name == b"\0TTW":
            hdr = TiffBuffer.from_header(buf, i + 8)
            if hdr:
                out.tiffs.append(("main", *hdr))
        i += 8 + length


def _png(buf: bytes, out: Blocks) -> None:
    i = 8
    while i + 12 <= len(buf):
        length, typ = struct.unpack(">I4s", buf[i:i + 8])
        data_at = i + 8
        if typ == b"eXIf":
            hdr = TiffBuffer.from_header(buf, data_at)
            if hdr:
                out.tiffs.append(("main", *hdr))
        elif typ == b"iTXt" and buf[data_at:data_at + 18] == b"XML:com.adobe.xmp\0":
            rest = buf[data_at + 18:data_at + length]
            compressed = rest[:1] == b"\x01"
            # skip compression flag/method, language tag and translated keyword (NUL-terminated)
            parts = rest[2:].split(b"\0", 2)
            if len(parts) == 3:
                text = parts[2]
                try:
                    out.xmp.append(zlib.decompress(text) if compressed else text)
                except zlib.error:
                    pass
        elif typ == b"IEND":
            break
        i += 12 + length


def container_of(buf: bytes) -> str:
    """The container a file's first bytes announce (its magic bytes; the name is never used): "jpeg", "png",
    "tiff" (TIFF and the TIFF-based RAWs: DNG, CR2, NEF, ARW, ORF, RW2, PEF ...), "bigtiff", "cr3", "crw", "mrw",
    "raf", "x3f", one of the image formats aat does not read ("heif", "webp", "gif", "bmp", "jpeg2000", "jpegxl"),
    or "unknown"."""
    if buf[:3] == b"\xff\xd8\xff":
        return "jpeg"
    if buf[:8] == b"\x89PNG\r\n\x1a\n":
        return "png"
    if buf[:2] in (b"II", b"MM") and buf[6:14] == b"HEAPCCDR":
        return "crw"
    if buf[:4] in (b"II*\0", b"MM\0*", b"IIRO", b"IIRS", b"MMOR", b"IIU\0"):
        return "tiff"
    if buf[:4] in (b"II+\0", b"MM\0+"):
        return "bigtiff"
    if buf[4:12] == b"ftypcrx ":
        return "cr3"
    if buf[4:8] == b"ftyp" and buf[8:12] in (b"heic", b"heix", b"mif1", b"msf1", b"hevc", b"avif"):
        return "heif"
    if buf[:4] == b"\0MRM":
        return "mrw"
    if buf[:16] == b"FUJIFILMCCD-RAW ":
        return "raf"
    if buf[:4] == b"FOVb":
        return "x3f"
    if buf[:4] == b"RIFF" and buf[8:12] == b"WEBP":
        return "webp"
    if buf[:6] in (b"GIF87a", b"GIF89a"):
        return "gif"
    if buf[:2] == b"BM" and len(buf) >= 26:
        return "bmp"
    if buf[:12] == b"\0\0\0\x0cjP  \r\n\x87\n" or buf[:4] == b"\xff\x4f\xff\x51":
        return "jpeg2000"
    if buf[:2] == b"\xff\x0a" or buf[:12] == b"\0\0\0\x0cJXL \r\n\x87\n":
        return "jpegxl"
    return "unknown"


def find_blocks(buf: bytes) -> Blocks:
    """Locate the metadata blocks in a whole file's bytes (unknown formats give empty Blocks)."""
    out = Blocks()
    kind = container_of(buf)
    if kind == "jpeg" or buf[:2] == b"\xff\xd8":
        out.container = "jpeg"
        _jpeg(buf, 0, out)
    elif kind == "crw":
        out.container = "crw"
        (hlen,) = struct.unpack("<I" if buf[:2] == b"II" else ">I", buf[2:6])
        out.ciff = (buf, hlen, len(buf) - hlen)
    elif kind == "cr3":
        out.container = "cr3"
        _cr3(buf, out)
    elif kind == "mrw":
        out.container = "mrw"
        _mrw(buf, out)
    elif kind == "raf":
        out.container = "raf"
        (jpeg_at,) = struct.unpack(">I", buf[84:88])
        if buf[jpeg_at:jpeg_at + 2] == b"\xff\xd8":
            _jpeg(buf, jpeg_at, out)
    elif kind == "png":
        out.container = "png"
        _png(buf, out)
    else:
        hdr = TiffBuffer.from_header(buf, 0)
        if hdr:
            out.container = "tiff"
            out.tiffs.append(("main", *hdr))
            ifd0 = hdr[0].ifd(hdr[1])
            if 700 in ifd0:  # XMP packet in IFD0 (DNG, TIFF)
                out.xmp.append(ifd0[700].data)
    return out
