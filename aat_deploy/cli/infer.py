"""aat-infer: run an ONNX depth-from-focus model on capture folders.

    aat-infer CAPTURE_DIR... --model M.onnx [--out DIR] [--force] [--strict] [--threads N] [--tile N] [--align]
    aat-infer CAPTURE_DIR... --model dfv_aat [--camera F_MM,N,PIXEL_UM] [--lens LENS | --psf PSF.onnx |
                             --calibration CAL.json] [--max-side N]
    aat-infer CAPTURE_DIR... --method focus [--lens LENS | --psf PSF.onnx | --calibration CAL.json]
                             [--focus-m 0.6,0.8,...] [--max-side N] [--prefilter-px SIGMA]
    [--min-confidence C]

--model dfv_aat is the any-camera model: it takes the camera's focal length, f-number and pixel pitch from EXIF (or
--camera) and what each frame has in focus at each pixel from a thin lens, or aberration-aware from the lens's
best-focus map (--lens, --psf) or a calibration (--calibration); it refuses in one line what it cannot know.
--method focus needs no trained model: classical depth from focus (aat_deploy.focus) at a working resolution
chosen from the stack's blur step (--max-side N, or 0 for the frames' own size), aberration-aware with the lens's best-focus map (--lens, --psf) or your camera's calibration
(--calibration, made by aat-calibrate: per pixel and frame what is in focus, the reported focus corrected). It also
writes confidence.npy/png.
Confidence is calibrated: the chance that the pixel's depth is within 10 % of the truth (aat_deploy.confidence);
a model has one when its `<stem>.confidence.json` lies next to it. Below --min-confidence (default 0.5) depth is
unknown: NaN in depth_m, grey in the previews, not in points.ply; summary.json gives the unknown share.

Writes depth (depth_m.npy/.tif, depth_mm.png, depth_color.png), aif.png, uncertainty (std_m.npy, std_mm.png,
std_color.png), points.ply, camera.json, summary.json and recording.rrd per capture (docs/contracts.md), into DIR itself for one capture, DIR/<capture name>/ for several (default DIR: ./aat_out/<capture name>); captures
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

from .common import add_reader_options, check_reader_options, parser, run_guarded, threads_option


def main(argv: list[str] | None = None) -> int:
    """The command; Ctrl-C or SIGTERM at any point is one line and exit status 130/143 (common.run_guarded)."""
    return run_guarded("aat-infer", _main, argv)


def _main(argv: list[str] | None) -> int:
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from ..anycam.model import DEFAULT_MAX_SIDE, FocusMapModel, mapping_from_args, open_model
    from ..capture.focuslist import parse_focus_list  # the heavy modules load inside the interrupt guard
    from ..confidence import MIN_CONFIDENCE
    from ..errors import CaptureError, one_line, safe_output_streams
    from ..focus.method import FocusConfig
    from ..focus.runner import FocusMethod
    from ..infer.pipeline import Options, check_output, output_dir_for, output_dirs, run_capture
    from ..shipped import resolve

    safe_output_streams()
    ap = parser("aat-infer", __doc__.split("\n")[0])
    ap.add_argument("captures", nargs="+", metavar="CAPTURE_DIR", help="capture folder(s): frames + focus distances")
    ap.add_argument("--model", type=Path, metavar="M.onnx", help="aat DfF model: a .onnx file or a shipped model's "
                    "name (rf50_dfvnet_aat, ...); required unless --method focus")
    ap.add_argument("--method", choices=("model", "focus"), default="model",
                    help="model (a trained DfF net, default) or focus (classical focus measures, no model)")
    ap.add_argument("--lens", type=Path, help="--method focus or dfv_aat: lens file, for its best-focus map "
                    "(aberration-aware)")
    ap.add_argument("--psf", type=Path, help="--method focus or dfv_aat: PSF surrogate carrying the lens's "
                    "best-focus map")
    ap.add_argument("--calibration", type=Path, metavar="CAL.json",
                    help="--method focus or dfv_aat: a camera calibration (aat-calibrate fit, "
                         "aat-camera-calibration-v1): per-pixel best focus, the reported focus's error and the "
                         "measured blur growth; replaces the nominal focus distances and the radial --lens map")
    ap.add_argument("--camera", metavar="F_MM,N,PIXEL_UM",
                    help="dfv_aat: focal length (mm), f-number and pixel pitch (um, of the frames as captured), for "
                         "frames whose EXIF lacks them")
    ap.add_argument("--focus-m", metavar="F1,F2,...", help="focus distances (m) of the frames in file-name order, "
                    "for files without focus metadata (overrides capture.json)")
    ap.add_argument("--max-side", type=int, metavar="N",
                    help="--method focus or dfv_aat: work at most this many px on the longer side (dfv_aat: default "
                         "1024; --method focus: default chosen from the stack's blur step, docs/focus_method.md, "
                         "0 = the frames' own size)")
    ap.add_argument("--prefilter-px", type=float, metavar="SIGMA",
                    help="--method focus: Gaussian blur of each frame before the focus measure, standard deviation "
                         f"in px at the working size (default {FocusConfig.prefilter_px:g}, chosen on validation "
                         "stacks; more for noisy high-ISO frames, 0 = none)")
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
    ap.add_argument("--min-confidence", type=float, default=MIN_CONFIDENCE, metavar="C",
                    help=f"depth whose calibrated confidence (chance of being within 10 %% of the truth) is below C is "
                         f"written as unknown (NaN); 0 keeps every pixel (default {MIN_CONFIDENCE:g})")
    ap.add_argument("--no-exiftool", action="store_true", help="never fall back to exiftool")
    ap.add_argument("--no-recording", action="store_true", help="skip recording.rrd")
    add_reader_options(ap)
    args = ap.parse_args(argv)
    check_reader_options(ap, args)
    args.threads = threads_option("aat-infer", ap, args.threads)
    if args.tile is not None and args.tile < 16:
        ap.error("--tile must be >= 16 px")
    if args.method == "model" and args.model is None:
        ap.error("--model is required (or --method focus, which needs no trained model)")
    if args.method == "focus" and args.camera:
        ap.error("--camera belongs to the any-camera model (--model dfv_aat)")
    if args.method == "focus" and args.model is not None:
        ap.error("--method focus uses no --model")
    if args.method == "model" and args.prefilter_px is not None:  # known before any model is opened
        ap.error("--prefilter-px belongs to --method focus (the classical method's pre-filter)")
    if args.prefilter_px is not None and not 0 <= args.prefilter_px <= 50:
        ap.error("--prefilter-px must be between 0 and 50 px")
    if not 0 <= args.min_confidence <= 1:
        ap.error("--min-confidence must be between 0 and 1")
    if args.max_side is not None and not (args.max_side >= 16 or (args.max_side == 0 and args.method == "focus")):
        ap.error("--max-side must be >= 16 px (or 0 with --method focus: the frames' own size)")
    if args.model is not None:
        args.model = resolve(args.model, "models")  # a path, or a shipped model's name
    if args.lens is not None:
        args.lens = resolve(args.lens, "lenses")
    if args.psf is not None:
        args.psf = resolve(args.psf, "models")
    lens_specific = None
    captures = [Path(c) for c in args.captures]
    outs = output_dirs(captures, args.out)
    refused = {}  # before any work: an output folder that is, holds or sits in an input is never touched
    for i, (c, out) in enumerate(zip(captures, outs)):
        try:
            check_output(out, args.force, [*captures, *(p for p in (args.model, args.lens, args.psf,
                                                                      args.calibration) if p)])
        except CaptureError as e:
            refused[i] = e
    try:
        focus_m = parse_focus_list(args.focus_m) if args.focus_m is not None else None
        config = FocusConfig() if args.prefilter_px is None else FocusConfig(prefilter_px=args.prefilter_px)
        if args.method == "focus":
            model = FocusMethod(config, lens=args.lens, psf=args.psf, max_side=args.max_side, progress=not args.quiet,
                                calibration=args.calibration)
        else:
            model = open_model(args.model, threads=args.threads)
            if isinstance(model, FocusMapModel):  # the any-camera model: its camera and focus mapping
                model.configure(mapping_from_args(args.lens, args.psf, args.calibration), camera=args.camera,
                                max_side=args.max_side or DEFAULT_MAX_SIDE)
            elif args.lens or args.psf or args.max_side is not None or args.camera or args.calibration:
                lens_specific = args.model
    except CaptureError as e:
        print(one_line(f"aat-infer: error: {e}"), file=sys.stderr)
        return 2
    if lens_specific is not None:
        ap.error(f"{lens_specific.name} is a lens-specific model: --lens, --psf, --calibration, --camera and "
                 "--max-side belong to --model dfv_aat (--lens and --psf also to --method focus)")
    opts = Options(tile=args.tile, align=args.align, strict=args.strict, force=args.force,
                   use_exiftool=not args.no_exiftool, focus_m=focus_m, record=not args.no_recording,
                   quiet=args.quiet, native=args.native_res, max_megapixels=args.max_megapixels,
                   allow_outside_links=args.allow_outside_links, min_confidence=args.min_confidence)
    failed = 0
    for i, (c, out) in enumerate(zip(captures, outs)):
        t0 = time.perf_counter()
        if not args.quiet:
            print(one_line(f"[{i + 1}/{len(captures)}] {c}"), file=sys.stderr, flush=True)
        if out.name != output_dir_for(c, args.out, len(captures) == 1).name:
            print(one_line(f"aat-infer: note: another capture in this batch is also named {c.resolve().name!r}: "
                           f"{c} goes to {out}"), file=sys.stderr, flush=True)
        try:
            if i in refused:
                raise refused[i]
            summary = run_capture(c, model, out, opts)
        except CaptureError as e:
            failed += 1
            print(one_line(f"aat-infer: FAILED {c}: {e}"), file=sys.stderr, flush=True)
            continue
        except MemoryError:
            failed += 1
            hint = "--max-side 2048" if args.method == "focus" else "--tile 256"
            print(one_line(f"aat-infer: FAILED {c}: out of memory (try {hint})"), file=sys.stderr, flush=True)
            continue
        except Exception as e:  # noqa: BLE001 (one capture's surprise must not stop the batch)
            failed += 1
            msg = str(e).splitlines()[0][:200] if str(e) else ""
            print(one_line(f"aat-infer: FAILED {c}: unexpected {type(e).__name__}: {msg}"), file=sys.stderr, flush=True)
            continue
        for w in summary["warnings"]:
            print(one_line(f"aat-infer: warning: {w}"), file=sys.stderr)
        rng = summary["depth_m_range"]
        share = summary["unknown"]["unknown_share"]
        print(one_line(f"{c} -> {out}  ({len(summary['focus_m'])} frames, "
                       + (f"depth {rng[0]:.3g}..{rng[1]:.3g} m" if rng else "no depth known")
                       + (f", {share:.0%} unknown" if share else "") + f", {time.perf_counter() - t0:.2f} s)"),
              flush=True)
    if failed:
        print(f"aat-infer: {failed} of {len(captures)} capture(s) failed", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
