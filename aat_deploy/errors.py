"""Errors the runtime reports to users as one line (file + problem), without a traceback."""

from __future__ import annotations

from pathlib import Path


class CaptureError(ValueError):
    """Bad input: an unreadable file, an inconsistent capture folder, a model that does not fit."""


class ModelError(CaptureError):
    """The ONNX model cannot be used (missing, not loadable, wrong metadata)."""


class OutputError(CaptureError):
    """An output cannot be written (exists without --force, not writable)."""


def read_input_bytes(path: Path) -> bytes:
    """A frame file's bytes; CaptureError naming the file if it cannot be read or is empty."""
    try:
        buf = Path(path).read_bytes()
    except OSError as e:
        raise CaptureError(f"{path}: cannot read ({e.strerror or e})") from None
    if not buf:
        raise CaptureError(f"{path}: empty file")
    return buf
