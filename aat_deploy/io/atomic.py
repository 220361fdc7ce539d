"""Outputs written whole or not at all: the one place files and folders are written atomically.

Files: `atomic_file(path)` yields a hidden temporary sibling `.NAME.tmp-PID-N-TAG.SUFFIX` (the suffix kept, so
writers that pick the format by extension or add one, as cv2.imwrite, savefig and np.savez do, write the file as
asked; TAG is a hash of the host, NAME, PID and N, so a file of that name is provably one of ours, written on this
host, not a user's file of a similar name); when the block ends it replaces `path` with one rename, on an exception
it is deleted and `path` is left as it was. `atomic_files` does the same for files that belong together;
`write_text_atomic` / `write_bytes_atomic` for text and bytes.

Folders: a folder is filled under a hidden temporary sibling `.NAME.tmp-PID` and renamed into place, carrying
the marker of its tool and its content list (aat_deploy.io.marker); an existing folder (replaced only with force, and
only when its marker proves it is an earlier output of the same tool with nothing else in it) is first moved aside to
`.NAME.old-PID`, checked again, then deleted. A run interrupted by SIGINT/SIGTERM deletes its temporary folder and
commits nothing, also when the signal's exception was discarded by a finalizer (aat_deploy.interrupt); one
killed outright leaves it behind, and the next run writing into the same parent folder deletes the marked hidden
siblings whose process is gone (never a folder without our marker).

Stale temporaries (clean_stale): the first write of a process into a folder deletes the temporaries there of
processes of this host that are gone (SIGKILL, power cut): folders with our marker, files whose name carries our
tag. Nothing else is touched: not a symlink, not a name without a valid tag, not a live process's temporary, not
another host's (a shared folder).
"""

from __future__ import annotations

import errno
import hashlib
import itertools
import os
import re
import shutil
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError
from ..interrupt import raise_if_interrupted
from . import marker

_SHORT_WRITE = re.compile(r"(\d+) requested and (\d+) written")  # numpy's tofile/save on a full disk (no errno)
_SIBLING = re.compile(r"^\.(?P<name>.+)\.(?:tmp|old)-(?P<pid>\d+)$")
_TEMP_FILE = re.compile(r"^\.(?P<name>.+)\.tmp-(?P<pid>\d+)-(?P<n>\d+)-(?P<tag>[0-9a-f]{8})(?P<suffix>.*)$")
_COUNTER = itertools.count()  # temporary files of one process (threads too) never share a name
_SWEPT: set[tuple[int, str]] = set()  # (pid, folder) already swept by this process: once per folder is enough
_SWEPT_LOCK = threading.Lock()


def write_error(folder: str | Path, e: OSError) -> OutputError:
    """One line naming the output folder for an OSError while it was written; a full disk is said so, also when
    numpy reports it only as a short write ("614400 requested and 524256 written", no errno)."""
    short = _SHORT_WRITE.search(str(e))
    if e.errno in (errno.ENOSPC, errno.EDQUOT) or short:
        why = "no space left on the device" + (f" ({short[1]} bytes to write, {short[2]} written)" if short else "")
    else:
        why = e.strerror or (str(e).splitlines()[0][:160] if str(e) else type(e).__name__)
    return OutputError(f"{folder}: could not write the outputs ({why}); nothing was left there")


@contextmanager
def writing(folder: str | Path) -> Iterator[None]:
    """Turn an OSError of the block into write_error(folder, e): put outside atomic_folder, so the temporary folder
    is gone before the one line is reported.

        with writing(out), atomic_folder(out, force, "aat-infer") as tmp:
            ...
    """
    try:
        yield
    except OSError as e:
        raise write_error(folder, e) from None


def _tag(name: str, pid: int, n: int, host: str | None = None) -> str:
    """The 8 hex digits that prove `.NAME.tmp-PID-N-TAG.SUFFIX` was named by temp_file on this host (host: another
    one's): a process id only says something on the host of its process, so other hosts' temporaries in a shared
    folder never match and are never swept here."""
    host = socket.gethostname() if host is None else host
    return hashlib.sha256(f"aat-temporary:{host}:{name}:{pid}:{n}".encode("utf-8", "surrogateescape")).hexdigest()[:8]


def temp_file(path: str | Path) -> Path:
    """A hidden temporary sibling of the file `path` that keeps its suffix: `.NAME.tmp-PID-N-TAG.SUFFIX`."""
    path = Path(path)
    pid, n = os.getpid(), next(_COUNTER)
    return path.with_name(f".{path.name}.tmp-{pid}-{n}-{_tag(path.name, pid, n)}{path.suffix}")


def temp_file_pid(name: str) -> int | None:
    """The process id in a file name made by temp_file, or None if the name is not one (tag or suffix wrong)."""
    m = _TEMP_FILE.match(name)
    if not m or m["suffix"] != Path(m["name"]).suffix or m["tag"] != _tag(m["name"], int(m["pid"]), int(m["n"])):
        return None
    return int(m["pid"])


@contextmanager
def atomic_files(*paths: str | Path) -> Iterator[list[Path]]:
    """Yield a temporary sibling for each of `paths` (temp_file); when the block ends without an exception each
    replaces its path (in the order given), otherwise they are deleted and the paths are left as they were. A
    temporary file the block did not write is skipped (optional outputs).

        with atomic_files(depth_png, mask_png) as (tmp_depth, tmp_mask):
            ...
    """
    tmps = [temp_file(p) for p in paths]
    for folder in {t.parent for t in tmps}:
        _sweep_once(folder)
    try:
        yield tmps
        raise_if_interrupted()  # a signal whose exception a finalizer discarded: commit nothing
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
    """Delete the stale temporaries beside out_dir (in its parent folder), returning what was deleted: the hidden
    `.X.tmp-PID` / `.X.old-PID` folders whose process is gone and that carry our marker (a temporary folder of a
    killed run; an earlier output moved aside, only if it still holds nothing but what its tool wrote), and the
    files `.X.tmp-PID-N-TAG.S` whose process is gone and whose TAG proves temp_file named them (a file being
    written when its process was killed). Symlinks, unmarked folders and untagged files are never touched."""
    return sweep_folder(Path(out_dir).parent)


def sweep_folder(parent: Path) -> list[Path]:
    """Delete the stale temporaries of dead processes directly in `parent` (see clean_stale); the list deleted."""
    removed: list[Path] = []
    try:
        entries = list(Path(parent).iterdir())
    except OSError:
        return removed
    for p in entries:
        m = _SIBLING.match(p.name)
        file_pid = None if m else temp_file_pid(p.name)
        if file_pid is not None:  # a file temporary: a regular file (never a link or folder) of a dead process
            if file_pid != os.getpid() and not pid_alive(file_pid) and p.is_file() and not p.is_symlink():
                try:
                    p.unlink()
                    removed.append(p)
                except OSError:
                    pass
            continue
        if not m or int(m["pid"]) == os.getpid() or pid_alive(int(m["pid"])) or not marker.is_ours(p):
            continue
        if not marker.written_here(marker.read(p)):  # another host's run in a shared folder: its pid means nothing here
            continue
        if ".old-" in p.name and marker.replace_problem(p, marker.read(p)["tool"]) is not None:
            continue
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed


def _sweep_once(folder: Path) -> None:
    """sweep_folder(folder) the first time this process writes a file there (a process killed later is swept by
    the next run, so once is enough; a fork gets its own pass)."""
    key = (os.getpid(), os.path.abspath(folder))
    with _SWEPT_LOCK:
        if key in _SWEPT:
            return
        _SWEPT.add(key)
    sweep_folder(folder)


def replace_folder(tmp: Path, out_dir: Path, force: bool, tool: str) -> None:
    """Move the finished folder `tmp` to out_dir; an existing out_dir is replaced only with force and only if it is
    an earlier output of `tool` holding nothing else (marker.replace_problem, checked again once it is moved aside,
    so nothing added while this run worked is lost): moved aside, swapped, then deleted; put back on any failure,
    a signal included (Ctrl-C while it is aside: else the next run's sweep would delete it as a stale `.old-PID`)."""
    old = None
    if os.path.lexists(out_dir) and not force:
        raise OutputError(f"{out_dir}: output folder exists (pass --force to overwrite)")
    try:
        if os.path.lexists(out_dir):
            old = temp_sibling(out_dir, "old")
            os.replace(out_dir, old)
            why = None if old.is_symlink() else marker.refusal(out_dir, tool, old)
            if why is not None:
                raise OutputError(why)
        os.replace(tmp, out_dir)
    except BaseException:
        if old is not None and os.path.lexists(old) and not os.path.lexists(out_dir):
            os.replace(old, out_dir)
        raise
    if old is not None:
        if old.is_symlink():
            old.unlink()
        else:
            shutil.rmtree(old, ignore_errors=True)


@contextmanager
def atomic_folder(out_dir: str | Path, force: bool, tool: str) -> Iterator[Path]:
    """Yield an empty temporary folder beside out_dir (marked as `tool`'s unfinished output); when the block ends
    without an exception the marker gets the content list and the folder becomes out_dir (see replace_folder),
    otherwise (including SIGINT/SIGTERM, which the commands raise as exceptions) it is deleted and out_dir is left
    as it was.

        with atomic_folder(out, force, "aat-infer") as tmp:
            (tmp / "a.json").write_text(...)
    """
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    clean_stale(out_dir)
    tmp = temp_sibling(out_dir)
    if tmp.is_dir() and not tmp.is_symlink() and marker.is_ours(tmp):  # left by an earlier call in this process
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        marker.write(tmp, tool, complete=False)
        yield tmp
        raise_if_interrupted()  # a signal whose exception a finalizer discarded: commit nothing
        marker.write(tmp, tool, complete=True)
        replace_folder(tmp, out_dir, force, tool)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
