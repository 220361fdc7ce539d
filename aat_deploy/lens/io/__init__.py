"""Load and save lenses: our JSON ("aat-lens-v1"), the paper's legacy JSON, Zemax .zmx, DiffOptics .txt.

`load_lens(path)` picks the reader from the file's suffix and content; `save_lens` writes our format. One module per
format (`aat_json.py`, `legacy_json.py`, `zemax.py`, `diffoptics.py`); a new format is one more module and one more
branch here. Every reader raises `LensFileError` (`aat_deploy.lens.check`) with the file name (and line or
surface) and the problem in one line.

This folder sits above `aat_deploy/optics` (the Zemax reader sizes the stop paraxially), which itself reads only
the plain lens data in `aat_deploy/lens`: the folders import in one direction.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..check import LensFileError, validate
from ..check import lens_file_error as _err
from ..schema import Lens
from .aat_json import lens_from_dict, save_lens
from .diffoptics import load_diffoptics_txt
from .legacy_json import DEFAULT_LEGACY_RESOLUTION, load_legacy_json
from .zemax import DEFAULT_ZMX_RESOLUTION, load_zmx

__all__ = ["LensFileError", "validate", "lens_from_dict", "save_lens", "load_legacy_json", "load_zmx",
           "load_diffoptics_txt", "load_lens", "DEFAULT_LEGACY_RESOLUTION", "DEFAULT_ZMX_RESOLUTION"]


def load_lens(path) -> Lens:
    """Read any supported lens file; errors name the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise _err(path, "no such file")
    suffix = path.suffix.lower()
    if suffix == ".zmx":
        return load_zmx(path)
    if suffix == ".json":
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise _err(path, f"invalid JSON ({e})") from None
        if not isinstance(d, dict):
            raise _err(path, "top level must be a JSON object")
        if d.get("format") == "aat-lens-v1":
            return lens_from_dict(d, path)
        if "surfaces" in d:
            return load_legacy_json(d, path)
        raise _err(path, "JSON is neither aat-lens-v1 nor a legacy lens file (no 'surfaces')")
    if suffix == ".txt":
        return load_diffoptics_txt(path)
    raise _err(path, f"unsupported lens file type {suffix!r} (.json, .zmx, .txt)")
