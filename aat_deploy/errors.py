"""Errors the runtime reports to users as one line (file + problem), without a traceback; the readers' file checks
that raise them live in `aat_deploy.io.files`."""

from __future__ import annotations

import sys


class AatError(ValueError):
    """The root of every error aat raises on purpose (bad input, a setting that cannot work, a missing extra): the
    message is one line naming the file or the setting and the problem. A ValueError, so callers that catch
    ValueError keep working; `except AatError` catches exactly aat's own. Some also derive from the built-in their
    callers catch (RuntimeError, ImportError). Not an error: `aat_deploy.interrupt.Interrupted` (a KeyboardInterrupt)."""


class CaptureError(AatError):
    """Bad input: an unreadable file, an inconsistent capture folder, a model that does not fit."""


class ModelError(CaptureError):
    """The ONNX model cannot be used (missing, not loadable, wrong metadata)."""


class OutputError(CaptureError):
    """An output cannot be written (exists without --force, not writable)."""


_CONTROL = {c: f"\\x{c:02x}" for c in [*range(0x20), 0x7F]} | {0x0A: "\\n", 0x0D: "\\r", 0x09: "\\t"}


def one_line(text: str) -> str:
    """`text` with control characters escaped (a newline in a folder name must not split a result line)."""
    return str(text).translate(_CONTROL)


def safe_output_streams() -> None:
    """Print file names that are not valid UTF-8 (Linux allows any bytes) with escapes instead of failing."""
    for s in (sys.stdout, sys.stderr):
        try:
            s.reconfigure(errors="backslashreplace")
        except (AttributeError, ValueError):  # replaced streams (pytest capture) may not support it
            pass
