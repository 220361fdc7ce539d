"""`--focus-m 0.6,0.8,1.2`: focus distances typed on the command line, for stacks whose files carry none (JPEG or
PNG stacks, phones), as an alternative to writing `capture.json`."""

from __future__ import annotations

import math

from ..errors import CaptureError

MAX_FOCUS_M = 1000.0  # beyond 1 km a "focus distance" is a typo or infinity, not a focus position


def parse_focus_list(text: str) -> list[float]:
    """'0.6, 0.8,1.2' -> [0.6, 0.8, 1.2]: metres from the sensor, comma-separated, each finite, > 0 and at most
    MAX_FOCUS_M; at least one. Raises CaptureError with one line naming the bad entry."""
    if not isinstance(text, str) or not text.strip():
        raise CaptureError("--focus-m: expected comma-separated focus distances in metres, e.g. 0.6,0.8,1.2")
    out = []
    for i, part in enumerate(text.split(",")):
        p = part.strip()
        try:
            v = float(p)
        except ValueError:
            raise CaptureError(f"--focus-m: entry {i + 1} ({p[:40]!r}) is not a number") from None
        if not math.isfinite(v) or v <= 0 or v > MAX_FOCUS_M:
            raise CaptureError(f"--focus-m: entry {i + 1} ({p[:40]}) must be a focus distance in metres, "
                               f"> 0 and at most {MAX_FOCUS_M:g}")
        out.append(v)
    return out
