"""aat-calibrate: calibrate a camera from focus sweeps of a flat chart, without its optical prescription.

    aat-calibrate chart --out chart.png [--size-mm 600,400] [--markers 6,4] [--marker-mm M] [--dpi 150] [--seed N]
                      [--frame-px W | --texture-sigma-mm S] [--force]
    aat-calibrate fit SWEEP_DIR [SWEEP_DIR ...] --chart chart.json --out mycam.json [--distance-m D1,D2,...]
                      [--pupil-to-sensor-mm P] [--sensor-mm W,H] [--max-side 1600] [--boot 100] [--force]
    aat-calibrate fit --from-scenes CAPTURE_DIR [CAPTURE_DIR ...] --out mycam.json [--sensor-mm W,H] [--force]
    aat-calibrate shoot --chart chart.png --lens LENS --distance-m D --out SWEEP_DIR [--psf PSF.onnx]
                      [--tilt-deg X,Y] [--sweep-d 0.3] [--step-d 0.04] [--effects noise,...] [--seed N] [--force]
    aat-calibrate show mycam.json [--png maps.png]

chart: a printable target (dead-leaves texture and ArUco markers) and chart.json, its layout (print at 100 %:
the PNG carries its dpi; check a marker's size with a ruler); --frame-px W (your image's width) softens the
texture to the fine detail photographs have. fit: per sweep the chart's pose from its markers
and each tile's focus peak; the smooth per-position best-focus model, the reported focus's error and the blur
growth, with bootstrap intervals; writes mycam.json (format aat-camera-calibration-v1, docs/contracts.md) and
mycam.png (the maps). Nothing is written when any sweep is unusable (one line each). --distance-m: per sweep, the
distance from the camera's sensor plane to the chart at the frame centre (tape or laser meter); ~D marks one the
fit finds (a chart too near for a tape's millimetre; at least one measured), D only its start; a bare ~ starts it
from the chart's marker pose (no tape at all). shoot: the
virtual camera photographs the chart at a pose through a lens with any registered effects (a sweep folder of
DNGs with the true geometry in virtual_camera.json; torch-free with the lens's PSF surrogate). --from-scenes: no
chart; ordinary stacks from a camera turned between them: the field term under which their estimates agree
where they see the same surface (the reported focus's offset and scale cannot be identified and are kept). How to
shoot: docs/calibration.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..errors import CaptureError, safe_output_streams
from .common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, add_reader_options, check_reader_options, parser, subparser


def _pair(text: str, what: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}: expected two numbers 'A,B', got {text!r}") from None
    return a, b


def _floats(text: str) -> list[float]:
    try:
        v = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not v or not all(np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"expected comma-separated finite numbers, got {text!r}")
    return v


class Distances(list):
    """--distance-m's metres per sweep (float, or None for a bare `~`); fitted: the indices marked `~` (`~D`: D is
    only a start; bare `~`: the start is the chart's marker pose; the fit finds them)."""

    fitted: frozenset = frozenset()


def _distances(text: str) -> Distances:
    """'D1,D2,~D3,~': metres per sweep; a leading ~ marks a distance the fit takes as an unknown (a chart too near
    for a tape's millimetre), the number after it only the start; a bare ~ starts it from the chart's marker pose.
    At least one must be measured."""
    parts = [t.strip() for t in text.split(",") if t.strip()]
    if not parts:
        _floats(text)  # raises: no numbers
    fitted = frozenset(i for i, t in enumerate(parts) if t.startswith("~"))
    if len(fitted) == len(parts):
        raise argparse.ArgumentTypeError(f"every distance of {text!r} is marked ~ (fitted): measure at least one")
    given = [t.lstrip("~").strip() for t in parts]
    nums = iter(_floats(",".join(g for g in given if g)))
    out = Distances(next(nums) if g else None for g in given)
    out.fitted = fitted
    return out


def prog(args) -> str:
    """The command's name in messages: `fit` also runs as `aat-lens focus-map --from-captures`, which sets it."""
    return getattr(args, "prog", None) or "aat-calibrate"


def _say(args, msg: str) -> None:
    if not getattr(args, "quiet", False):
        print(msg, file=sys.stderr, flush=True)


# -- chart -------------------------------------------------------------------------------------------------------
def cmd_chart(args) -> int:
    from ..calibrate.chart import ChartSpec, texture_sigma_for, write_chart

    try:
        sigma = args.texture_sigma_mm
        if args.frame_px is not None:
            sigma = texture_sigma_for(float(args.size_mm[0]), args.frame_px)
        spec = ChartSpec(size_mm=args.size_mm, markers=tuple(int(v) for v in args.markers), dpi=args.dpi,
                         marker_mm=args.marker_mm, seed=args.seed, texture_sigma_mm=sigma)
        png, js = write_chart(args.out, spec, force=args.force)
    except (ValueError, CaptureError) as e:
        print(f"aat-calibrate: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    print(json.dumps({"chart": str(png), "layout": str(js), "size_mm": list(spec.size_mm), "dpi": spec.dpi,
                      "marker_mm": round(spec.marker_side_mm, 3), "texture_sigma_mm": round(spec.texture_sigma_mm, 4)}))
    return EXIT_OK


# -- fit ---------------------------------------------------------------------------------------------------------
def cmd_fit(args) -> int:
    from ..calibrate.chart import load_layout
    from ..calibrate.fit import fit_calibration
    from ..calibrate.format import CalibrationError
    from ..calibrate.plots import calibration_png
    from ..calibrate.sweep import load_sweep, measure_sweep
    from ..focus.method import FocusConfig
    from ..io.atomic import atomic_files

    out = Path(args.out)
    png = out.with_suffix(".png")
    for p in (out, png):
        if p.exists() and not args.force:
            print(f"{prog(args)}: error: {p}: exists (use --force to overwrite)", file=sys.stderr)
            return EXIT_USAGE
    sweeps = [Path(s) for s in args.sweeps]
    if any(p.resolve() in (s.resolve(), *s.resolve().parents) for s in sweeps for p in (out, png)):
        print(f"{prog(args)}: error: {out}: the output must not be inside a sweep folder", file=sys.stderr)
        return EXIT_USAGE
    if args.from_scenes:
        return fit_scenes(args, sweeps, out, png)
    if args.chart is None:
        print(f"{prog(args)}: error: --chart chart.json is required (or --from-scenes)", file=sys.stderr)
        return EXIT_USAGE
    if args.distance_m is not None and len(args.distance_m) != len(sweeps):
        print(f"{prog(args)}: error: --distance-m gives {len(args.distance_m)} distances for {len(sweeps)} sweeps",
              file=sys.stderr)
        return EXIT_USAGE
    try:
        layout = load_layout(args.chart)
    except CaptureError as e:
        print(f"{prog(args)}: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    cfg = FocusConfig()
    fitted = getattr(args.distance_m, "fitted", frozenset())  # ~D: the fit finds that chart's distance
    measures, failed = [], 0
    for i, s in enumerate(sweeps):
        _say(args, f"{prog(args)}: measuring {s} ({i + 1}/{len(sweeps)})")
        try:
            sw = load_sweep(s, args.max_side, max_megapixels=args.max_megapixels,
                            allow_outside_links=args.allow_outside_links)
            measures.append(measure_sweep(sw, layout, None if args.distance_m is None else args.distance_m[i],
                                          args.pupil_to_sensor_mm, args.sensor_mm, cfg.measure, cfg.window_px,
                                          cfg.prefilter_px,
                                          fit_distance=i in fitted))
        except CaptureError as e:
            print(f"{prog(args)}: error: {e}", file=sys.stderr)
            failed += 1
    if failed:
        print(f"{prog(args)}: {failed} of {len(sweeps)} sweeps unusable: nothing written", file=sys.stderr)
        return EXIT_FAILED
    settings = {"sweeps": [str(s) for s in sweeps], "chart": str(args.chart),
                "distance_m": args.distance_m, "distance_fitted": sorted(fitted), "measure": cfg.measure,
                "window_px": cfg.window_px,
                "prefilter_px": cfg.prefilter_px, "estimator": "gauss", "max_side": args.max_side}
    try:
        res = fit_calibration(measures, n_boot=args.boot, sensor_mm=args.sensor_mm, settings=settings,
                              progress=lambda what: _say(args, f"{prog(args)}: {what}"))
    except (CaptureError, ValueError) as e:
        print(f"{prog(args)}: error: {e}", file=sys.stderr)
        return EXIT_FAILED
    cal = res.calibration
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_files(out, png) as (tj, tp):
            from ..calibrate.format import save_calibration

            save_calibration(cal, tj, force=True)
            calibration_png(cal, tp, res.observations, res.model.residual_d)
    except (OSError, CalibrationError) as e:
        print(f"{prog(args)}: error: {out}: cannot write ({e})", file=sys.stderr)
        return EXIT_FAILED
    for w in res.warnings:
        print(f"{prog(args)}: warning: {w}", file=sys.stderr)
    print(json.dumps(summary(cal, out, png)))
    return EXIT_OK


def fit_scenes(args, captures: list[Path], out: Path, png: Path) -> int:
    """Blind calibration (`aat_deploy.calibrate.scenes`): nothing is written unless every capture reads."""
    from ..calibrate.fit import camera_identity_of
    from ..calibrate.format import CalibrationError, save_calibration
    from ..calibrate.plots import calibration_png
    from ..calibrate.scenes import estimate_scene, fit_from_scenes
    from ..calibrate.sweep import identity_differences, load_sweep
    from ..io.atomic import atomic_files

    scenes, loaded, failed = [], [], 0
    for i, c in enumerate(captures):
        _say(args, f"{prog(args)}: estimating {c} ({i + 1}/{len(captures)})")
        try:
            sw = load_sweep(c, args.max_side, min_frames=3, max_megapixels=args.max_megapixels,
                            allow_outside_links=args.allow_outside_links)
            if loaded:
                diff = identity_differences(loaded[0].identity, sw.identity)
                if diff or sw.size_px != loaded[0].size_px:
                    raise CaptureError(f"{c}: from another camera than {loaded[0].path} "
                                       f"({'; '.join(diff) or 'frame size'}): calibrate one camera at a time")
            scenes.append(estimate_scene(c.name, sw.frames, sw.reported_m))
            loaded.append(sw)
        except CaptureError as e:
            print(f"{prog(args)}: error: {e}", file=sys.stderr)
            failed += 1
    if failed:
        print(f"{prog(args)}: {failed} of {len(captures)} captures unusable: nothing written", file=sys.stderr)
        return EXIT_FAILED
    if len(scenes) < 2:
        print(f"{prog(args)}: error: --from-scenes needs at least two captures of the same surfaces", file=sys.stderr)
        return EXIT_USAGE
    try:
        res = fit_from_scenes(scenes, camera_identity_of(loaded[0]), loaded[0].size_px, args.sensor_mm,
                              args.pupil_to_sensor_mm, n_boot=min(args.boot, 50),
                              settings={"captures": [str(c) for c in captures], "max_side": args.max_side})
    except ValueError as e:
        print(f"{prog(args)}: error: {e}", file=sys.stderr)
        return EXIT_FAILED
    cal = res.calibration
    try:
        with atomic_files(out, png) as (tj, tp):
            save_calibration(cal, tj, force=True)
            calibration_png(cal, tp)
    except (OSError, CalibrationError) as e:
        print(f"{prog(args)}: error: {out}: cannot write ({e})", file=sys.stderr)
        return EXIT_FAILED
    for w in res.warnings:
        print(f"{prog(args)}: warning: {w}", file=sys.stderr)
    print(json.dumps({**summary(cal, out, png), "pairs": cal.residuals["pairs"],
                      "samples": cal.residuals["samples"]}))
    return EXIT_OK


def summary(cal, out: Path | None = None, png: Path | None = None) -> dict:
    fe = cal.focus_error
    near, far = cal.focus_range_m
    d = {"calibration": str(out) if out else None, "maps": str(png) if png else None,
         "camera": cal.to_dict()["camera"], "focus_error": {"family": fe.family, "bias_d": fe.bias_d,
                                                            "scale": fe.scale, "intervals": fe.intervals,
                                                            "support": fe.support},
         "focus_range_m": [round(near, 4), round(far, 4)],
         "residual_rms_d": cal.residuals.get("rms_d"), "residual_p95_d": cal.residuals.get("p95_d"),
         "tiles": cal.residuals.get("tiles"), "field_radius_max": cal.best_focus.radius_max}
    rng = cal.fit.get("object_range_d")
    if rng:  # beyond these objects (or radius, or focus range) the map is extrapolated (calibrate.measured_mask)
        d["object_range_m"] = [round(1.0 / max(float(v), 1e-9), 4) for v in rng[::-1]]
    fitted = [{"sweep": p["sweep"], "chart_distance_m": p["chart_distance_m"], "given_m": p["distance_given_m"],
               "start_from": p.get("distance_start_from", "--distance-m"), "interval_m": p.get("distance_ci_m")}
              for p in cal.residuals.get("per_sweep", []) if "distance_given_m" in p]
    if fitted:  # charts whose distance the fit found (--distance-m ~D, or ~ from the marker pose)
        d["fitted_distances"] = fitted
    return {k: v for k, v in d.items() if v is not None}


# -- shoot (the virtual camera) ------------------------------------------------------------------------------------
def cmd_shoot(args) -> int:
    from ..calibrate.chart import load_layout
    from ..calibrate.pose import ChartPose
    from ..calibrate.scene import chart_scene
    from ..capture.virtual import shoot, write_capture
    from ..diagnose.lookup import find_surrogate
    from ..io.images import imread
    from ..lens.io import load_lens
    from ..optics.paraxial import paraxial_data
    from ..render import effects as fx
    from ..shipped import resolve

    out = Path(args.out)
    if out.exists() and not args.force:
        print(f"aat-calibrate: error: {out}: exists (use --force to overwrite)", file=sys.stderr)
        return EXIT_USAGE
    chart_png = Path(args.chart)
    try:
        layout = load_layout(chart_png.with_suffix(".json"))
        img = imread(chart_png, 0)
        if img is None:
            raise CaptureError(f"{chart_png}: not a readable image")
        if img.dtype != np.uint8 or (img.shape[1], img.shape[0]) != tuple(layout.image_px):
            raise CaptureError(f"{chart_png}: not the image of {chart_png.with_suffix('.json')} (8-bit, "
                               f"{layout.image_px[0]}x{layout.image_px[1]} px expected)")
        lens = load_lens(resolve(args.lens, "lenses"))
        effects = fx.parse(args.effects)
        src = find_surrogate(lens, resolve(args.psf, "models") if args.psf else None)
    except (CaptureError, ValueError, OSError) as e:
        print(f"aat-calibrate: error: {str(e).splitlines()[0]}", file=sys.stderr)
        return EXIT_USAGE
    p = paraxial_data(lens)
    s = lens.sensor
    f_px = p.efl_mm / s.pixel_mm
    pupil = p.total_track_mm + p.bfl_mm - p.entrance_pupil_z_mm  # paraxial, focused at infinity (aat-gt's)
    pose = ChartPose(args.distance_m, args.tilt_deg[0], args.tilt_deg[1], args.roll_deg)
    try:
        rgb, depth = chart_scene(img, layout, pose, s.width_px, s.height_px, f_px, pupil)
    except ValueError as e:
        print(f"aat-calibrate: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    d = 1.0 / depth
    focus_d = np.arange(float(d.max()) + args.sweep_d, float(d.min()) - args.sweep_d - 1e-9, -args.step_d)
    focus_d = focus_d[focus_d > 0.01]
    _say(args, f"aat-calibrate: shooting {len(focus_d)} frames of the chart at {args.distance_m} m through {lens.name}")
    try:
        frames, reported = shoot(lens, rgb * args.exposure, depth, 1.0 / focus_d, [fx.spec(e) for e in effects], src,
                                 args.seed, workers=args.threads)
    except (fx.NeedsTorch, ValueError) as e:
        print(f"aat-calibrate: error: {str(e).splitlines()[0]} (aat-render renders with torch)", file=sys.stderr)
        return EXIT_USAGE
    info = {"what": "a chart sweep shot by the virtual camera (aat-calibrate shoot)", "lens": lens.name,
            "lens_hash": lens.prescription_hash(), "psf": None if src is None else str(src.path),
            "effects": [fx.spec(e) for e in effects], "seed": args.seed, "chart": str(chart_png),
            "pose": {"distance_m": pose.distance_m, "tilt_x_deg": pose.tilt_x_deg, "tilt_y_deg": pose.tilt_y_deg,
                     "roll_deg": pose.roll_deg},
            "pupil_to_sensor_mm": pupil, "f_px": f_px, "focus_true_m": (1.0 / focus_d).tolist(),
            "focus_reported_m": reported.tolist()}
    try:
        write_capture(out, frames, reported, lens, depth, rgb, info, force=args.force)
    except (FileExistsError, ValueError, OSError) as e:
        print(f"aat-calibrate: error: {e}", file=sys.stderr)
        return EXIT_FAILED
    print(json.dumps({"sweep": str(out), "frames": len(focus_d), "chart_distance_m": args.distance_m}))
    return EXIT_OK


# -- show --------------------------------------------------------------------------------------------------------
def cmd_show(args) -> int:
    from ..calibrate.format import CalibrationError, load_calibration
    from ..calibrate.plots import calibration_png

    try:
        cal = load_calibration(args.calibration)
        if args.png:
            if Path(args.png).exists() and not args.force:
                raise CalibrationError(f"{args.png}: exists (use --force to overwrite)")
            calibration_png(cal, args.png)
    except (CalibrationError, OSError) as e:
        print(f"aat-calibrate: error: {e}", file=sys.stderr)
        return EXIT_FAILED
    print(json.dumps(summary(cal, Path(args.calibration), Path(args.png) if args.png else None)))
    return EXIT_OK


def add_fit_options(f: argparse.ArgumentParser) -> None:
    """The fit's options but the folders, --out and --force: `aat-calibrate fit` and `aat-lens focus-map
    --from-captures` (the same command, `cmd_fit`)."""
    f.add_argument("--chart", help="the chart's layout (chart.json from `aat-calibrate chart`)")
    f.add_argument("--from-scenes", action="store_true", help="no chart: the folders are ordinary stacks of one "
                   "camera turned between them (blind calibration of the field term; docs/calibration.md)")
    f.add_argument("--distance-m", type=_distances, metavar="D1,D2,...",
                   help="per sweep, metres from the sensor plane to the chart at the frame centre (measured); ~D: "
                        "only a start, the fit finds it (a chart nearer than a tape's millimetre allows; at least "
                        "one measured); a bare ~: the fit finds it starting from the chart's marker pose")
    f.add_argument("--pupil-to-sensor-mm", type=float, help="entrance pupil's distance in front of the sensor "
                   "(default: the EXIF focal length)")
    f.add_argument("--sensor-mm", type=lambda t: _pair(t, "--sensor-mm"), metavar="W,H",
                   help="sensor size in mm (focal length in px for the pose; stored in the calibration)")
    f.add_argument("--max-side", type=int, default=1600, help="measure on frames reduced to this many px (default "
                   "1600)")
    f.add_argument("--boot", type=int, default=100, help="bootstrap replicates for the intervals (default 100)")
    add_reader_options(f)


def build_parser() -> argparse.ArgumentParser:
    ap = parser("aat-calibrate", __doc__.split("\n")[0], quiet=False)
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="{chart,fit,shoot,show}")
    c = subparser(sub, "chart", "write a printable calibration chart (PNG) and its layout (JSON beside it)")
    c.add_argument("--out", required=True, help="chart image to write (.png); the layout goes to the same name .json")
    c.add_argument("--size-mm", type=lambda t: _pair(t, "--size-mm"), default=(600.0, 400.0), metavar="W,H",
                   help="printed size in mm (default 600,400; the frame should be filled by the chart)")
    c.add_argument("--markers", type=lambda t: _pair(t, "--markers"), default=(6, 4), metavar="NX,NY",
                   help="ArUco markers across and down (default 6,4)")
    c.add_argument("--marker-mm", type=float, help="marker side in mm (default: a quarter of their spacing)")
    c.add_argument("--dpi", type=float, default=150.0, help="image resolution for printing (default 150)")
    c.add_argument("--seed", type=int, default=0, help="the texture's random seed")
    soft = c.add_mutually_exclusive_group()
    soft.add_argument("--frame-px", type=int, metavar="W",
                      help="your camera image's width in pixels: the texture is softened to 0.7 of its pixels where "
                      "the chart fills the frame's width, as fine as photographs' detail (recommended; "
                      "docs/calibration.md)")
    soft.add_argument("--texture-sigma-mm", type=float, default=0.0, metavar="S",
                      help="the texture's softening (Gaussian SD, mm of chart; default 0: sharp dead leaves)")
    c.add_argument("--force", action="store_true", help="overwrite existing files")
    f = subparser(sub, "fit", "fit a camera calibration to chart sweeps")
    f.add_argument("sweeps", nargs="+", metavar="SWEEP_DIR", help="one capture folder per chart position (with "
                   "--from-scenes: per scene)")
    f.add_argument("--out", required=True, help="calibration file to write (.json; the maps go to .png beside it)")
    f.add_argument("--force", action="store_true", help="overwrite an existing calibration")
    add_fit_options(f)
    s = subparser(sub, "shoot", "the virtual camera: a chart sweep through a lens with effects (a capture folder)")
    s.add_argument("--chart", required=True, help="chart image (.png with its .json beside it)")
    s.add_argument("--lens", required=True, help="lens file or shipped lens name")
    s.add_argument("--psf", help="the lens's PSF surrogate (default: a shipped one for the lens, else thin lens)")
    s.add_argument("--distance-m", type=float, required=True, help="sensor plane to chart at the frame centre (m)")
    s.add_argument("--tilt-deg", type=lambda t: _pair(t, "--tilt-deg"), default=(0.0, 0.0), metavar="X,Y",
                   help="chart rotation about the vertical / horizontal axis (deg; +: right / top side farther)")
    s.add_argument("--roll-deg", type=float, default=0.0, help="chart rotation about the optical axis (deg)")
    s.add_argument("--sweep-d", type=float, default=0.3, help="the sweep extends this far beyond the chart (D)")
    s.add_argument("--step-d", type=float, default=0.04, help="frame spacing (D)")
    s.add_argument("--effects", default="", help="registered effects, comma-separated (aat-diagnose --list-effects)")
    s.add_argument("--exposure", type=float, default=0.6, help="linear level of the chart's white (1 = clipping)")
    s.add_argument("--seed", type=int, default=0, help="random seed (noise)")
    s.add_argument("--threads", type=int, default=2, help="render threads")
    s.add_argument("--out", required=True, help="sweep folder to write")
    s.add_argument("--force", action="store_true", help="replace an existing sweep folder")
    w = subparser(sub, "show", "summarise a calibration file (and draw its maps)")
    w.add_argument("calibration")
    w.add_argument("--png", help="write the maps here")
    w.add_argument("--force", action="store_true", help="overwrite an existing --png")
    return ap


def main(argv: list[str] | None = None) -> int:
    safe_output_streams()
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.cmd == "fit":
        check_reader_options(ap, args)
    return {"chart": cmd_chart, "fit": cmd_fit, "shoot": cmd_shoot, "show": cmd_show}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
