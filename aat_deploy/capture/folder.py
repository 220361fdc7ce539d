"""A capture folder: its frame files, each frame's focus distance (sidecar > EXIF/maker notes > exiftool),
optional ground truth, and the validation that turns a bad folder into a one-line error.

Layout (docs/contracts.md, "Capture folder"): frames in any RAW/TIFF/PNG/JPEG format, one per focus distance;
optional `capture.json` = {"frames": [{"file": "f0.dng", "focus_m": 0.5}, ...]} which overrides metadata
(when it lists frames, exactly those files are the capture; names are relative paths inside the folder, no
".." or absolute paths); optional `gt_depth_m.npy`, `gt_depth_mm.png`,
`gt_aif.png`. `virtual_camera.json` is never read here (real captures do not have it).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import CaptureError
from ..io.files import check_inside, file_kind, load_json, member_path, read_input_bytes
from . import exiftool
from .exif import FrameMeta, read_metadata
from .imagefile import FRAME_EXTENSIONS, frame_header

SIDECAR = "capture.json"
GT_NAMES = ("gt_depth_m.npy", "gt_depth_mm.png", "gt_aif.png")
MAX_FOCUS_M = 1000.0  # a reported focus distance beyond 1 km is a decoding error, not a focus position


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


def _is_frame_name(name: str) -> bool:
    return Path(name).suffix.lower() in FRAME_EXTENSIONS and not name.startswith((".", "gt_"))


def frame_files(folder: Path) -> list[Path]:
    """Frame files in a folder, by name (ground-truth images and hidden files excluded)."""
    return sorted(p for p in folder.iterdir() if _is_frame_name(p.name) and file_kind(p) is None)


def odd_frame_files(folder: Path) -> list[str]:
    """Entries named like frames that are not regular files: dangling symlinks, FIFOs, devices, folders."""
    return [f"{p.name} ({kind})" for p in sorted(folder.iterdir())
            if _is_frame_name(p.name) and (kind := file_kind(p)) is not None]


def focus_problem(focus_m: object) -> str | None:
    """Why a focus distance (metres) is not physical, or None: it must be a finite number in (0, MAX_FOCUS_M]."""
    if not isinstance(focus_m, (int, float)) or isinstance(focus_m, bool):
        return f"not a number ({focus_m!r})"
    try:
        f = float(focus_m)
    except OverflowError:
        return "too large"
    if math.isnan(f):
        return "NaN"
    if f <= 0:
        return "not positive"
    if math.isinf(f):
        return "infinite"
    if f > MAX_FOCUS_M:
        return f"beyond {MAX_FOCUS_M:g} m, not a focus distance"
    return None


def _sidecar(folder: Path, allow_outside_links: bool = False) -> dict[str, float] | None:
    """capture.json's frames as {name as written: focus_m}; names are confined to the folder."""
    path = folder / SIDECAR
    if not os.path.lexists(path):
        return None
    check_inside(folder, path, allow_outside_links)
    kind = file_kind(path)
    if kind is not None:
        raise CaptureError(f"{path}: {kind}, not a readable file")
    data = load_json(path)
    frames = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(frames, list):
        raise CaptureError(f'{path}: expected {{"frames": [{{"file": ..., "focus_m": ...}}, ...]}}')
    out: dict[str, float] = {}
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or not isinstance(fr.get("file"), str):
            raise CaptureError(f"{path}: frames[{i}] needs a string 'file'")
        name = fr["file"]
        if member_path(folder, name) is None:
            raise CaptureError(f"{path}: frames[{i}] file {name!r} is not inside the capture folder "
                               "(relative names only, no '..')")
        f = fr.get("focus_m")
        why = focus_problem(f)
        if why is not None:
            raise CaptureError(f"{path}: frames[{i}] ({name!r}) needs focus_m > 0 in metres, "
                               f"at most {MAX_FOCUS_M:g}, got {f!r}")
        if name in out:
            raise CaptureError(f"{path}: {name!r} listed twice")
        out[name] = float(f)
    return out


def read_capture(folder: str | Path, use_exiftool: bool = True, focus_m: list[float] | None = None,
                 equal_focus_ok: bool = False, max_megapixels: float | None = None,
                 allow_outside_links: bool = False) -> Capture:
    """Read and validate a capture folder's frame list and focus distances (pixels are not decoded here, but each
    frame's kind and size are read from its header: unknown content or a size beyond the pixel limit is refused).

    focus_m: the frames' focus distances (m, `aat-infer --focus-m`) in file-name order, overriding metadata and
    capture.json (as many as there are frames). equal_focus_ok: frames with equal focus distances are a warning
    (the caller places them), not an error. max_megapixels: the pixel limit (aat_deploy.capture.imagefile).
    allow_outside_links: follow symlinks that lead out of the folder (refused by default, before anything is read
    through them). The same file listed twice (a hard link or symlink) is refused."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: not a folder")
    try:
        return _read_capture(folder, use_exiftool, focus_m, equal_focus_ok, max_megapixels, allow_outside_links)
    except OSError as e:  # e.g. a folder that cannot be listed
        raise CaptureError(f"{e.filename or folder}: cannot read ({e.strerror or e})") from None


def _same_files(files: list[Path]) -> None:
    """CaptureError if two frame files are one file on disk (a hard link, or a symlink inside the folder)."""
    seen: dict[tuple[int, int], Path] = {}
    for p in files:
        st = os.stat(p)
        key = (st.st_dev, st.st_ino)
        if key in seen:
            raise CaptureError(f"{p}: the same file as {seen[key].name} (a link); a focal stack needs a distinct "
                               "frame per focus distance")
        seen[key] = p


def _read_capture(folder: Path, use_exiftool: bool, focus_m: list[float] | None, equal_focus_ok: bool,
                  max_megapixels: float | None, allow_outside_links: bool) -> Capture:
    sidecar = _sidecar(folder, allow_outside_links)
    warnings: list[str] = []
    odd = odd_frame_files(folder)
    if sidecar:
        files, names = [], {}
        for name in sidecar:
            p = member_path(folder, name)
            if p in names:
                raise CaptureError(f"{folder / SIDECAR}: {name!r} names the same file as {names[p]!r}")
            kind = file_kind(p)
            if kind is not None:
                raise CaptureError(f"{folder / SIDECAR}: lists {name}, which is {kind}"
                                   if kind != "missing" else f"{folder / SIDECAR}: lists {name}, which does not exist")
            files.append(p)
            names[p] = name
        others = [p.name for p in frame_files(folder) if p.name not in sidecar]
        if others:
            warnings.append(f"{folder}: {len(others)} frame file(s) not listed in {SIDECAR} ignored: "
                            + ", ".join(others[:5]))
    else:
        files = frame_files(folder)
        if odd:
            warnings.append(f"{folder}: skipped, not regular files: " + ", ".join(odd[:5]))
    if not files:
        raise CaptureError(f"{folder}: empty capture folder (no RAW, TIFF, PNG or JPEG frames"
                           + (f"; not regular files: {', '.join(odd[:5])}" if odd else "") + ")")
    if len(files) < 2:
        raise CaptureError(f"{folder}: only one frame ({files[0].name}); a focal stack needs at least two"
                           + (f" (not regular files: {', '.join(odd[:5])})" if odd else ""))
    if focus_m is not None and len(focus_m) != len(files):
        raise CaptureError(f"{folder}: --focus-m gives {len(focus_m)} focus distances for {len(files)} frames")
    if focus_m is not None and sidecar:
        warnings.append(f"{folder}: --focus-m overrides the focus distances in {SIDECAR}")
    for p in files:  # before anything is read through them
        check_inside(folder, p, allow_outside_links)
    _same_files(files)
    frames = []
    # exiftool is the focus distance's fallback (one process per frame, ~0.2 s each): not run when capture.json or
    # --focus-m gives the distances (camera fields then come from the built-in EXIF reader alone)
    ask_exiftool = use_exiftool and focus_m is None and not sidecar
    for i, p in enumerate(files):
        buf = read_input_bytes(p)
        frame_header(p, buf, max_megapixels)  # unknown content, or a size beyond the pixel limit: refused here
        meta = read_metadata(p, use_exiftool=ask_exiftool, buf=buf)
        del buf
        if focus_m is not None:
            frames.append(Frame(p, float(focus_m[i]), "--focus-m", meta))
        elif sidecar:
            frames.append(Frame(p, sidecar[names[p]], SIDECAR, meta))
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
        why = focus_problem(fr.focus_m)
        if why is not None:
            raise CaptureError(f"{fr.path}: focus distance {fr.focus_m:g} m ({fr.focus_source}) is not usable "
                               f"({why}); give it in {folder / SIDECAR}")
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
            check_inside(folder, folder / name, allow_outside_links)
            setattr(cap, attr, folder / name)
    return cap
