"""Errors the runtime reports to users as one line (file + problem), without a traceback."""

from __future__ import annotations


class CaptureError(ValueError):
    """Bad input: an unreadable file, an inconsistent capture folder, a model that does not fit."""


class ModelError(CaptureError):
    """The ONNX model cannot be used (missing, not loadable, wrong metadata)."""


class OutputError(CaptureError):
    """An output cannot be written (exists without --force, not writable)."""
