"""`aat-lens`: look at a lens prescription.

    aat-lens info LENS [--json]
    aat-lens spot LENS --field-deg F --focus-m D [--defocus-mm X] [--json] [--png out.png]
    aat-lens layout LENS --png out.png [--focus-m D]
    aat-lens focus-map LENS [--png out.png] [--force] [--no-calibrate] [--psf trace|PSF.onnx] [--out MAP.json]
                            [--stamp PSF.onnx] [--near-m M] [--calibrate-at M,M,...] [--sweep-d D]
                            [--calibrate-radii R,R,...] [--calibrate-textures N] [--calibrate-crop-px PX]
                            [--recalibrate MAP.json]
    aat-lens focus-map --from-captures SWEEP_DIR [SWEEP_DIR ...] --chart chart.json --out mycam.json
                            [--distance-m D1,D2,...] [--force] ...   (the options of `aat-calibrate fit`)

A best-focus map either way: from a prescription (traced, then calibrated on rendered stacks; for `aat-infer
--method focus --lens`) or from captures, with no prescription (chart sweeps, or `--from-scenes` ordinary stacks:
`aat-calibrate fit` itself, the one fit; the `aat-camera-calibration-v1` file `--calibration` reads, maps PNG
beside it; docs/calibration.md).

Distances in metres are measured from the sensor plane (camera convention); lengths in mm.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from aat_deploy.cli.calibrate import add_fit_options
from aat_deploy.cli.common import check_reader_options, parser, run_or_hint, subparser
from aat_deploy.focus.measures import MEASURES
from aat_deploy.io.atomic import atomic_file
from aat_deploy.lens.io import LensFileError, load_lens
from aat_deploy.lens.materials import UnknownMaterialError
from aat_deploy.shipped import resolve


def _distance(text: str) -> float:
    v = float(text)
    if not (v > 0):
        raise argparse.ArgumentTypeError(f"distance must be > 0 metres (or 'inf'), got {text}")
    return v


def _distances(text: str) -> tuple[float, ...]:
    try:
        return tuple(_distance(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated distances in metres, got {text!r}") from None


def _radii(text: str) -> tuple[float, ...]:
    try:
        r = tuple(float(t) for t in text.split(",") if t.strip())
    except ValueError:
        r = ()
    if not r or not all(0.0 <= v <= 1.0 for v in r):
        raise argparse.ArgumentTypeError(f"expected comma-separated field radii in 0..1, got {text!r}")
    return tuple(sorted(set(r)))


def _png_path(p: str | None, force: bool) -> Path | None:
    if p is None:
        return None
    path = Path(p)
    if path.suffix.lower() != ".png":
        raise SystemExit(f"aat-lens: error: {p}: output must be a .png file")
    if path.exists() and not force:
        raise SystemExit(f"aat-lens: error: {p}: exists (use --force to overwrite)")
    if not path.parent.exists():
        raise SystemExit(f"aat-lens: error: {p}: folder {path.parent} does not exist")
    return path


def _atomic_png(draw, path: Path) -> None:
    with atomic_file(path) as tmp:
        draw(tmp)


def cmd_info(a) -> int:
    from aat_deploy.optics.paraxial import paraxial_data

    lens = load_lens(a.lens)
    p = paraxial_data(lens)
    out = {
        "name": lens.name,
        "efl_mm": p.efl_mm,
        "bfl_mm": p.bfl_mm,
        "fno": p.fno,
        "entrance_pupil_mm": p.entrance_pupil_mm,
        "entrance_pupil_z_mm": p.entrance_pupil_z_mm,
        "exit_pupil_mm": p.exit_pupil_mm,
        "exit_pupil_z_mm": p.exit_pupil_z_mm,
        "hfov_deg": p.hfov_deg,
        "hfov_h_deg": p.hfov_h_deg,
        "hfov_v_deg": p.hfov_v_deg,
        "sensor_mm": list(p.sensor_mm),
        "sensor_px": [lens.sensor.width_px, lens.sensor.height_px],
        "pixel_um": p.pixel_um,
        "total_track_mm": p.total_track_mm,
        "stop_index": lens.stop_index,
        "wavelength_nm": p.wavelength_nm,
        "prescription_hash": lens.prescription_hash(),
    }
    if a.json:
        print(json.dumps(out))
        return 0
    print(f"{lens.name}")
    print(f"{'#':>3} {'radius mm':>11} {'thick mm':>9} {'semi-dia':>8} {'n@λ':>8}  material   notes")
    idx = lens.indices(p.wavelength_nm)
    for i, s in enumerate(lens.surfaces):
        r = "inf" if math.isinf(s.radius_mm) else f"{s.radius_mm:.4f}"
        notes = []
        if i == lens.stop_index:
            notes.append("STOP")
        if s.kind == "ideal":
            notes.append(f"ideal f={s.focal_length_mm:.4f}")
        if s.conic:
            notes.append(f"k={s.conic:g}")
        if any(s.asphere_from_r2):
            notes.append("asphere")
        print(f"{i:>3} {r:>11} {s.thickness_mm:>9.4f} {s.semi_diameter_mm:>8.3f} {idx[i + 1]:>8.5f}  "
              f"{s.material:<10} {' '.join(notes)}")
    print(f"EFL {p.efl_mm:.4f} mm   BFL {p.bfl_mm:.4f} mm   F/{p.fno:.4f}   at {p.wavelength_nm} nm")
    print(f"entrance pupil {p.entrance_pupil_mm:.4f} mm at z = {p.entrance_pupil_z_mm:.4f} mm; "
          f"exit pupil {p.exit_pupil_mm:.4f} mm at z = {p.exit_pupil_z_mm:.4f} mm (z from the first vertex)")
    print(f"sensor {p.sensor_mm[0]:.3f} x {p.sensor_mm[1]:.3f} mm, {lens.sensor.width_px} x "
          f"{lens.sensor.height_px} px, {p.pixel_um:.2f} um pixels; half field of view {p.hfov_deg:.3f} deg "
          f"(diagonal), {p.hfov_h_deg:.3f} (h), {p.hfov_v_deg:.3f} (v)")
    return 0


def cmd_spot(a) -> int:
    from training.optics.spot import spot

    png = _png_path(a.png, a.force)
    lens = load_lens(a.lens)
    sp = spot(lens, a.field_deg, a.focus_m, a.defocus_mm, wavelength_nm=a.wavelength_nm, grid=a.grid)
    out = {
        "rms_um": sp.rms_um,
        "centroid_mm": list(sp.centroid_mm),
        "n_rays": sp.n_rays,
        "n_valid": sp.n_valid,
        "sensor_z_mm": sp.sensor_z_mm,
        "field_deg": a.field_deg,
        "focus_m": a.focus_m,
        "defocus_mm": a.defocus_mm,
    }
    if png:
        from training.optics.layout import draw_spot

        title = f"{lens.name}\nfield {a.field_deg}°, focus {a.focus_m} m, defocus {a.defocus_mm} mm"
        _atomic_png(lambda p: draw_spot(sp, p, title), png)
        out["png"] = str(png)
    if a.json:
        print(json.dumps(out))
    else:
        print(f"RMS spot radius {sp.rms_um:.3f} um (about the centroid); centroid y {sp.centroid_mm[1]:.4f} mm; "
              f"{sp.n_valid}/{sp.n_rays} rays pass")
        if png:
            print(f"wrote {png}")
    return 0


def cmd_layout(a) -> int:
    from training.optics.layout import draw_layout

    png = _png_path(a.png, a.force)
    lens = load_lens(a.lens)
    _atomic_png(lambda p: draw_layout(lens, p, focus_m=a.focus_m), png)
    print(f"wrote {png}")
    return 0


def cmd_focus_map(a) -> int:
    """The lens's best-focus map for `aat-infer --method focus --lens` (traced, then calibrated on rendered stacks),
    written to <lens folder>/best_focus/<lens stem>.json; --png draws it (the stored one, without --force)."""
    import time

    from aat_deploy.focus.bestfocus import load_json, map_path_for_lens

    if a.sweeps:
        return focus_map_from_captures(a)
    out = Path(a.out) if a.out else map_path_for_lens(a.lens)
    png = _png_path(a.png, a.force)
    if a.recalibrate:
        if not a.force:
            print(f"aat-lens: error: --recalibrate replaces {a.recalibrate}'s calibration in {out}: pass --force",
                  file=sys.stderr)
            return 2
        from training.render.focus_calibration import make_focus_map

        t0 = time.time()
        fmap, points = make_focus_map(a.lens, True, a.psf, progress=not a.quiet, calibrate_at_m=a.calibrate_at,
                                      sweep_d=a.sweep_d, radii=a.calibrate_radii, traced=load_json(a.recalibrate),
                                      textures=a.calibrate_textures, measure=a.calibrate_measure,
                                      prefilter_px=a.calibrate_prefilter_px, crop_px=a.calibrate_crop_px)
        fmap.save_json(out)
        print(f"wrote {out} ({time.time() - t0:.0f} s)")
        for p in points:
            print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in p.items()}))
    elif out.exists() and not a.force:
        if png is None and a.stamp is None:
            print(f"aat-lens: error: {out}: exists (pass --force to replace it, --png to draw it, --stamp to stamp "
                  "it)", file=sys.stderr)
            return 2
        fmap = load_json(out)
    else:
        from training.render.focus_calibration import make_focus_map

        t0 = time.time()
        fmap, points = make_focus_map(a.lens, not a.no_calibrate, a.psf, progress=not a.quiet, near_m=a.near_m,
                                      calibrate_at_m=a.calibrate_at, sweep_d=a.sweep_d, radii=a.calibrate_radii,
                                      textures=a.calibrate_textures, measure=a.calibrate_measure,
                                      prefilter_px=a.calibrate_prefilter_px, crop_px=a.calibrate_crop_px)
        fmap.save_json(out)
        print(f"wrote {out} ({time.time() - t0:.0f} s)")
        for p in points:
            print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in p.items()}))
    if png:
        from training.optics.layout import draw_focus_map

        _atomic_png(lambda p: draw_focus_map(fmap, p, fmap.lens_name), png)
        print(f"wrote {png}")
    if a.stamp:
        from training.psf.export import stamp_optics_metadata

        md = stamp_optics_metadata(a.stamp, load_lens(a.lens), best_focus=fmap)
        print(f"{a.stamp}: stamped {', '.join(sorted(md))}")
    return 0


def _fit_options_given(a) -> list[str]:
    """The --from-captures options set to other than their defaults."""
    ref = argparse.ArgumentParser()
    add_fit_options(ref)
    return [f"--{k.replace('_', '-')}" for k, v in vars(ref.parse_args([])).items() if getattr(a, k) != v]


PRESCRIPTION_ONLY = ("png", "no_calibrate", "psf", "stamp")


def focus_map_from_captures(a) -> int:
    """`aat-calibrate fit` (`aat_deploy.cli.calibrate.cmd_fit`, the one fit) on the sweeps: a camera calibration,
    not a lens's radial map; its options are the fit's (`add_fit_options`)."""
    from aat_deploy.cli.calibrate import cmd_fit

    given = [f"--{k.replace('_', '-')}" for k in PRESCRIPTION_ONLY if getattr(a, k) not in (None, False, "trace")]
    if given:
        print(f"aat-lens: error: {', '.join(given)}: for a map from a prescription (LENS), not --from-captures "
              "(the maps PNG goes beside --out)", file=sys.stderr)
        return 2
    if a.out is None:
        print("aat-lens: error: --from-captures needs --out mycam.json (the calibration file to write)",
              file=sys.stderr)
        return 2
    a.prog = "aat-lens"
    return cmd_fit(a)


LENS_HELP = "lens file (our JSON, the paper's JSON, Zemax .zmx, DiffOptics .txt) or a shipped lens's name"


def build_parser() -> argparse.ArgumentParser:
    ap = parser("aat-lens", "Inspect a lens prescription (units: mm; distances in metres from the sensor plane).",
                quiet=False)
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="{info,spot,layout,focus-map}")
    p = subparser(sub, "info", "surface table and paraxial data")
    p.add_argument("lens", metavar="LENS", help=LENS_HELP)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_info)
    p = subparser(sub, "spot", "RMS spot radius (um, about the centroid) and spot diagram (needs the train extra)")
    p.add_argument("lens", metavar="LENS", help=LENS_HELP)
    p.add_argument("--field-deg", type=float, required=True, help="chief-ray field angle in degrees")
    p.add_argument("--focus-m", type=_distance, required=True, help="focus (and object) distance, m from sensor")
    p.add_argument("--defocus-mm", type=float, default=0.0, help="sensor shift from best focus (+ = away)")
    p.add_argument("--wavelength-nm", type=float, default=None, help="default: the lens's design wavelength")
    p.add_argument("--grid", type=int, default=36, help="pupil grid size across (default 36)")
    p.add_argument("--json", action="store_true")
    p.add_argument("--png", default=None, help="write a spot diagram PNG")
    p.add_argument("--force", action="store_true", help="overwrite an existing PNG")
    p.set_defaults(func=cmd_spot)
    p = subparser(sub, "layout", "2-D drawing of the lens with ray fans (needs the train extra)")
    p.add_argument("lens", metavar="LENS", help=LENS_HELP)
    p.add_argument("--png", required=True, help="the PNG to write")
    p.add_argument("--focus-m", type=_distance, default=math.inf, help="focus distance, m from the sensor (default inf)")
    p.add_argument("--force", action="store_true", help="overwrite an existing PNG")
    p.set_defaults(func=cmd_layout)
    p = subparser(sub, "focus-map", "a best-focus map: from LENS, for aat-infer --method focus --lens (real-ray "
                  "traced, then calibrated on rendered stacks; needs the train extra; about 4 min tracing, 3 "
                  "calibrating), or --from-captures, a camera calibration for --calibration (as aat-calibrate fit; "
                  "no prescription, no torch)")
    p.add_argument("lens", metavar="LENS", nargs="?", help=LENS_HELP + " (or --from-captures)")
    p.add_argument("--from-captures", dest="sweeps", nargs="+", metavar="SWEEP_DIR", default=None,
                   help="no prescription: fit the camera's map to these capture folders, one chart sweep each "
                   "(`aat-calibrate shoot` makes virtual ones; docs/calibration.md), or ordinary stacks with "
                   "--from-scenes; writes --out, an aat-camera-calibration-v1 file, and its maps as .png beside it")
    p.add_argument("--out", default=None, help="the map's file (LENS: default <lens folder>/best_focus/<lens "
                   "stem>.json; --from-captures: required, the calibration .json)")
    p.add_argument("--png", default=None, help="also draw the map (best focus against field radius) as this PNG; "
                   "with an existing map and no --force, the stored map is drawn")
    p.add_argument("--force", action="store_true", help="replace an existing map and PNG")
    p.add_argument("--no-calibrate", action="store_true", help="the traced map only (no rendered calibration)")
    p.add_argument("--psf", default="trace", help="PSFs of the calibration renders: trace (default) or a .onnx")
    p.add_argument("--stamp", default=None, help="also stamp the map (the stored one, without --force), the lens's "
                   "focus table and exit pupil into this PSF surrogate's metadata (the surrogate of this lens), so "
                   "that aat-infer --method focus --psf and the diagnosis's twins find them")
    p.add_argument("--near-m", type=_distance, default=None,
                   help="the map's nearest frame focus, m from the sensor (default 0.2 m or the lens's nearest "
                        "focus; a phone lens's working range is nearer)")
    p.add_argument("--calibrate-at", type=_distances, default=None, metavar="M,M,...",
                   help="frame focus settings of the calibration renders, m from the sensor (default 0.6,1,2,5)")
    p.add_argument("--sweep-d", type=float, default=None,
                   help="the calibration's frame sweep, +- diopters around each setting (default 0.2: about 7 px of "
                        "blur on a 50 mm f/1.8; widen it for a lens with less blur per diopter)")
    p.add_argument("--calibrate-textures", type=int, default=None, metavar="N",
                   help="photo textures per calibration point (default 3): more average out how a lens's off-axis "
                        "astigmatism makes the measure's peak depend on the texture (a phone lens: ~0.15 D per "
                        "point with 3)")
    p.add_argument("--calibrate-measure", default=None, choices=sorted(MEASURES), metavar="NAME",
                   help="the focus measure whose peak the map is calibrated to (default: the runtime's, mlap2; "
                        "narrowband: its peak moves less with the texture, but on noisy chart sweeps it did not "
                        "calibrate better; BENCHMARKS.md). The map then belongs to that measure")
    p.add_argument("--calibrate-prefilter-px", type=float, default=None, metavar="PX",
                   help="that measure's pre-filter (Gaussian sigma, px; default the runtime's 1 px; narrowband: 0)")
    p.add_argument("--calibrate-crop-px", type=int, default=None, metavar="PX",
                   help="side of each calibration point's measured patch (px; default 64). Its peak is that of the "
                        "best focus averaged over the patch: where the field is curved over 64 px (a phone lens's "
                        "middle field) a smaller patch holds the point's own, with more textures per point")
    p.add_argument("--recalibrate", default=None, metavar="MAP.json",
                   help="calibrate this stored map of LENS again (its traced part kept, its calibration replaced; "
                        "needs --force) instead of tracing the lens anew")
    p.add_argument("--calibrate-radii", type=_radii, default=None, metavar="R,R,...",
                   help="field radii of the calibration renders (0 centre, 1 corner; default 0,0.3,0.5,0.65,0.8,0.9): "
                        "closer where best focus changes steeply (a phone lens's edge)")
    g = p.add_argument_group("--from-captures (the options of aat-calibrate fit)")
    add_fit_options(g)
    p.set_defaults(func=cmd_focus_map)
    return ap


def main(argv: list[str] | None = None) -> int:
    return run_or_hint("aat-lens", _main, argv)


def _main(argv: list[str] | None) -> int:
    ap = build_parser()
    a = ap.parse_args(argv)
    if a.cmd == "focus-map":
        if (a.lens is None) == (a.sweeps is None):
            ap.error("focus-map: give LENS (a prescription) or --from-captures SWEEP_DIR ... (captures), one of them")
        if a.sweeps:
            check_reader_options(ap, a)
            return a.func(a)
        given = _fit_options_given(a)
        if given:
            ap.error(f"focus-map: {', '.join(given)}: options of --from-captures, not of a map from LENS")
    a.lens = str(resolve(a.lens, "lenses"))  # a path, or a shipped lens's name
    try:
        return a.func(a)
    except (LensFileError, UnknownMaterialError, FileExistsError, ValueError) as e:
        print(f"aat-lens: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
