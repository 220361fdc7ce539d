"""Outputs written whole or not at all: the one place files and folders are written atomically.

Files: `atomic_file(path)` yields a hidden temporary sibling `.NAME.tmp-PID-N.SUFFIX` (the suffix kept, so writers
that pick the format by extension or add one, as cv2.imwrite, savefig and np.savez do, write the file as asked);
when the block ends it replaces `path` with one rename, on an exception it is deleted and `path` is left as it
was. `atomic_files` does the same for files that belong together; `write_text_atomic` / `write_bytes_atomic` for
text and bytes.

Folders: a folder is filled under a hidden temporary sibling `.NAME.tmp-PID` and renamed into place; an existing
folder (replaced only with force) is first moved aside to `.NAME.old-PID`, then deleted. A run killed half-way
leaves such hidden siblings behind: the next run for the same NAME deletes those whose process is gone.
"""

from __future__ import annotations

import itertools
import os
import re
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError

_SIBLING = re.compile(r"^\.(?P<name>.+)\.(?:tmp|old)-(?P<pid>\d+)$")
_COUNTER = itertools.count()  # temporary files of one process (threads too) never share a name


def temp_file(path: str | Path) -> Path:
    """A hidden temporary sibling of the file `path` that keeps its suffix: `.NAME.tmp-PID-N.SUFFIX`."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp-{os.getpid()}-{next(_COUNTER)}{path.suffix}")


@contextmanager
def atomic_files(*paths: str | Path) -> Iterator[list[Path]]:
    """Yield a temporary sibling for each of `paths` (temp_file); when the block ends without an exception each
    replaces its path (in the order given), otherwise they are deleted and the paths are left as they were. A
    temporary file the block did not write is skipped (optional outputs).

        with atomic_files(depth_png, mask_png) as (tmp_depth, tmp_mask):
            ...
    """
    tmps = [temp_file(p) for p in paths]
    try:
        yield tmps
        for tmp, path in zip(tmps, paths):
            if os.path.lexists(tmp):
                os.replace(tmp, path)
    finally:
        for tmp in tmps:
            if os.path.lexists(tmp):
                tmp.unlink()


@contextmanager
def atomic_file(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling of `path` to write; it replaces `path` when the block ends without an exception
    (one rename: readers see the old file or the new one, never half of one), else it is deleted.

        with atomic_file(out_png) as tmp:
            fig.savefig(tmp)
    """
    with atomic_files(path) as (tmp,):
        yield tmp


def write_bytes_atomic(path: str | Path, data: bytes, fsync: bool = False) -> None:
    """Write `data` to `path` atomically; fsync: flush it to the disk before the rename (survives a power cut)."""
    with atomic_file(path) as tmp, open(tmp, "wb") as f:
        f.write(data)
        if fsync:
            f.flush()
            os.fsync(f.fileno())


def write_text_atomic(path: str | Path, text: str, encoding: str = "utf-8") -> None:
    """Write `text` to `path` atomically."""
    write_bytes_atomic(path, text.encode(encoding))


def temp_sibling(out_dir: Path, kind: str = "tmp", pid: int | None = None) -> Path:
    """The hidden sibling `.NAME.<kind>-PID` of out_dir (kind: "tmp" or "old")."""
    out_dir = Path(out_dir)
    return out_dir.parent / f".{out_dir.name}.{kind}-{os.getpid() if pid is None else pid}"


def pid_alive(pid: int) -> bool:
    """True if a process with this id exists (whoever owns it)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    except OverflowError:
        return False
    return True


def clean_stale(out_dir: Path) -> list[Path]:
    """Delete the `.NAME.tmp-PID` / `.NAME.old-PID` folders next to out_dir left by processes that are gone
    (only for out_dir's NAME; symlinks and files are never touched). Returns what was deleted."""
    out_dir = Path(out_dir)
    parent = out_dir.parent
    removed: list[Path] = []
    try:
        entries = list(parent.iterdir())
    except OSError:
        return removed
    for p in entries:
        m = _SIBLING.match(p.name)
        if (m and m["name"] == out_dir.name and int(m["pid"]) != os.getpid() and not pid_alive(int(m["pid"]))
                and p.is_dir() and not p.is_symlink()):
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
    return removed


def replace_folder(tmp: Path, out_dir: Path, force: bool) -> None:
    """Move the finished folder `tmp` to out_dir; an existing out_dir is replaced only with force (moved aside,
    swapped, then deleted; put back if the swap fails)."""
    old = None
    if os.path.lexists(out_dir):
        if not force:
            raise OutputError(f"{out_dir}: output folder exists (pass --force to overwrite)")
        old = temp_sibling(out_dir, "old")
        os.replace(out_dir, old)
    try:
        os.replace(tmp, out_dir)
    except BaseException:
        if old is not None:
            os.replace(old, out_dir)
        raise
    if old is not None:
        if old.is_symlink():
            old.unlink()
        else:
            shutil.rmtree(old, ignore_errors=True)


@contextmanager
def atomic_folder(out_dir: str | Path, force: bool) -> Iterator[Path]:
    """Yield an empty temporary folder beside out_dir; when the block ends without an exception it becomes
    out_dir (see replace_folder), otherwise it is deleted and out_dir is left as it was.

        with atomic_folder(out, force) as tmp:
            (tmp / "a.json").write_text(...)
    """
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    clean_stale(out_dir)
    tmp = temp_sibling(out_dir)
    if tmp.is_dir() and not tmp.is_symlink():  # left by an earlier call in this very process
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        yield tmp
        replace_folder(tmp, out_dir, force)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
