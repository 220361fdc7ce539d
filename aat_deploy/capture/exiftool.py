"""Optional fallback: ask ExifTool (`exiftool -j -n`) when it is installed. Never required."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from .makernotes import canon_focus_m

# exiftool tag names that hold a focus distance in metres, in the order we trust them
FOCUS_TAGS = ("FocusDistance", "FocusDistanceUpper", "SubjectDistance", "ObjectDistance", "ApproximateFocusDistance")
_ASKED = ("FocusDistance", "FocusDistanceUpper", "FocusDistanceLower", "SubjectDistance", "ObjectDistance",
          "ApproximateFocusDistance", "Make", "Model", "LensModel", "Lens", "FocalLength", "FNumber",
          "FocalLengthIn35mmFormat", "FocalPlaneXResolution", "FocalPlaneResolutionUnit")
_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # exiftool -n FocalPlaneResolutionUnit: inch, cm, mm, um


@dataclass
class ExifToolResult:
    """What exiftool reported (distances in metres)."""

    focus_m: float | None = None
    focus_source: str | None = None
    focus_tags: dict[str, float] = field(default_factory=dict)
    make: str | None = None
    model: str | None = None
    lens: str | None = None
    focal_length_mm: float | None = None
    f_number: float | None = None
    focal_length_35mm: float | None = None
    focal_plane_px_per_mm: float | None = None


def available() -> bool:
    """True when an `exiftool` executable is on PATH."""
    return shutil.which("exiftool") is not None


def read(path: str | Path, timeout_s: float = 30.0) -> ExifToolResult:
    """Run exiftool on one file; an empty result if it fails (exiftool is only a fallback)."""
    out = ExifToolResult()
    exe = shutil.which("exiftool")
    if exe is None:
        return out
    try:
        proc = subprocess.run([exe, "-j", "-n", *(f"-{t}" for t in _ASKED), str(path)],
                              capture_output=True, text=True, timeout=timeout_s, check=False)
        data = json.loads(proc.stdout)[0]
    except (OSError, subprocess.SubprocessError, ValueError, IndexError, KeyError):
        return out
    for name in _ASKED[:6]:
        v = data.get(name)
        if isinstance(v, (int, float)) and math.isfinite(v):
            out.focus_tags[name] = float(v)
    for name in FOCUS_TAGS:
        v = out.focus_tags.get(name)
        if v is None:
            continue
        if name == "FocusDistanceUpper":
            if v <= 0:
                continue
            v, _ = canon_focus_m(v, out.focus_tags.get("FocusDistanceLower", 0.0))
        if v > 0:
            out.focus_m, out.focus_source = v, name
            break
    out.make = data.get("Make") or None
    out.model = str(data["Model"]) if data.get("Model") is not None else None
    out.lens = data.get("LensModel") or data.get("Lens") or None
    for attr, name in (("focal_length_mm", "FocalLength"), ("f_number", "FNumber"),
                       ("focal_length_35mm", "FocalLengthIn35mmFormat")):
        v = data.get(name)
        if isinstance(v, (int, float)):
            setattr(out, attr, float(v))
    res, unit = data.get("FocalPlaneXResolution"), data.get("FocalPlaneResolutionUnit", 2)
    if isinstance(res, (int, float)) and math.isfinite(res) and res > 0 and unit in _PLANE_UNIT_MM:
        out.focal_plane_px_per_mm = float(res) / _PLANE_UNIT_MM[unit]
    return out
