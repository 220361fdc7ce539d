"""`--focus-m 0.6,0.8,1.2`: focus distances typed on the command line, for stacks whose files carry none (JPEG or
PNG stacks, phones), as an alternative to writing `capture.json`."""

from __future__ import annotations

from ..errors import CaptureError
from .folder import MAX_FOCUS_M, focus_problem

__all__ = ["MAX_FOCUS_M", "parse_focus_list"]


def parse_focus_list(text: str) -> list[float]:
    """'0.6, 0.8,1.2' -> [0.6, 0.8, 1.2]: metres from the sensor, comma-separated, each a physical focus distance
    (`folder.focus_problem`: finite, > 0, at most MAX_FOCUS_M); at least one. Raises CaptureError, one line naming
    the bad entry."""
    if not isinstance(text, str) or not text.strip():
        raise CaptureError("--focus-m: expected comma-separated focus distances in metres, e.g. 0.6,0.8,1.2")
    out = []
    for i, part in enumerate(text.split(",")):
        p = part.strip()
        try:
            v = float(p)
        except ValueError:
            raise CaptureError(f"--focus-m: entry {i + 1} ({p[:40]!r}) is not a number") from None
        why = focus_problem(v)
        if why is not None:
            raise CaptureError(f"--focus-m: entry {i + 1} ({p[:40]}) is not a focus distance in metres ({why})")
        out.append(v)
    return out
