"""The batch around `aat-eval`: finding capture folders with ground truth, naming models and captures, and the
progress bar."""

from __future__ import annotations

import os
from pathlib import Path

from ..capture.raw import FRAME_EXTENSIONS
from ..errors import CaptureError, one_line
from ..gt.read import has_ground_truth
from ..progress import Progress as BaseProgress


class Progress(BaseProgress):
    """The reporter (`aat_deploy.progress`) over the batch's (capture, model) runs, which also records failures."""

    def __init__(self, total: int, quiet: bool):
        super().__init__(total, "aat-eval", "run", quiet)

    def fail(self, rows: list[dict], messages: list[str], name: str, label: str, msg: str) -> None:
        """Record that `label` failed on `name`: a failed row, the message, and a line under the bar."""
        rows.append({"capture": name, "model": label, "status": "failed", "error": msg})
        line = one_line(f"aat-eval: FAILED {name} ({label}): {msg}")
        messages.append(line)
        self.note(line)


def find_captures(root: Path, exclude: list[Path] = ()) -> tuple[list[Path], list[Path]]:
    """(folders with ground truth, folders with frames but none) under root (root itself included), by path.
    Hidden folders and `exclude` are skipped; a capture folder's subfolders are not searched."""
    root = Path(root)
    if not root.is_dir():
        raise CaptureError(f"{root}: not a folder")
    excl = {p.resolve() for p in exclude}
    with_gt, without = [], []
    for cur, dirs, files in os.walk(root):
        here = Path(cur)
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and (here / d).resolve() not in excl)
        if has_ground_truth(here):
            with_gt.append(here)
            dirs[:] = []
        elif sum(1 for f in files if Path(f).suffix.lower() in FRAME_EXTENSIONS and not f.startswith(("gt_", "."))) >= 2:
            without.append(here)
    return with_gt, without


def model_labels(paths: list[Path]) -> list[str]:
    """Short names of the models: file stems, made unique with a suffix."""
    out: list[str] = []
    for p in paths:
        base, label, i = Path(p).stem, Path(p).stem, 2
        while label in out:
            label, i = f"{base}_{i}", i + 1
        out.append(label)
    return out


def capture_name(root: Path, cap: Path) -> str:
    """A capture's name in the outputs: its path below root with "__" for "/" (root itself: its folder name)."""
    rel = cap.resolve().relative_to(root.resolve()) if cap.resolve() != root.resolve() else Path(cap.resolve().name)
    return "__".join(rel.parts)
