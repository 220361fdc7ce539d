"""A capture folder: its frame files, each frame's focus distance (sidecar > EXIF/maker notes > exiftool),
optional ground truth, and the validation that turns a bad folder into a one-line error.

Layout (docs/contracts.md, "Capture folder"): frames in any RAW/TIFF/PNG/JPEG format, one per focus distance;
optional `capture.json` = {"frames": [{"file": "f0.dng", "focus_m": 0.5}, ...]} which overrides metadata
(when it lists frames, exactly those files are the capture); optional `gt_depth_m.npy`, `gt_depth_mm.png`,
`gt_aif.png`. `virtual_camera.json` is never read here (real captures do not have it).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import CaptureError
from . import exiftool
from .exif import FrameMeta, read_metadata
from .raw import FRAME_EXTENSIONS

SIDECAR = "capture.json"
GT_NAMES = ("gt_depth_m.npy", "gt_depth_mm.png", "gt_aif.png")


@dataclass
class Frame:
    """One frame: its file, the focus distance used (metres from the sensor) and where it came from."""

    path: Path
    focus_m: float | None
    focus_source: str | None
    meta: FrameMeta


@dataclass
class Capture:
    """A capture folder's frames (in file-name order until sorted by the pipeline) and extras."""

    path: Path
    frames: list[Frame]
    gt_depth_m: Path | None = None
    gt_depth_mm: Path | None = None
    gt_aif: Path | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.path.name


def frame_files(folder: Path) -> list[Path]:
    """Frame files in a folder, by name (ground-truth images and hidden files excluded)."""
    return sorted(p for p in folder.iterdir()
                  if p.is_file() and p.suffix.lower() in FRAME_EXTENSIONS and not p.name.startswith((".", "gt_")))


def _sidecar(folder: Path) -> dict[str, float] | None:
    path = folder / SIDECAR
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise CaptureError(f"{path}: not valid JSON ({e})") from None
    frames = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(frames, list):
        raise CaptureError(f'{path}: expected {{"frames": [{{"file": ..., "focus_m": ...}}, ...]}}')
    out: dict[str, float] = {}
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or not isinstance(fr.get("file"), str):
            raise CaptureError(f"{path}: frames[{i}] needs a string 'file'")
        f = fr.get("focus_m")
        if not isinstance(f, (int, float)) or isinstance(f, bool) or not math.isfinite(f) or f <= 0:
            raise CaptureError(f"{path}: frames[{i}] ({fr['file']}) needs focus_m > 0 in metres, got {f!r}")
        if fr["file"] in out:
            raise CaptureError(f"{path}: {fr['file']} listed twice")
        out[fr["file"]] = float(f)
    return out


def read_capture(folder: str | Path, use_exiftool: bool = True, focus_m: list[float] | None = None,
                 equal_focus_ok: bool = False) -> Capture:
    """Read and validate a capture folder's frame list and focus distances (pixels are not decoded here).

    focus_m: the frames' focus distances (m, `aat-infer --focus-m`) in file-name order, overriding metadata and
    capture.json (as many as there are frames). equal_focus_ok: frames with equal focus distances are a warning
    (the caller places them), not an error."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: not a folder")
    sidecar = _sidecar(folder)
    warnings: list[str] = []
    if sidecar:
        files = []
        for name in sidecar:
            p = folder / name
            if not p.is_file():
                raise CaptureError(f"{folder / SIDECAR}: lists {name}, which does not exist")
            files.append(p)
        others = [p.name for p in frame_files(folder) if p.name not in sidecar]
        if others:
            warnings.append(f"{folder}: {len(others)} frame file(s) not listed in {SIDECAR} ignored: "
                            + ", ".join(others[:5]))
    else:
        files = frame_files(folder)
    if not files:
        raise CaptureError(f"{folder}: empty capture folder (no RAW, TIFF, PNG or JPEG frames)")
    if len(files) < 2:
        raise CaptureError(f"{folder}: only one frame ({files[0].name}); a focal stack needs at least two")
    if focus_m is not None and len(focus_m) != len(files):
        raise CaptureError(f"{folder}: --focus-m gives {len(focus_m)} focus distances for {len(files)} frames")
    if focus_m is not None and sidecar:
        warnings.append(f"{folder}: --focus-m overrides the focus distances in {SIDECAR}")
    frames = []
    for i, p in enumerate(files):
        meta = read_metadata(p, use_exiftool=use_exiftool)
        if focus_m is not None:
            frames.append(Frame(p, float(focus_m[i]), "--focus-m", meta))
        elif sidecar:
            frames.append(Frame(p, sidecar[p.name], SIDECAR, meta))
        else:
            frames.append(Frame(p, meta.focus_m, meta.focus_source, meta))
        for note in meta.notes:
            warnings.append(f"{p}: {note}")
    for fr in frames:
        if fr.focus_m is None:
            asked = "EXIF, maker notes, XMP" + (", exiftool" if use_exiftool and exiftool.available() else "")
            why = "".join(f"; {n}" for n in fr.meta.notes)  # e.g. an encrypted Nikon LensData
            raise CaptureError(f"{fr.path}: no focus distance in its metadata ({asked}{why}); "
                               f"give it in {folder / SIDECAR} or with aat-infer --focus-m")
        if not math.isfinite(fr.focus_m) or fr.focus_m <= 0:
            raise CaptureError(f"{fr.path}: focus distance {fr.focus_m} m ({fr.focus_source}) is not usable "
                               f"(infinite or not positive); give it in {folder / SIDECAR}")
    seen: dict[float, Path] = {}
    for fr in frames:
        key = round(fr.focus_m, 6)
        if key in seen and equal_focus_ok:
            warnings.append(f"{fr.path}: focus distance {fr.focus_m:g} m equals {seen[key].name}'s "
                            "(coarse metadata?): placed from the images")
            continue
        if key in seen:
            raise CaptureError(f"{fr.path}: duplicate focus distance {fr.focus_m:g} m (same as {seen[key].name})")
        seen[key] = fr.path
    cap = Capture(folder, frames, warnings=warnings)
    for name, attr in zip(GT_NAMES, ("gt_depth_m", "gt_depth_mm", "gt_aif")):
        if (folder / name).is_file():
            setattr(cap, attr, folder / name)
    return cap
