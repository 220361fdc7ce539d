"""aat-capture: look at capture folders or single files before running a model on them.

    aat-capture inspect CAPTURE_DIR_OR_FILES... [--json] [--no-exiftool]

Per frame: the focus distance found (metres from the sensor), where it came from (sidecar, which EXIF or
maker-note tag, exiftool), camera make/model, lens, focal length, F-number and image size.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from ..capture.exif import read_metadata
from ..capture.folder import SIDECAR, _sidecar, frame_files
from ..capture.raw import FRAME_EXTENSIONS, is_raw, raw_size
from ..errors import CaptureError, safe_output_streams


def _rows(targets: list[str], use_exiftool: bool) -> list[dict]:
    rows = []
    for t in targets:
        p = Path(t)
        if p.is_dir():
            sidecar = _sidecar(p) or {}
            files = [p / n for n in sidecar] if sidecar else frame_files(p)  # names confined by _sidecar
            focus = dict(zip(files, sidecar.values())) if sidecar else {}
            if not files:
                raise CaptureError(f"{p}: empty capture folder (no RAW, TIFF, PNG or JPEG frames)")
        elif p.is_file():
            if p.suffix.lower() not in FRAME_EXTENSIONS:
                raise CaptureError(f"{p}: unknown frame type {p.suffix!r} (expected RAW, TIFF, PNG or JPEG)")
            files, focus = [p], {}
        else:
            raise CaptureError(f"{p}: no such file or folder")
        for f in files:
            meta = read_metadata(f, use_exiftool=use_exiftool)
            if f in focus:
                meta.focus_m, meta.focus_source = focus[f], SIDECAR
            if meta.width is None and is_raw(f):
                size = raw_size(f)
                if size:
                    meta.width, meta.height = size
            rows.append(meta.as_json())
    return rows


def _fmt(v, unit: str = "", digits: int = 4) -> str:
    if v is None:
        return "-"
    if v == "inf" or (isinstance(v, float) and math.isinf(v)):
        return "inf"
    if isinstance(v, float):
        return f"{v:.{digits}g}{unit}"
    return f"{v}{unit}"


def main(argv: list[str] | None = None) -> int:
    safe_output_streams()
    ap = argparse.ArgumentParser(prog="aat-capture", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    ins = sub.add_parser("inspect", help="per-frame focus distance, its source, camera and lens")
    ins.add_argument("targets", nargs="+", metavar="CAPTURE_DIR_OR_FILE")
    ins.add_argument("--json", action="store_true", help="print a JSON list of objects")
    ins.add_argument("--no-exiftool", action="store_true", help="do not fall back to exiftool even if installed")
    args = ap.parse_args(argv)
    try:
        rows = _rows(args.targets, not args.no_exiftool)
    except CaptureError as e:
        print(f"aat-capture: error: {e}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        size = f"{r['width']}x{r['height']}" if r["width"] else "-"
        print(f"{r['file']}\n  focus {_fmt(r['focus_m'], ' m')}  from {r['focus_source'] or '-'}\n"
              f"  camera {r['make'] or '-'} / {r['model'] or '-'}  lens {r['lens'] or '-'}  "
              f"f {_fmt(r['focal_length_mm'], ' mm')}  F/{_fmt(r['f_number'])}  size {size}")
        for n in r["notes"]:
            print(f"  note: {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
