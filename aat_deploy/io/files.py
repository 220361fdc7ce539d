"""Reading users' files safely: what a path is without opening it (`file_kind`), a frame file's bytes, a user's
JSON, paths named inside a folder that stay inside it, and links out of a capture folder (refused unless allowed).
Each failure is the caller's one-line error naming the file (`aat_deploy.errors`)."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path, PurePosixPath, PureWindowsPath

from ..errors import CaptureError


def read_input_bytes(path: Path) -> bytes:
    """A frame file's bytes; CaptureError naming the file if it cannot be read, is empty or is not a regular
    file (a FIFO is never opened: it would block)."""
    kind = file_kind(Path(path))
    if kind is not None:
        raise CaptureError(f"{path}: {kind}, not a readable file")
    try:
        buf = Path(path).read_bytes()
    except OSError as e:
        raise CaptureError(f"{path}: cannot read ({e.strerror or e})") from None
    if not buf:
        raise CaptureError(f"{path}: empty file")
    return buf


def load_json(path: Path, error: type[CaptureError] = CaptureError):
    """A user's JSON file (UTF-8) as Python objects; `error` naming the file for anything unreadable, including
    nesting too deep for the parser and integers too long to convert."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8-sig"))  # a BOM (Windows editors) is no error
    except OSError as e:
        raise error(f"{path}: cannot read ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not UTF-8 text") from None
    except RecursionError:
        raise error(f"{path}: not valid JSON (nested too deeply)") from None
    except ValueError as e:  # JSONDecodeError, and int() limits on huge numbers
        raise error(f"{path}: not valid JSON ({str(e).splitlines()[0][:120]})") from None


def member_path(folder: Path, name: object) -> Path | None:
    """folder/name if `name` is a relative path that stays inside `folder` (no absolute path, no "..", no NUL),
    else None. Decided on the text alone, so nothing outside the folder is read before refusing."""
    if not isinstance(name, str) or not name or "\0" in name:
        return None
    p = PurePosixPath(name.replace("\\", "/"))
    if p.is_absolute() or ".." in p.parts or PureWindowsPath(name).drive:
        return None
    return Path(folder) / p


OUTSIDE_LINKS_FLAG = "--allow-outside-links"


def outside_target(folder: Path, path: Path) -> str | None:
    """Where `path` really leads (symlinks resolved) if that is outside `folder`, else None."""
    real, base = os.path.realpath(path), os.path.realpath(folder)
    return None if real == base or real.startswith(base.rstrip(os.sep) + os.sep) else real


def check_inside(folder: Path, path: Path, allow_outside: bool = False, error: type[CaptureError] = CaptureError,
                 ) -> None:
    """`error` naming `path` if a symlink (of it or of a folder on its way) leads out of `folder`, unless allowed:
    a capture folder's files must be its own (`ln -s /etc/shadow cap/frame_07.dng` is never parsed)."""
    if allow_outside:
        return
    real = outside_target(folder, path)
    if real is not None:
        raise error(f"{path}: a link out of the folder (to {real}); not followed "
                    f"(pass {OUTSIDE_LINKS_FLAG} to use it)")


def file_kind(path: Path) -> str | None:
    """Why `path` is not a readable regular file ("missing", "a dangling symlink", "a folder", "a FIFO",
    "a device", "a socket"), or None if it is one. Never opens the file (a FIFO would block)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "a dangling symlink" if os.path.islink(path) else "missing"
    except OSError as e:
        return f"not accessible ({e.strerror or e})"
    mode = st.st_mode
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"
