"""aat-eval: score DfF models on every capture folder with ground truth under a root.

    aat-eval ROOT --model M.onnx --out DIR [--compare A.onnx B.onnx ...] [--align [MODE]] [--force] [--threads N]

Each capture is run through the runtime (as aat-infer does) and scored with the shared metrics against its
ground truth (docs/contracts.md, "Ground truth"). DIR gets metrics.csv/.json/.md, error maps, error-versus-radius
and error-versus-depth plots and eval.rrd. A failing capture is reported on one line and the batch goes on;
the exit status is 1 if any failed, 2 if nothing could be run.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from .common import add_reader_options, check_reader_options, parser, run_guarded, threads_option


def main(argv: list[str] | None = None) -> int:
    """The command; Ctrl-C or SIGTERM at any point is one line and exit status 130/143 (common.run_guarded)."""
    return run_guarded("aat-eval", _main, argv)


def _main(argv: list[str] | None) -> int:
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from ..errors import CaptureError, one_line, safe_output_streams  # the heavy modules load inside the interrupt guard
    from ..eval.report import MD_COLUMNS
    from ..eval.run import EvalOptions, evaluate
    from ..eval.score import ALIGN_MODES
    from ..shipped import resolve

    safe_output_streams()
    ap = parser("aat-eval", __doc__.split("\n")[0])
    ap.add_argument("root", type=Path, metavar="ROOT", help="a capture folder or a folder of capture folders")
    ap.add_argument("--model", type=Path, help="aat DfF model (.onnx)")
    ap.add_argument("--compare", type=Path, nargs="+", default=[], metavar="M.onnx",
                    help="(more) models scored on the same captures, in one table")
    ap.add_argument("--out", type=Path, required=True, help="output folder (replaced only with --force)")
    ap.add_argument("--force", action="store_true", help="replace an existing output folder")
    ap.add_argument("--align", nargs="?", const="scale-shift", choices=ALIGN_MODES, default=None,
                    help="fit the prediction to the GT per capture and report the fit: scale-shift (least squares "
                         "in depth, the default), scale, or median (median ratio). Default: metric, no fit")
    ap.add_argument("--align-frames", action="store_true",
                    help="align the frames against focus breathing (aat-infer --align)")
    ap.add_argument("--focus-range-mask", action="store_true",
                    help="score only GT pixels inside the capture's focus range")
    ap.add_argument("--threads", type=int, default=None, help="onnxruntime intra-op threads (default: all cores)")
    ap.add_argument("--no-exiftool", action="store_true", help="never fall back to exiftool")
    ap.add_argument("--no-recording", action="store_true", help="skip eval.rrd")
    ap.add_argument("--no-panels", action="store_true", help="skip the per-capture panel PNGs")
    add_reader_options(ap)
    args = ap.parse_args(argv)
    check_reader_options(ap, args)
    args.threads = threads_option("aat-eval", ap, args.threads)
    models = ([args.model] if args.model else []) + [m for m in args.compare if m != args.model]
    models = [resolve(m, "models") for m in models]  # paths, or shipped models' names
    if not models:
        ap.error("give --model M.onnx and/or --compare A.onnx B.onnx ...")
    opts = EvalOptions(align=args.align, align_frames=args.align_frames, focus_range_mask=args.focus_range_mask,
                       force=args.force, use_exiftool=not args.no_exiftool, record=not args.no_recording,
                       panels=not args.no_panels, quiet=args.quiet, max_megapixels=args.max_megapixels,
                       allow_outside_links=args.allow_outside_links)
    try:
        rep = evaluate(args.root, models, args.out, opts, threads=args.threads)
    except CaptureError as e:
        print(one_line(f"aat-eval: error: {e}"), file=sys.stderr)
        return 2
    keys = [k for k, _ in MD_COLUMNS[:3]]
    for label, m in rep["overall"].items():
        vals = "  ".join(f"{k} {m[k]:.4g}" for k in keys if k in m)
        print(f"{label}: {m.get('n_images', 0)} capture(s)  {vals}")
    print(f"-> {args.out}")
    n_failed = len(rep["failed"])
    if n_failed:
        print(f"aat-eval: {n_failed} of {len(rep['per_capture'])} run(s) failed", file=sys.stderr)
    return 1 if n_failed else 0


if __name__ == "__main__":
    sys.exit(main())
