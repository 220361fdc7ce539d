"""aat-infer: run an ONNX depth-from-focus model on capture folders.

    aat-infer CAPTURE_DIR... --model M.onnx [--out DIR] [--force] [--strict] [--threads N] [--tile N] [--align]

Writes depth_mm.png, depth_m.npy, aif.png, std_m.npy, std_mm.png, summary.json and recording.rrd per capture,
into DIR itself for one capture, DIR/<capture name>/ for several (default DIR: ./aat_out/<capture name>); captures
with the same folder name get <name>_2, <name>_3, ... An output folder that is, contains or lies inside an input,
or is the current folder, is refused before any work; an existing one is replaced only with --force, and only if it
is an earlier aat-infer output. A failing capture is reported on one line and the batch goes on; the exit status is
1 if any failed, 2 if the model cannot be used.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from ..errors import CaptureError, safe_output_streams
from ..model import DfFModel
from ..pipeline import Options, check_output, output_dir_for, output_dirs, run_capture
from ..shipped import resolve
from .common import parser


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    safe_output_streams()
    ap = parser("aat-infer", __doc__.split("\n")[0])
    ap.add_argument("captures", nargs="+", metavar="CAPTURE_DIR", help="capture folder(s): frames + focus distances")
    ap.add_argument("--model", required=True, type=Path, metavar="M.onnx",
                    help="aat DfF model: a .onnx file or a shipped model's name (dff_dfvnet_aat, ...)")
    ap.add_argument("--out", type=Path, metavar="DIR", help="output folder: DIR itself for one capture, "
                    "DIR/<capture name>/ for several (default ./aat_out/<capture name>/)")
    ap.add_argument("--force", action="store_true", help="replace existing output folders (earlier aat-infer "
                    "outputs only)")
    ap.add_argument("--strict", action="store_true", help="camera/lens mismatch with the model is an error")
    ap.add_argument("--threads", type=int, default=None, metavar="N", help="onnxruntime intra-op threads (default: all cores)")
    ap.add_argument("--tile", type=int, default=None, metavar="N", help="run in overlapping tiles of N px (bounded memory)")
    ap.add_argument("--align", action="store_true", help="align frames (affine) against focus breathing")
    ap.add_argument("--native-res", action="store_true",
                    help="depth and all-in-focus at the capture's own resolution (the model runs at its sensor size; "
                         "depth upsampled guided by the all-in-focus image)")
    ap.add_argument("--no-exiftool", action="store_true", help="never fall back to exiftool")
    ap.add_argument("--no-recording", action="store_true", help="skip recording.rrd")
    args = ap.parse_args(argv)
    if args.threads is not None and args.threads < 1:
        ap.error("--threads must be >= 1")
    if args.tile is not None and args.tile < 16:
        ap.error("--tile must be >= 16 px")
    args.model = resolve(args.model, "models")  # a path, or a shipped model's name
    captures = [Path(c) for c in args.captures]
    outs = output_dirs(captures, args.out)
    refused = {}  # before any work: an output folder that is, holds or sits in an input is never touched
    for i, (c, out) in enumerate(zip(captures, outs)):
        try:
            check_output(out, args.force, [*captures, args.model])
        except CaptureError as e:
            refused[i] = e
    try:
        model = DfFModel(args.model, threads=args.threads)
    except CaptureError as e:
        print(f"aat-infer: error: {e}", file=sys.stderr)
        return 2
    opts = Options(tile=args.tile, align=args.align, strict=args.strict, force=args.force,
                   use_exiftool=not args.no_exiftool, record=not args.no_recording, quiet=args.quiet,
                   native=args.native_res)
    failed = 0
    for i, (c, out) in enumerate(zip(captures, outs)):
        t0 = time.perf_counter()
        if not args.quiet:
            print(f"[{i + 1}/{len(captures)}] {c}", file=sys.stderr, flush=True)
        if out.name != output_dir_for(c, args.out, len(captures) == 1).name:
            print(f"aat-infer: note: another capture in this batch is also named {c.resolve().name!r}: "
                  f"{c} goes to {out}", file=sys.stderr, flush=True)
        try:
            if i in refused:
                raise refused[i]
            summary = run_capture(c, model, out, opts)
        except CaptureError as e:
            failed += 1
            print(f"aat-infer: FAILED {c}: {e}", file=sys.stderr, flush=True)
            continue
        except MemoryError:
            failed += 1
            print(f"aat-infer: FAILED {c}: out of memory (try --tile 256)", file=sys.stderr, flush=True)
            continue
        except Exception as e:  # noqa: BLE001 (one capture's surprise must not stop the batch)
            failed += 1
            msg = str(e).splitlines()[0][:200] if str(e) else ""
            print(f"aat-infer: FAILED {c}: unexpected {type(e).__name__}: {msg}", file=sys.stderr, flush=True)
            continue
        for w in summary["warnings"]:
            print(f"aat-infer: warning: {w}", file=sys.stderr)
        lo, hi = summary["depth_m_range"]
        print(f"{c} -> {out}  ({len(summary['focus_m'])} frames, depth {lo:.3g}..{hi:.3g} m, "
              f"{time.perf_counter() - t0:.2f} s)", flush=True)
    if failed:
        print(f"aat-infer: {failed} of {len(captures)} capture(s) failed", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
