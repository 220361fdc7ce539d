"""The one atomic-write helper (aat_deploy.io.atomic) for files: whole or nothing, temporaries that keep the
suffix, unique per process and thread, normal permissions; temporaries of killed processes swept, nothing else."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from aat_deploy.io import atomic
from aat_deploy.io.atomic import atomic_file, atomic_files, temp_file, write_bytes_atomic, write_text_atomic


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


def test_write_replaces_whole_and_leaves_nothing_behind(tmp_path):
    p = tmp_path / "a.json"
    write_text_atomic(p, "old\n")
    write_text_atomic(p, "new\n")
    write_bytes_atomic(tmp_path / "b.bin", b"\x00\x01", fsync=True)
    assert p.read_text() == "new\n" and (tmp_path / "b.bin").read_bytes() == b"\x00\x01"
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.json", "b.bin"]
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~_umask()  # as open() makes it (mkstemp would be 0600)


def test_failure_keeps_the_old_file(tmp_path):
    p = tmp_path / "model.onnx"
    p.write_text("old")
    with pytest.raises(RuntimeError, match="parity"):
        with atomic_file(p) as tmp:
            tmp.write_text("half")
            raise RuntimeError("parity check failed")
    assert p.read_text() == "old" and [q.name for q in tmp_path.iterdir()] == ["model.onnx"]


def test_temporaries_keep_the_suffix_for_writers_that_add_one(tmp_path):
    """np.savez appends .npz to a name without it: the temporary ends in the target's suffix."""
    f = tmp_path / "000001.npz"
    with atomic_file(f) as tmp:
        assert tmp.suffix == ".npz" and tmp.name.startswith(".000001.npz.tmp-") and tmp.parent == tmp_path
        np.savez(tmp, x=np.arange(3))
    with np.load(f) as z:
        assert z["x"].tolist() == [0, 1, 2]
    assert [q.name for q in tmp_path.iterdir()] == ["000001.npz"]


def test_several_files_all_or_none_and_optional_ones(tmp_path):
    a, b, c = tmp_path / "gt.npy", tmp_path / "gt.png", tmp_path / "gt.json"
    with pytest.raises(OSError):
        with atomic_files(a, b) as (ta, tb):
            np.save(ta, np.zeros(2))
            raise OSError("could not write PNG")
    assert list(tmp_path.iterdir()) == []
    with atomic_files(a, c) as (ta, tc):  # c not written (an optional output): skipped
        np.save(ta, np.ones(2))
    assert [q.name for q in tmp_path.iterdir()] == ["gt.npy"]


def test_names_unique_across_threads(tmp_path):
    p = tmp_path / "item.npz"
    names = [temp_file(p) for _ in range(100)]
    assert len(set(names)) == 100

    def write(i):
        write_text_atomic(p, f"{i}\n" * 1000)

    threads = [threading.Thread(target=write, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    lines = set(p.read_text().splitlines())
    assert len(lines) == 1 and [q.name for q in tmp_path.iterdir()] == ["item.npz"]  # one writer's file, whole


KILLED_WHILE_WRITING = """
import os, signal, sys
sys.path.insert(0, {root!r})
from aat_deploy.io.atomic import atomic_file
with atomic_file(sys.argv[1]) as tmp:
    open(tmp, "wb").write(b"half a file")
    os.kill(os.getpid(), signal.SIGKILL)
"""


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_temporary_files_of_killed_processes_are_swept_and_nothing_else(tmp_path):
    """Issue 31 leftover: a process killed (SIGKILL) inside atomic_file left its `.NAME.tmp-PID-...` file for ever
    (only temporary folders were swept). The next write into that folder deletes it; a name without our tag, a live
    process's temporary, another host's (a shared folder: its pid means nothing here), and a link or folder that has
    a tagged name are kept."""
    root = str(Path(__file__).resolve().parents[3])
    proc = subprocess.run([sys.executable, "-c", KILLED_WHILE_WRITING.format(root=root), str(tmp_path / "cache.npz")])
    assert proc.returncode == -signal.SIGKILL
    stale = [q for q in tmp_path.iterdir()]
    assert len(stale) == 1 and stale[0].name.startswith(".cache.npz.tmp-") and stale[0].read_bytes() == b"half a file"
    dead, alive = _dead_pid(), os.getppid()
    (tmp_path / "thesis.txt").write_text("a user's file")

    def tagged(name: str, pid: int, n: int = 0, suffix: str | None = None) -> Path:
        suffix = Path(name).suffix if suffix is None else suffix
        return tmp_path / f".{name}.tmp-{pid}-{n}-{atomic._tag(name, pid, n)}{suffix}"

    keep = [tmp_path / f".a.png.tmp-{dead}-0.png",  # no tag (a user's name, or written before tags)
            tmp_path / f".a.png.tmp-{dead}-0-00000000.png",  # a wrong tag
            tagged("a.png", alive),  # a running process's
            tagged("a.png", dead, 1, ".jpg"),  # a tag, but not the suffix temp_file gives
            tmp_path / f".e.png.tmp-{dead}-0-{atomic._tag('e.png', dead, 0, host='elsewhere')}.png"]  # another host's
    for q in keep:
        q.write_bytes(b"keep")
    link, folder = tagged("b.png", dead), tagged("c.png", dead)
    link.symlink_to(tmp_path / "thesis.txt")
    folder.mkdir()
    (folder / "x").write_text("keep")
    gone = tagged("d.npz", dead, 7)
    gone.write_bytes(b"stale")
    assert atomic.temp_file_pid(gone.name) == dead and atomic.temp_file_pid(keep[1].name) is None
    assert atomic.temp_file_pid(keep[-1].name) is None

    write_text_atomic(tmp_path / "other.json", "{}\n")  # the first write of this process into the folder sweeps it
    assert not stale[0].exists() and not gone.exists()
    assert all(q.read_bytes() == b"keep" for q in keep) and link.is_symlink() and (folder / "x").exists()
    assert (tmp_path / "thesis.txt").read_text() == "a user's file"
    assert atomic.temp_file_pid(temp_file(tmp_path / "x.tar.gz").name) == os.getpid()


def test_nothing_is_committed_after_a_signal_whose_exception_was_discarded(tmp_path):
    """A SIGTERM remembered by the commands' handler (aat_deploy.interrupt) but whose exception a finalizer discarded:
    the writers raise Interrupted instead of committing; the old file and folder stay, no temporary is left."""
    from aat_deploy import interrupt
    from aat_deploy.io import marker

    p, out = tmp_path / "a.json", tmp_path / "out"
    p.write_text("old")
    out.mkdir()
    (out / "summary.json").write_text("old")
    marker.write(out, "aat-infer", complete=True)
    try:
        with pytest.raises(interrupt.Interrupted, match="SIGTERM"):
            with atomic_file(p) as tmp:
                tmp.write_text("new")
                interrupt.note(signal.SIGTERM)  # while it was written
        interrupt.clear()
        with pytest.raises(interrupt.Interrupted) as e:
            with atomic.atomic_folder(out, True, "aat-infer") as tmp:
                (tmp / "summary.json").write_text("new")
                interrupt.note(signal.SIGTERM)
        assert e.value.signum == signal.SIGTERM
    finally:
        interrupt.clear()
    assert p.read_text() == "old" and (out / "summary.json").read_text() == "old"
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.json", "out"]
    write_text_atomic(p, "new")  # cleared: writes commit again
    assert p.read_text() == "new"


def test_a_signal_while_the_earlier_output_is_moved_aside_puts_it_back(tmp_path, monkeypatch):
    """Before: Ctrl-C while --force's earlier output sat aside as .out.old-PID (its marker being checked) left it
    there and no out/ at all; the next run's sweep then deleted it as a dead process's stale folder."""
    from aat_deploy import interrupt
    from aat_deploy.io import marker

    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text("old")
    marker.write(out, "aat-infer", complete=True)

    def signal_now(*a, **k):
        raise interrupt.Interrupted(signal.SIGINT)

    monkeypatch.setattr(marker, "refusal", signal_now)
    with pytest.raises(interrupt.Interrupted):
        with atomic.atomic_folder(out, True, "aat-infer") as tmp:
            (tmp / "summary.json").write_text("new")
    assert (out / "summary.json").read_text() == "old"
    assert sorted(q.name for q in tmp_path.iterdir()) == ["out"]
