"""The output-folder guard every command that writes runs before any work.

An output folder may be replaced as a whole (`--force`), so it must never be, contain or lie inside an input
(paths resolved, symlinks followed), never be the current folder or one of its parents, and, when it exists,
only be replaced if it is empty or provably an earlier output of the same tool: its marker (aat_deploy.io.marker)
names the tool and lists every entry in it. A mount point is never replaced (it cannot be renamed).
Its location must be writable. Each refusal is one OutputError line naming the folder and the reason.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

from ..errors import OutputError
from . import marker


def resolved(path: str | Path) -> Path:
    """Absolute path with every existing symlink followed (missing tails kept as written)."""
    return Path(os.path.abspath(path)).resolve()


def _under(child: Path, parent: Path) -> bool:
    return parent in child.parents


def check_no_overlap(out: str | Path, inputs: Iterable[str | Path], nest_ok: Iterable[str | Path] = ()) -> None:
    """OutputError if `out` is an input, contains one, or lies inside an input folder. Inputs in `nest_ok`
    (e.g. aat-eval's ROOT, whose outputs are skipped when searching it) may hold the output, not be it or be
    inside it."""
    o = resolved(out)
    allowed = {resolved(p) for p in nest_ok}
    for inp in inputs:
        i = resolved(inp)
        if o == i:
            raise OutputError(f"{out}: is the input {inp}; choose another output folder")
        if _under(i, o):
            raise OutputError(f"{out}: contains the input {inp}; choose another output folder")
        if _under(o, i) and i not in allowed:
            raise OutputError(f"{out}: lies inside the input {inp}; choose an output folder outside it")


def check_not_cwd(out: str | Path) -> None:
    """OutputError if `out` is the current folder or one of its parents (it would be replaced while in use)."""
    o, cwd = resolved(out), Path.cwd().resolve()
    if o == cwd or _under(cwd, o):
        raise OutputError(f"{out}: is the current folder{'' if o == cwd else ' or contains it'}; "
                          "choose another output folder")


def check_writable(out: str | Path) -> None:
    """OutputError unless a folder can be created where `out` goes (tried with a temporary folder in its
    nearest existing parent, which also catches read-only file systems and root-owned places)."""
    parent = Path(os.path.abspath(out)).parent
    while not os.path.lexists(parent) and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{out}: cannot be created ({parent} is not a folder)")
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".aat-write-test-", dir=parent))
    except OSError as e:
        raise OutputError(f"{out}: not writable ({parent}: {e.strerror or e})") from None


def check_output_dir(out: str | Path, inputs: Iterable[str | Path], force: bool, *, tool: str,
                     nest_ok: Iterable[str | Path] = ()) -> None:
    """Everything a command checks before it starts work on an output folder it will write (and, with force,
    replace): no overlap with the inputs, not the current folder, exists only with force (and then only an empty
    folder or an earlier output of `tool` with nothing else in it, not a mount point), writable location."""
    out = Path(out)
    check_no_overlap(out, inputs, nest_ok)
    check_not_cwd(out)
    if os.path.lexists(out):
        if not out.is_dir():
            raise OutputError(f"{out}: exists and is not a folder")
        if not force:
            raise OutputError(f"{out}: output folder exists (pass --force to overwrite)")
        if os.path.ismount(out):
            raise OutputError(f"{out}: is a mount point, which cannot be replaced; choose a folder inside it")
        why = marker.refusal(out, tool)
        if why is not None:
            raise OutputError(why)
    check_writable(out)


def check_output_files(outs: Iterable[str | Path], inputs: Iterable[str | Path]) -> None:
    """For commands that write single files: none of them may be an input; each one's folder must be writable."""
    ins = {resolved(p): p for p in inputs}
    for o in outs:
        if resolved(o) in ins:
            raise OutputError(f"{o}: is the input {ins[resolved(o)]}; choose another output name")
        if os.path.lexists(o) and Path(o).is_dir():
            raise OutputError(f"{o}: is a folder, expected a file name")
        check_writable(o)
