"""aat-capture: look at capture folders before running a model on them, write their capture.json, plan a stack.

    aat-capture inspect CAPTURE_DIR_OR_FILE... [--json] [--no-exiftool] [--calibration CAM.json]
    aat-capture init CAPTURE_DIR [--focus-m F1,F2,...] [--force] [--no-exiftool]
    (both also [--max-megapixels MP] [--allow-outside-links], as every command that reads captures)
    aat-capture plan --near M --far M --frames N

inspect: per frame the focus distance found (metres from the sensor), where it came from (capture.json, which EXIF
or maker-note tag, exiftool), camera make/model, lens, focal length, F-number and image size; per folder whether
aat-infer can run it, and if not why; with --calibration, whether its camera is the calibrated one. Exit status 1 if a folder cannot be run or a file gives no usable focus
distance.
init: write CAPTURE_DIR/capture.json listing the frame files in name order with their focus distances: from
--focus-m (in that order), else from each file's metadata, else null for you to fill in. An existing capture.json
is replaced only with --force (the old one is kept as capture.json.bak).
plan: focus distances for N frames from near to far, evenly spaced in diopters (as the models were trained).
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

from ..capture.exif import read_metadata
from ..capture.focuslist import parse_focus_list
from ..capture.folder import SIDECAR, _sidecar, focus_problem, frame_files, read_capture
from ..capture.imagefile import frame_header
from ..errors import CaptureError, one_line, safe_output_streams
from ..io.atomic import atomic_file
from ..io.files import check_inside, read_input_bytes
from .common import (
    EXIT_FAILED,
    EXIT_OK,
    EXIT_USAGE,
    add_reader_options,
    check_reader_options,
    parser,
    run_guarded,
    subparser,
)


def _frame_rows(target: Path, args) -> list[dict]:
    """Per-frame metadata rows of a folder (its capture.json's files if it has one) or of one file. Each file's
    kind and size come from its header, as aat-infer reads them: unknown content, a size beyond the pixel limit or
    a link out of the folder is a CaptureError naming the file."""
    if target.is_dir():
        sidecar = _sidecar(target, args.allow_outside_links) or {}
        files = [target / n for n in sidecar] if sidecar else frame_files(target)  # names confined by _sidecar
        focus = dict(zip(files, sidecar.values())) if sidecar else {}
        if not files:
            raise CaptureError(f"{target}: empty capture folder (no RAW, TIFF, PNG or JPEG frames)")
        for f in files:
            check_inside(target, f, args.allow_outside_links)
    elif target.is_file():
        files, focus = [target], {}
    else:
        raise CaptureError(f"{target}: no such file or folder")
    rows = []
    for f in files:
        buf = read_input_bytes(f)
        _, size = frame_header(f, buf, args.max_megapixels)
        meta = read_metadata(f, use_exiftool=not args.no_exiftool, buf=buf)
        if f in focus:
            meta.focus_m, meta.focus_source = focus[f], SIDECAR
        if meta.width is None and size:
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


def _problem(target: Path, rows: list[dict], args) -> str | None:
    """Why aat-infer cannot run this target, or None: a folder through the runtime's own checks
    (aat_deploy.capture.folder.read_capture), a single file when it gives no usable focus distance."""
    if target.is_dir():
        try:
            read_capture(target, use_exiftool=not args.no_exiftool, max_megapixels=args.max_megapixels,
                         allow_outside_links=args.allow_outside_links)
        except CaptureError as e:
            return str(e)
        return None
    f = rows[0]["focus_m"]
    f = math.inf if f == "inf" else f
    if f is None:
        return f"{target}: no focus distance in its metadata; give it in {SIDECAR} (aat-capture init)"
    why = focus_problem(f)
    return None if why is None else f"{target}: focus distance {_fmt(f, ' m')} is not usable ({why})"


def calibration_mismatch(cal, rows: list[dict]) -> list[str]:
    """How the frames' cameras (EXIF rows) differ from a calibration's camera, and frame sizes of another aspect
    ratio than its frames': one phrase each, [] when they match as far as the metadata tells."""
    out: list[str] = []
    for r in rows:
        for m in cal.camera.mismatch(r.get("make"), r.get("model"), r.get("lens"), r.get("focal_length_mm"),
                                     r.get("f_number")):
            if m not in out:
                out.append(m)
        if r.get("width") and r.get("height"):
            w = cal.aspect_warning(int(r["height"]), int(r["width"]), "frames")
            if w and w not in out:
                out.append(w)
    return out


def inspect(args) -> int:
    failed, out = 0, []
    cal = None
    if args.calibration is not None:
        from ..calibrate.format import load_calibration

        try:
            cal = load_calibration(args.calibration)
        except CaptureError as e:
            print(one_line(f"aat-capture: error: {e}"), file=sys.stderr, flush=True)
            return EXIT_USAGE
    for t in args.targets:
        target = Path(t)
        try:
            rows = _frame_rows(target, args)
        except CaptureError as e:
            print(one_line(f"aat-capture: CANNOT READ: {e}"), file=sys.stderr, flush=True)
            failed += 1
            continue
        problem = _problem(target, rows, args)
        failed += problem is not None
        differs = calibration_mismatch(cal, rows) if cal is not None else None
        for r in rows:
            r["capture"], r["capture_problem"] = str(target), problem
            if differs is not None:
                r["calibration_mismatch"] = differs
        out += rows
        if not args.json and not args.quiet:
            for r in rows:
                size = f"{r['width']}x{r['height']}" if r["width"] else "-"
                print(f"{r['file']}\n  focus {_fmt(r['focus_m'], ' m')}  from {r['focus_source'] or '-'}\n"
                      f"  camera {r['make'] or '-'} / {r['model'] or '-'}  lens {r['lens'] or '-'}  "
                      f"f {_fmt(r['focal_length_mm'], ' mm')}  F/{_fmt(r['f_number'])}  size {size}")
                for n in r["notes"]:
                    print(f"  note: {n}")
            if target.is_dir() and problem is None:
                print(one_line(f"{target}: ok, {len(rows)} frames aat-infer can run"))
        if differs is not None and not args.json:  # a result: printed under --quiet too
            verdict = (f"matches the calibration's camera ({args.calibration})" if not differs else
                       f"NOT the calibration's camera ({args.calibration}): {'; '.join(differs)}")
            print(one_line(f"{target}: {verdict}"))
        if problem is not None:
            print(one_line(f"aat-capture: CANNOT RUN: {problem}"), file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps(out, indent=2))
    return EXIT_FAILED if failed else EXIT_OK


def _backup_name(path: Path) -> Path:
    bak, k = path.with_name(path.name + ".bak"), 2
    while os.path.lexists(bak):
        bak, k = path.with_name(f"{path.name}.bak{k}"), k + 1
    return bak


def init(args, ap) -> int:
    folder = Path(args.folder)
    if not folder.is_dir():
        ap.error(f"{folder}: not a folder")
    try:
        focus = parse_focus_list(args.focus_m) if args.focus_m is not None else None
    except CaptureError as e:  # the parser aat-infer --focus-m uses
        ap.error(str(e))
    path = folder / SIDECAR
    if os.path.lexists(path) and not args.force:
        print(f"aat-capture: FAILED: {path} exists (pass --force to replace it; the old one is kept as "
              f"{_backup_name(path).name})", file=sys.stderr)
        return EXIT_FAILED
    try:
        files = frame_files(folder)
    except OSError as e:
        print(f"aat-capture: FAILED: {folder}: cannot read ({e.strerror or e})", file=sys.stderr)
        return EXIT_FAILED
    if not files:
        print(f"aat-capture: FAILED: {folder}: no RAW, TIFF, PNG or JPEG frames", file=sys.stderr)
        return EXIT_FAILED
    if focus is not None and len(focus) != len(files):
        ap.error(f"--focus-m gives {len(focus)} focus distances, {folder} has {len(files)} frames: "
                 + ", ".join(p.name for p in files[:8]) + (" ..." if len(files) > 8 else ""))
    frames, missing = [], []
    for i, p in enumerate(files):
        try:  # as aat-infer reads it: inside the folder, known content, within the pixel limit
            check_inside(folder, p, args.allow_outside_links)
            buf = read_input_bytes(p)
            frame_header(p, buf, args.max_megapixels)
        except CaptureError as e:
            print(one_line(f"aat-capture: FAILED: {e}"), file=sys.stderr)
            return EXIT_FAILED
        if focus is not None:
            f, src = focus[i], "--focus-m"
        else:
            try:
                meta = read_metadata(p, use_exiftool=not args.no_exiftool, buf=buf)
            except CaptureError as e:
                print(f"aat-capture: warning: {e}", file=sys.stderr)
                meta = None
            f = meta.focus_m if meta is not None and meta.focus_m is not None and focus_problem(meta.focus_m) is None \
                else None
            src = meta.focus_source if f is not None else None
        if f is None:
            missing.append(p.name)
        frames.append({"file": p.name, "focus_m": f, **({"from": src} if src else {})})
    text = json.dumps({"frames": frames}, indent=2) + "\n"
    try:
        with atomic_file(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
            if os.path.lexists(path):  # written: keep the old one, then rename the new one into place
                bak = _backup_name(path)
                os.replace(path, bak)
                print(f"{path}: the previous one is kept as {bak.name}", file=sys.stderr)
    except OSError as e:
        print(f"aat-capture: FAILED: {path}: cannot write ({e.strerror or e})", file=sys.stderr)
        return EXIT_FAILED
    if not args.quiet:
        print(f"{path}: {len(frames)} frames")
    if missing:
        print(f"{path}: fill in focus_m (metres from the sensor) for {len(missing)} frame(s): "
              + ", ".join(missing[:8]) + (" ..." if len(missing) > 8 else ""), file=sys.stderr)
    return EXIT_OK


def plan_focus_m(near_m: float, far_m: float, frames: int) -> list[float]:
    """`frames` focus distances (m) from near_m to far_m, evenly spaced in diopters (1/m)."""
    dn, df = 1.0 / near_m, 1.0 / far_m
    return [1.0 / (dn + (df - dn) * i / (frames - 1)) for i in range(frames)]


def plan(args, ap) -> int:
    if not (args.near > 0 and args.far > args.near and math.isfinite(args.far)):
        ap.error("need 0 < --near < --far (metres from the sensor)")
    if args.frames < 2:
        ap.error("--frames must be >= 2")
    fs = plan_focus_m(args.near, args.far, args.frames)
    step = (1 / args.near - 1 / args.far) / (args.frames - 1)
    print(f"{args.frames} frames, {step:.4g} diopters apart (focus distances in m from the sensor):")
    print(",".join(f"{f:.4g}" for f in fs))
    return EXIT_OK


def main(argv: list[str] | None = None) -> int:
    """The command; Ctrl-C or SIGTERM at any point is one line and exit status 130/143 (common.run_guarded)."""
    return run_guarded("aat-capture", _main, argv)


def _main(argv: list[str] | None) -> int:
    safe_output_streams()
    ap = parser("aat-capture", __doc__.split("\n")[0], quiet=False)
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="{inspect,init,plan}")
    ins = subparser(sub, "inspect", "per-frame focus distance and its source, camera and lens; whether aat-infer "
                    "can run each folder")
    ins.add_argument("targets", nargs="+", metavar="CAPTURE_DIR_OR_FILE")
    ins.add_argument("--json", action="store_true", help="print a JSON list of per-frame objects (with 'capture' and "
                     "'capture_problem': null when aat-infer can run it)")
    ins.add_argument("--no-exiftool", action="store_true", help="do not fall back to exiftool even if installed")
    ins.add_argument("--calibration", type=Path, metavar="CAM.json", help="say whether each capture's camera (make, "
                     "model, lens, focal length, F-number, frame aspect) matches this calibration's (aat-calibrate)")
    add_reader_options(ins)
    ini = subparser(sub, "init", "write CAPTURE_DIR/capture.json listing its frames and their focus distances")
    ini.add_argument("folder", metavar="CAPTURE_DIR")
    ini.add_argument("--focus-m", metavar="F1,F2,...", help="focus distances in metres from the sensor, one per frame "
                     "in file-name order (default: from each file's metadata, null where it has none)")
    ini.add_argument("--force", action="store_true", help="replace an existing capture.json (kept as .bak)")
    ini.add_argument("--no-exiftool", action="store_true", help="do not fall back to exiftool even if installed")
    add_reader_options(ini)
    pl = subparser(sub, "plan", "focus distances for a stack, evenly spaced in diopters")
    pl.add_argument("--near", type=float, required=True, metavar="M", help="nearest focus distance (m from the sensor)")
    pl.add_argument("--far", type=float, required=True, metavar="M", help="farthest focus distance (m)")
    pl.add_argument("--frames", type=int, required=True, metavar="N", help="number of frames")
    args = ap.parse_args(argv)
    if args.cmd == "inspect":
        check_reader_options(ins, args)
        return inspect(args)
    if args.cmd == "init":
        check_reader_options(ini, args)
        return init(args, ini)
    return plan(args, pl)


if __name__ == "__main__":
    sys.exit(main())
