"""Image files through OpenCV's in-memory codecs, so any file name works.

cv2.imread/cv2.imwrite crash the process (segmentation fault) on a path that is not valid UTF-8, which Linux
allows (a camera card's Latin-1 folder name): Python reads and writes the bytes, OpenCV only decodes/encodes.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def imread(path: str | Path, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray | None:
    """cv2.imread without the file name problem: None if the file cannot be read or decoded (as cv2.imread)."""
    try:
        buf = Path(path).read_bytes()
    except OSError:
        return None
    if not buf:
        return None
    return cv2.imdecode(np.frombuffer(buf, np.uint8), flags)


def imwrite(path: str | Path, img: np.ndarray) -> bool:
    """cv2.imwrite without the file name problem (format from the suffix); False if it cannot be written."""
    path = Path(path)
    try:
        ok, enc = cv2.imencode(path.suffix or ".png", np.ascontiguousarray(img))
        if not ok:
            return False
        path.write_bytes(enc.tobytes())
    except (OSError, cv2.error):
        return False
    return True
