"""A small, defensive TIFF/IFD reader for metadata (EXIF, maker notes, XMP). No pixel data.

Everything works on an in-memory `bytes` buffer with offsets relative to a base (the TIFF header, or
another origin a maker note dictates). Malformed entries are skipped rather than raising: metadata in
the wild is often damaged, and a missing focus tag is reported by the caller.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

# TIFF field types: size in bytes and struct code (rationals handled separately)
_TYPES = {1: (1, "B"), 2: (1, "s"), 3: (2, "H"), 4: (4, "I"), 5: (8, "II"), 6: (1, "b"), 7: (1, "B"),
          8: (2, "h"), 9: (4, "i"), 10: (8, "ii"), 11: (4, "f"), 12: (8, "d"), 13: (4, "I")}
MAX_ENTRIES = 1000


@dataclass(frozen=True)
class Entry:
    """One IFD entry: `data` is the raw value bytes (already located, in-line or out-of-line)."""

    tag: int
    type: int
    count: int
    data: bytes
    data_offset: int  # absolute offset of `data` in the buffer (for maker notes that use absolute offsets)


class TiffBuffer:
    """Read IFDs from `buf`; offsets in IFDs are relative to `base`; `endian` is '<' or '>'."""

    def __init__(self, buf: bytes, base: int = 0, endian: str = "<"):
        self.buf, self.base, self.endian = buf, base, endian

    @classmethod
    def from_header(cls, buf: bytes, start: int = 0) -> tuple[TiffBuffer, int] | None:
        """Parse a TIFF header ('II*\\0' or 'MM\\0*') at `start`; returns (reader, first IFD offset) or None."""
        head = buf[start:start + 8]
        if len(head) < 8 or head[:2] not in (b"II", b"MM"):
            return None
        endian = "<" if head[:2] == b"II" else ">"
        magic, first = struct.unpack(endian + "HI", head[2:8])
        if magic not in (42, 0x4F52, 0x5352, 0x55):  # TIFF, ORF ('RO', 'RS'), RW2 (0x55)
            return None
        return cls(buf, start, endian), first

    def u16(self, off: int) -> int:
        return struct.unpack_from(self.endian + "H", self.buf, off)[0]

    def u32(self, off: int) -> int:
        return struct.unpack_from(self.endian + "I", self.buf, off)[0]

    def ifd(self, offset: int, absolute: bool = False) -> dict[int, Entry]:
        """Entries of the IFD at `offset` (relative to base unless `absolute`); {} if it is not readable."""
        pos = offset if absolute else self.base + offset
        if pos < 0 or pos + 2 > len(self.buf):
            return {}
        n = self.u16(pos)
        if n == 0 or n > MAX_ENTRIES or pos + 2 + 12 * n > len(self.buf):
            return {}
        out: dict[int, Entry] = {}
        for i in range(n):
            e = pos + 2 + 12 * i
            tag, typ, count = struct.unpack_from(self.endian + "HHI", self.buf, e)
            if typ not in _TYPES or count > 10_000_000:
                continue
            size = _TYPES[typ][0] * count
            if size <= 4:
                at = e + 8
            else:
                at = self.base + self.u32(e + 8)
            if at < 0 or at + size > len(self.buf):
                continue
            out.setdefault(tag, Entry(tag, typ, count, self.buf[at:at + size], at))
        return out

    def next_ifd(self, offset: int) -> int:
        """Offset of the IFD following the one at `offset` (0 if none or unreadable)."""
        pos = self.base + offset
        try:
            n = self.u16(pos)
            return self.u32(pos + 2 + 12 * n)
        except struct.error:
            return 0

    def values(self, entry: Entry) -> list | str | bytes:
        """Decoded value: str for ASCII, bytes for UNDEFINED/BYTE, list of numbers otherwise (rationals as float)."""
        typ, data = entry.type, entry.data
        if typ == 2:
            return data.split(b"\0", 1)[0].decode("latin-1").strip()
        if typ in (1, 7):
            return data
        size, code = _TYPES[typ]
        n = len(data) // size
        if typ in (5, 10):
            flat = struct.unpack(self.endian + code[0] * (2 * n), data[:8 * n])
            return [a / b if b else float("inf") if a else float("nan") for a, b in zip(flat[::2], flat[1::2])]
        return list(struct.unpack(self.endian + code * n, data[:size * n]))

    def number(self, ifd: dict[int, Entry], tag: int) -> float | None:
        """First numeric value of `tag` in `ifd`, or None."""
        e = ifd.get(tag)
        if e is None or e.type in (1, 2, 7):
            if e is not None and e.type == 1 and e.data:
                return float(e.data[0])
            return None
        v = self.values(e)
        return float(v[0]) if v else None

    def text(self, ifd: dict[int, Entry], tag: int) -> str | None:
        """ASCII value of `tag` in `ifd` (stripped), or None."""
        e = ifd.get(tag)
        if e is None:
            return None
        if e.type == 2:
            return self.values(e) or None
        if e.type in (1, 7):
            return e.data.split(b"\0", 1)[0].decode("latin-1").strip() or None
        return None

    def array(self, entry: Entry, fmt: str) -> list[int]:
        """Re-read an entry's raw bytes as an array of struct code `fmt` (e.g. 'H', 'h', 'I') in this byte order."""
        size = struct.calcsize(fmt)
        n = len(entry.data) // size
        return list(struct.unpack(self.endian + fmt * n, entry.data[:n * size]))
