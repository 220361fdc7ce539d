"""Which cameras' files give a focus distance, without and with ExifTool: the tables in docs/shooting.md.

    python -m benchmarks.exif_focus_table [FOLDER]      (default ../shared/data/raw_exif_makernotes_exiftool)

Reads every sample file with the runtime's own reader (`aat_deploy.capture.exif.read_metadata`, no ExifTool) and
with ExifTool (`exiftool -j -n`, as the runtime's fallback asks it), and prints two Markdown tables: per brand
(how many samples give a focus distance each way) and per file (the value and the tag it came from). It needs the
`exiftool` executable (Debian: libimage-exiftool-perl). tests/test_shooting_docs.py checks that docs/shooting.md
holds exactly this output.
"""

from __future__ import annotations

import math
import sys
from collections import defaultdict
from pathlib import Path

from aat_deploy.capture import exiftool
from aat_deploy.capture.exif import read_metadata
from aat_deploy.capture.folder import focus_problem
from aat_deploy.capture.raw import FRAME_EXTENSIONS

ROOT = Path(__file__).resolve().parents[1]

DEFAULT = ROOT.parent / "shared" / "data" / "raw_exif_makernotes_exiftool"
BRANDS = (("CANON", "Canon"), ("NIKON", "Nikon"), ("OLYMPUS", "Olympus"), ("OM DIGITAL", "Olympus"),
          ("MINOLTA", "Minolta"), ("KONICA MINOLTA", "Minolta"), ("CASIO", "Casio"), ("FLIR", "FLIR"),
          ("GOOGLE", "Google"), ("APPLE", "Apple"), ("FUJIFILM", "Fujifilm"), ("PANASONIC", "Panasonic"),
          ("PENTAX", "Pentax"), ("RICOH", "Pentax"), ("LEAF", "Phase One"), ("PHASE ONE", "Phase One"),
          ("SIGMA", "Sigma"), ("SONY", "Sony"))


EXIFTOOL_TAG = {"FocusDistanceUpper": "FocusDistanceUpper/Lower"}  # the runtime combines Canon's pair


def brand(make: str | None, name: str) -> str:
    """The brand from EXIF Make (or, when the file has none we can read, from the sample's name)."""
    for key, b in BRANDS:
        if (make or "").upper().startswith(key) or (make is None and name.upper().startswith(key)):
            return b
    return make or "?"


def _fmt(v: float | None, source: str | None) -> str:
    if v is None:
        return "—"
    shown = "∞" if math.isinf(v) else f"{v:.4g} m"
    why = focus_problem(v)
    return f"{shown} ({source}){'; unusable: ' + why if why else ''}"


def rows(folder: Path) -> list[dict]:
    out = []
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() not in FRAME_EXTENSIONS:
            continue
        ours = read_metadata(p, use_exiftool=False)
        et = exiftool.read(p)
        usable = lambda v: v is not None and focus_problem(v) is None
        out.append({"file": p.name, "brand": brand(ours.make or et.make, p.name),
                    "camera": ours.model or et.model or "?",
                    "ours": _fmt(ours.focus_m, ours.focus_source), "ours_ok": usable(ours.focus_m),
                    "exiftool": _fmt(et.focus_m, EXIFTOOL_TAG.get(et.focus_source, et.focus_source)),
                    "exiftool_ok": usable(et.focus_m)})
    return out


def todo(r: dict) -> str:
    if r["ours_ok"]:
        return "nothing"
    if r["exiftool_ok"]:
        return "install ExifTool"
    return "`capture.json` (`aat-capture init --focus-m`)"


def tables(folder: Path) -> str:
    rs = rows(folder)
    by_brand: dict[str, list[dict]] = defaultdict(list)
    for r in rs:
        by_brand[r["brand"]].append(r)
    lines = ["| brand | samples | focus distance without ExifTool | with ExifTool |", "|---|---|---|---|"]
    for b in sorted(by_brand):
        g = by_brand[b]
        types = ", ".join(sorted({Path(r["file"]).suffix.lstrip(".").upper() for r in g}))
        lines.append(f"| {b} | {len(g)} ({types}) | {sum(r['ours_ok'] for r in g)} of {len(g)} | "
                     f"{sum(r['exiftool_ok'] or r['ours_ok'] for r in g)} of {len(g)} |")
    lines += ["", "| brand | file | camera | without ExifTool | with ExifTool | what to do |",
              "|---|---|---|---|---|---|"]
    for b in sorted(by_brand):
        for r in by_brand[b]:
            lines.append(f"| {b} | {r['file']} | {r['camera']} | {r['ours']} | {r['exiftool']} | {todo(r)} |")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    folder = Path(argv[0]) if argv else DEFAULT
    if not folder.is_dir():
        print(f"{folder}: no such folder (the shared maker-note samples)", file=sys.stderr)
        return 2
    if not exiftool.available():
        print("exiftool is not installed (Debian: libimage-exiftool-perl): the 'with ExifTool' column needs it",
              file=sys.stderr)
        return 2
    print(tables(folder))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
