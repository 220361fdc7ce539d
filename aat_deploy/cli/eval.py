"""aat-eval: score DfF models on every capture folder with ground truth under a root, or on a public benchmark.

    aat-eval ROOT --model M.onnx --out DIR [--compare A.onnx B.onnx ...] [--align [MODE]] [--force] [--threads N]
    aat-eval --dataset {ddff12,fod500,zedd,mobile_depth} PATH [--model M.onnx ...] [--method focus
             [--calibration CAM.json]] --out DIR [--split S] [--frames 0,2,4,...] [--aperture N] [--limit N]

Each capture is run through the runtime (as aat-infer does) and scored with the shared metrics against its
ground truth (docs/contracts.md, "Ground truth"). DIR gets metrics.csv/.json/.md, error maps, error-versus-radius
and error-versus-depth plots and eval.rrd. With --dataset the stacks are read from the benchmark as published
(docs/datasets.md) and scored in its unit and by its conventions; --method focus adds the classical method, with
--calibration mapping each frame's focus through a camera calibration (aat-calibrate fit) of the camera that shot
the stacks (it is the one focus mapping aat-eval uses: the models scored on capture folders map focus their own way). A
failing capture is reported on one line and the batch goes on; the exit status is 1 if any failed, 2 if nothing
could be run.
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
    from ..errors import CaptureError, one_line, safe_output_streams  # heavy modules load inside the guard
    from ..eval.datasets import NAMES as DATASETS
    from ..eval.report import MD_COLUMNS
    from ..eval.run import EvalOptions, evaluate
    from ..eval.score import ALIGN_MODES
    from ..shipped import resolve

    safe_output_streams()
    ap = parser("aat-eval", __doc__.split("\n")[0])
    ap.add_argument("root", type=Path, metavar="ROOT", help="a capture folder or a folder of capture folders; with "
                    "--dataset, the dataset's file or folder")
    ap.add_argument("--dataset", choices=DATASETS, help="read ROOT as this public benchmark (docs/datasets.md)")
    ap.add_argument("--method", choices=("focus",), help="--dataset: also score the classical method (no model)")
    ap.add_argument("--calibration", type=Path, metavar="CAM.json",
                    help="--dataset with --method focus: the classical method maps each frame's reported focus "
                         "through this camera calibration (aat-calibrate fit; docs/calibration.md)")
    ap.add_argument("--split", help="--dataset: the split (ddff12: val|train|test, fod500: test|train, "
                    "zedd: val|test)")
    ap.add_argument("--frames", metavar="I,J,...", help="--dataset: indices of the slices to use, near to far "
                    "(default: the dataset's convention)")
    ap.add_argument("--aperture", type=float, metavar="N", help="--dataset zedd: f-number of the sweep (default 2.8)")
    ap.add_argument("--limit", type=int, metavar="N", help="--dataset: only the first N stacks")
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
    if args.dataset:
        return _dataset(ap, args, models)
    if args.method or args.split or args.frames or args.aperture is not None or args.limit is not None:
        ap.error("--method, --split, --frames, --aperture and --limit belong to --dataset")
    if args.calibration is not None:
        ap.error("--calibration belongs to --dataset with --method focus (the classical method's focus mapping; "
                 "models scored on capture folders map focus their own way)")
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
    return _summary(rep, [k for k, _ in MD_COLUMNS[:3]], "capture(s)", args.out)


def _summary(rep: dict, keys, what: str, out: Path) -> int:
    """Print the mean per model and where the results are; the exit status (1 if any run failed)."""
    for label, m in rep["overall"].items():
        vals = "  ".join(f"{k} {m[k]:.4g}" for k in keys if k in m)
        print(f"{label}: {m.get('n_images', 0)} {what}  {vals}")
    if rep.get("shown_without_ground_truth"):
        print(f"{len(rep['shown_without_ground_truth'])} stack(s) without ground truth: shown, not scored")
    print(f"-> {out}")
    n_failed = len(rep["failed"])
    if n_failed:
        print(f"aat-eval: {n_failed} of {len(rep['per_capture'])} run(s) failed", file=sys.stderr)
    return 1 if n_failed else 0


def _dataset(ap, args, models: list[Path]) -> int:
    """aat-eval --dataset NAME PATH: the models and/or the classical method on a public benchmark."""
    from ..errors import CaptureError, one_line
    from ..eval.batch import model_labels
    from ..eval.dataset_run import DatasetEvalOptions, evaluate_dataset
    from ..eval.datasets import open_dataset
    from ..focus.runner import FocusMethod
    from ..infer.model import DfFModel
    from ..io.guard import check_output_dir

    if not models and not args.method:
        ap.error("--dataset: give --model M.onnx (and/or --compare ...) and/or --method focus")
    if args.align or args.align_frames or args.focus_range_mask:
        ap.error("--align, --align-frames and --focus-range-mask are not used with --dataset")
    if args.calibration is not None and args.method != "focus":
        ap.error("--calibration belongs to --method focus (the classical method's focus mapping)")
    if args.limit is not None and args.limit < 1:
        ap.error("--limit must be >= 1")
    try:
        frames = None if args.frames is None else [int(v) for v in args.frames.split(",")]
    except ValueError:
        ap.error(f"--frames must be indices separated by commas, got {args.frames!r}")
    try:
        check_output_dir(args.out, [args.root, *models, *([args.calibration] if args.calibration else [])],
                         args.force, tool="aat-eval")
        ds = open_dataset(args.dataset, args.root, split=args.split, frames=frames, aperture=args.aperture,
                          max_megapixels=args.max_megapixels)
        labels = model_labels(models)
        methods = [(lb, DfFModel(m, threads=args.threads)) for lb, m in zip(labels, models)]
        if args.method == "focus":
            methods.append(("focus" if "focus" not in labels else "focus_method",
                            FocusMethod(calibration=args.calibration)))  # a bad file: a CaptureError, one line
        rep = evaluate_dataset(ds, methods, args.out, DatasetEvalOptions(limit=args.limit, force=args.force,
                                                                         quiet=args.quiet))
    except CaptureError as e:
        print(one_line(f"aat-eval: error: {e}"), file=sys.stderr)
        return 2
    return _summary(rep, ("mse", "rmse", "abs_rel", "delta1"), f"stack(s) ({rep['units']})", args.out)


if __name__ == "__main__":
    sys.exit(main())
