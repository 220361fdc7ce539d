"""aat-render: the virtual camera. An all-in-focus image and a metric depth map in, a capture folder out.

    aat-render RGB DEPTH --lens LENS --focus-m 0.5,1,2 --out DIR [--psf PSF.onnx] [--effects noise,vignetting]
               [--thin-lens] [--depth-scale S] [--seed N] [--force]
    aat-render --list-effects

RGB: 8/16-bit sRGB image. DEPTH: .npy in metres or 16-bit PNG in millimetres (0 = unknown), metres from the
sensor. The scene is scaled to cover the lens's sensor and centre-cropped; frames are rendered at the sensor's
resolution with the lens's PSFs (its surrogate from --psf or models/, else ray-traced) unless --thin-lens.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from aat_deploy.cli.common import add_list_option, parser, print_effects, run_or_hint
from aat_deploy.shipped import resolve, shipped_dir


def _floats(text: str) -> list[float]:
    try:
        v = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not v:
        raise argparse.ArgumentTypeError("expected at least one number")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = parser("aat-render", __doc__.split("\n\n")[0] + " Needs the train extra.")
    add_list_option(p, "--list-effects", print_effects, "list the simulator's effects and exit")
    p.add_argument("rgb", metavar="RGB", help="all-in-focus image (8/16-bit sRGB)")
    p.add_argument("depth", metavar="DEPTH", help="depth: .npy metres or 16-bit PNG millimetres (0 = unknown)")
    p.add_argument("--lens", required=True, help="lens file (.json, .zmx)")
    p.add_argument("--focus-m", type=_floats, required=True,
                   help="focus distances, metres from the sensor (comma-separated)")
    p.add_argument("--out", required=True, help="capture folder to write")
    p.add_argument("--psf", help="PSF surrogate .onnx for this lens (default: a matching one in models/, else ray-trace)")
    p.add_argument("--effects", default="", help="extra effects, comma-separated (see --list-effects)")
    p.add_argument("--thin-lens", action="store_true", help="ideal thin lens (Gaussian PSFs) instead of the lens's")
    p.add_argument("--depth-scale", type=float, help="metres per depth unit (default: 1 for .npy, 0.001 for PNG)")
    p.add_argument("--seed", type=int, default=0, help="random seed (noise)")
    p.add_argument("--force", action="store_true", help="overwrite an existing capture folder")
    return p


def find_surrogate(lens) -> Path | None:
    """A shipped PSF surrogate (models/) made for exactly this prescription."""
    import onnx

    models = shipped_dir("models")
    for f in sorted(models.glob("*.onnx")) if models else []:
        try:
            meta = {p.key: p.value for p in onnx.load(str(f), load_external_data=False).metadata_props}
        except Exception:
            continue
        if meta.get("aat.kind") == "psf_surrogate" and meta.get("aat.lens_hash") == lens.prescription_hash():
            return f
    return None


def run(args) -> Path:
    import torch

    from aat_deploy.capture.virtual import write_capture
    from aat_deploy.errors import OutputError
    from aat_deploy.gt.holes import fill_holes
    from aat_deploy.infer.geometry import fit_rgbd_to_sensor
    from aat_deploy.io.guard import check_output_dir
    from aat_deploy.lens.io import LensFileError, load_lens
    from aat_deploy.render import effects as fx
    from training.data.rgbd import RGBDError, load_rgbd
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF, RayTracedPSF

    out = Path(args.out)
    try:  # before any work: --force replaces the folder, so it must never hold or sit in an input
        check_output_dir(out, [p for p in (args.rgb, args.depth, args.lens, args.psf) if p], args.force,
                         tool="aat-render")
    except OutputError as e:
        raise SystemExit(f"aat-render: error: {e}") from None
    try:
        lens = load_lens(args.lens)
        rgb, depth = load_rgbd(args.rgb, args.depth, args.depth_scale)
        effects = fx.parse(args.effects)
    except (LensFileError, RGBDError, ValueError, OSError) as e:
        raise SystemExit(f"aat-render: error: {e}") from None
    hs, ws = lens.sensor.height_px, lens.sensor.width_px
    rgb, depth = fit_rgbd_to_sensor(rgb, depth, (hs, ws))
    names = [e.name for e in effects]
    lens_src, psf_used = None, None
    if not args.thin_lens or "vignetting" in names:
        psf = Path(args.psf) if args.psf else find_surrogate(lens)
        if psf is not None:
            lens_src, psf_used = OnnxPSF(psf, lens), psf.name
        else:
            lens_src, psf_used = RayTracedPSF(lens, n_rays=1024), "ray-traced (1024 rays)"
    if not args.thin_lens:
        effects = fx.parse(["aberrations"] + names)
    sim = Simulator(lens, lens_src, effects)
    lo, hi = 0.2, 100.0
    for f in args.focus_m:
        if not lo <= f <= hi:
            raise SystemExit(f"aat-render: error: focus distance {f} m outside {lo}..{hi} m")
    focus = np.sort(np.asarray(args.focus_m, dtype=np.float64))
    img = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))).float()
    rng = np.random.default_rng(args.seed)
    frames = []
    t0 = time.time()
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        tqdm = None
    it = tqdm(focus, desc="frames", unit="frame") if tqdm and not args.quiet else focus
    for f in it:
        st = sim.render_stack(img, torch.from_numpy(fill_holes(depth)).float(), [f], rng=rng)
        frames.append(st.frames[0].numpy())
    info = {"lens": lens.name, "lens_hash": lens.prescription_hash(), "psf": psf_used,
            "effects": sim.effect_names, "focus_m": focus.tolist(), "seed": args.seed,
            "rgb": Path(args.rgb).name, "depth": Path(args.depth).name, "render_seconds": round(time.time() - t0, 2)}
    focus_reported = focus.copy()  # metadata effects (if any) decide what the EXIF says
    for e in sim.effects:
        focus_reported = e.report_focus(focus_reported, sim.context(), rng)
    info["focus_reported_m"] = focus_reported.tolist()
    try:
        write_capture(out, np.stack(frames), focus_reported, lens, depth, rgb.transpose(2, 0, 1), info,
                      force=args.force)
    except (FileExistsError, ValueError) as e:
        raise SystemExit(f"aat-render: error: {e}") from None
    return out


def main(argv: list[str] | None = None) -> int:
    return run_or_hint("aat-render", _main, argv)


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    args.lens = str(resolve(args.lens, "lenses"))  # a path, or a shipped lens's name
    args.psf = str(resolve(args.psf, "models")) if args.psf else None
    out = run(args)
    print(json.dumps({"capture": str(out)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
