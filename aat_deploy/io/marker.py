"""The marker that makes an output folder provably ours, so `--force` can never delete a user's files.

Every output folder written by `atomic_folder` holds `.aat-output.json`: the tool that wrote it and its content
list, every entry below the folder (relative POSIX path → size in bytes, "dir" or "link"). An existing folder may
be replaced only when it is empty, or its marker names the same tool and every entry in it is in the list with the
same kind and size: a file a user dropped in, or changed since, keeps the whole folder. A folder holding only a
file with one of our output names (summary.json ...) is not ours.

The temporary folder of a run in progress holds a marker with `"complete": false` from its first moment, so
leftovers of killed runs can be told from a user's folder that happens to have a similar name (atomic.clean_stale).
"""

from __future__ import annotations

import json
import os
import socket
import stat
from pathlib import Path

MARKER = ".aat-output.json"
FORMAT = "aat-output/1"
MARKER_SINCE = "2026-11-25"  # outputs written before this carry no marker, so --force refuses them


def entries(folder: Path) -> dict[str, int | str]:
    """Every entry below `folder` (symlinks not followed), the marker excepted: relative path → size in bytes
    (regular files), "dir", "link" or "other"."""
    folder = Path(folder)
    out: dict[str, int | str] = {}
    for cur, dirs, files in os.walk(folder, onerror=_raise):
        for name in dirs + files:
            p = Path(cur) / name
            rel = p.relative_to(folder).as_posix()
            if rel == MARKER:
                continue
            st = os.lstat(p)
            out[rel] = (st.st_size if stat.S_ISREG(st.st_mode) else "dir" if stat.S_ISDIR(st.st_mode)
                        else "link" if stat.S_ISLNK(st.st_mode) else "other")
    return out


def _raise(e: OSError) -> None:
    raise e


def write(folder: Path, tool: str, complete: bool) -> None:
    """Write folder's marker: the tool, and when complete the content list of what is in the folder now."""
    from .. import __version__

    doc = {"format": FORMAT, "tool": tool, "version": __version__, "complete": complete, "host": socket.gethostname(),
           "entries": entries(folder) if complete else {}}
    (Path(folder) / MARKER).write_text(json.dumps(doc, indent=0, sort_keys=True) + "\n")


def read(folder: Path) -> dict | None:
    """The marker of `folder` (a dict with tool, complete, entries), or None if it has none or a damaged one."""
    p = Path(folder) / MARKER
    try:
        if p.is_symlink() or not p.is_file():
            return None
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    if (not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("tool"), str)
            or not isinstance(doc.get("entries"), dict)):
        return None
    return doc


def replace_problem(folder: Path, tool: str) -> str | None:
    """Why the existing folder may not be replaced by `tool`'s output, or None if it may (empty, or an earlier
    complete output of `tool` holding nothing else)."""
    folder = Path(folder)
    try:
        if not any(folder.iterdir()):
            return None
        on_disk = entries(folder)
    except OSError as e:
        return f"cannot be read ({e.strerror or e})"
    doc = read(folder)
    if doc is None:
        return (f"is not an earlier {tool} output (no {MARKER}; outputs written before {MARKER_SINCE} have none)"
                if not os.path.lexists(folder / MARKER)
                else f"is not an earlier {tool} output (its {MARKER} is damaged)")
    if doc["tool"] != tool:
        return f"is an output of {doc['tool']}, not of {tool}"
    if doc.get("complete") is not True:
        return f"is an unfinished {tool} output of a run that may still be going"
    listed = doc["entries"]
    unknown = sorted(rel for rel in on_disk if rel not in listed)
    if unknown:
        more = f" and {len(unknown) - 1} more" if len(unknown) > 1 else ""
        return f"holds {unknown[0]!r}{more}, which {tool} did not write"
    changed = sorted(rel for rel, kind in on_disk.items() if listed[rel] != kind)
    if changed:
        more = f" and {len(changed) - 1} more" if len(changed) > 1 else ""
        return f"{changed[0]!r}{more} changed since {tool} wrote it"
    return None


def refusal(out: Path, tool: str, folder: Path | None = None) -> str | None:
    """The one-line refusal of `--force` over the existing output folder `out` (checked at `folder`, where it was
    moved aside, if given), or None if `tool` may replace it. It names the folder, why, and what to do; a folder
    without a marker (also an output written before MARKER_SINCE) is never replaced on a guess."""
    why = replace_problem(Path(out if folder is None else folder), tool)
    if why is None:
        return None
    return (f"{out}: {why}; --force replaces only a folder proven to be an earlier {tool} output, so nothing was "
            "deleted: choose another output folder, or rename this one and run again")


def written_here(doc: dict) -> bool:
    """True if the marker `doc` was written on this host (or is older than the host field): a process id in a name
    says something only on the host whose process it was (a shared or network folder has other hosts' runs)."""
    return doc.get("host") in (None, socket.gethostname())


def is_ours(folder: Path) -> bool:
    """True if `folder` (a real folder, not a link) carries any aat marker, finished or not."""
    folder = Path(folder)
    return folder.is_dir() and not folder.is_symlink() and read(folder) is not None
