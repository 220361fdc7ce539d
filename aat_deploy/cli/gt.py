"""aat-gt: ground-truth depth for evaluation.

    aat-gt render MESH --pose POSE.json --lens M.onnx|INTRINSICS.json --out OUT [--width W --height H]
                  [--pupil-to-sensor-mm D] [--mesh-scale S] [--max-incidence-deg A] [--force]
    aat-gt pose --points POINTS.json|.csv --lens M.onnx|INTRINSICS.json --out POSE.json [--init POSE.json]
                [--image FRAME] [--width W --height H] [--mesh-scale S] [--force]
    aat-gt check CAPTURE_DIR... [--model M.onnx] [--max-megapixels MP] [--allow-outside-links]

render: ray-casts a mesh (PLY/OBJ/..., e.g. a lidar scan) from the camera pose and writes depth in metres from
the sensor plane: a 16-bit PNG in mm (0 = no surface), a float32 .npy in metres (NaN = no surface), a validity
mask PNG (255 = valid) and a JSON of how it was rendered. OUT is a .png path, or a folder (a capture folder:
gt_depth_mm.png, gt_depth_m.npy, gt_mask.png, gt_render.json). Needs the gt extra (pip install "aat-dff[gt]").
pose: the camera pose from a few clicked correspondences (pixel in a frame, the same point on the mesh), solved or
refined from --init, written as the pose file `render` reads, with each point's reprojection error; with --image,
a picture of the clicks and where the pose puts them (POSE.png).
check: reads each capture's ground truth as aat-eval does and prints what it found (one line each).
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

from ..errors import CaptureError, one_line, safe_output_streams
from ..gt.raycast import load_mesh, load_pose, render_depth
from ..gt.read import check_aspect, check_units, find_gt, load_ground_truth
from ..io.atomic import atomic_files
from ..io.depth_png import encode_mm16
from ..io.files import check_inside
from ..io.guard import check_output_files
from ..io.images import imwrite
from ..optics.camera import load_intrinsics
from .common import add_reader_options, check_reader_options, parser, run_guarded, subparser


def output_paths(out: Path) -> dict[str, Path]:
    """The files `render` writes for OUT: a folder → gt_* names inside it; a .png → beside it
    (name_mm.png → name_m.npy; gt_*.png → gt_mask.png; else name.npy, name_mask.png)."""
    if out.suffix.lower() != ".png":
        return {"png": out / "gt_depth_mm.png", "npy": out / "gt_depth_m.npy", "mask": out / "gt_mask.png",
                "json": out / "gt_render.json"}
    stem = out.stem
    npy = out.with_name((stem[:-3] + "_m" if stem.endswith("_mm") else stem) + ".npy")
    mask = out.with_name("gt_mask.png" if stem.startswith("gt_") else stem + "_mask.png")
    return {"png": out, "npy": npy, "mask": mask, "json": npy.with_suffix(".json")}


def _write_atomic(paths: dict[str, Path], depth_m: np.ndarray, info: dict) -> None:
    valid = np.isfinite(depth_m)
    mm, info["beyond_png_range"] = encode_mm16(depth_m)  # clipped to 65.535 m in the PNG; the .npy keeps them
    with atomic_files(*paths.values()) as tmps:
        tmp = dict(zip(paths, tmps))
        np.save(tmp["npy"], depth_m.astype(np.float32))
        if not imwrite(tmp["png"], mm) or not imwrite(tmp["mask"], valid.astype(np.uint8) * 255):
            raise OSError("could not write PNG")
        tmp["json"].write_text(json.dumps(info, indent=2) + "\n")


def cmd_render(a) -> int:
    paths = output_paths(a.out)
    check_output_files(paths.values(), [a.mesh, a.pose, a.lens])  # before any work
    existing = [p for p in paths.values() if p.exists()]
    if existing and not a.force:
        raise CaptureError(f"{existing[0]}: exists (pass --force to overwrite)")
    if a.out.suffix.lower() != ".png":
        a.out.mkdir(parents=True, exist_ok=True)
    intr = load_intrinsics(a.lens, a.width, a.height, a.pupil_to_sensor_mm)
    pose = load_pose(a.pose)
    mesh = load_mesh(a.mesh, a.mesh_scale)
    if not a.quiet:
        print(f"aat-gt: {len(mesh.faces)} triangles, {intr.width}x{intr.height} rays", file=sys.stderr)
    depth, rinfo = render_depth(mesh, intr, pose, a.max_incidence_deg)
    if rinfo["hits"] == 0:
        raise CaptureError(f"{a.mesh}: no pixel sees the mesh from {a.pose} (pose, axes or --mesh-scale wrong?)")
    info = {"mesh": str(a.mesh), "mesh_scale_to_m": a.mesh_scale, "pose": str(a.pose),
            "camera_to_world_rdf": pose.tolist(), "intrinsics": intr.as_dict(),
            "depth": "metres from the sensor plane along the optical axis (z-depth from the entrance pupil + "
                     "pupil_to_sensor_mm)", **rinfo}
    _write_atomic(paths, depth, info)
    for n in intr.notes:
        print(f"aat-gt: note: {n}", file=sys.stderr)
    ok = np.isfinite(depth)
    print(f"{a.mesh} -> {paths['png']}  ({100 * ok.mean():.1f} % valid, depth "
          f"{np.nanmin(depth):.3f}..{np.nanmax(depth):.3f} m from the sensor)")
    return 0


def cmd_pose(a) -> int:
    from ..gt.pose import fit_notes, load_correspondences, preview, solve_pose

    outs = [a.out] + ([a.out.with_suffix(".png")] if a.image else [])
    check_output_files(outs, [p for p in (a.points, a.lens, a.init, a.image) if p])
    existing = [p for p in outs if p.exists()]
    if existing and not a.force:
        raise CaptureError(f"{existing[0]}: exists (pass --force to overwrite)")
    intr = load_intrinsics(a.lens, a.width, a.height)
    points = load_correspondences(a.points, a.mesh_scale)
    init = load_pose(a.init) if a.init else None
    fit = solve_pose(points, intr, init)
    notes = fit_notes(fit, points, intr)
    picture = None
    if a.image:
        from ..capture.raw import load_frame
        from ..io.color import linear_to_srgb

        rgb, _ = load_frame(a.image)
        if rgb.shape[:2] != (intr.height, intr.width):  # the clicks are taken in the intrinsics' pixels
            notes.append(f"{a.image} is {rgb.shape[1]}x{rgb.shape[0]} px, the intrinsics {intr.width}x{intr.height} "
                         "px: the points are read as pixels of the latter (give --width/--height of the image "
                         "they were clicked in)")
        picture = preview(linear_to_srgb(np.clip(rgb / max(float(np.percentile(rgb, 99.5)), 1e-6), 0, 1)),
                          points, intr, fit)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_files(*outs) as tmps:  # the pose, and its picture with --image
        tmps[0].write_text(json.dumps(fit.as_json(intr, points, notes), indent=2) + "\n")
        if picture is not None and not imwrite(tmps[1], picture):
            raise OSError(f"{outs[1]}: could not write PNG")
    for n in notes:  # the intrinsics' pupil notes concern depth, not the pose
        print(f"aat-gt: note: {n}", file=sys.stderr)
    pos = fit.cam_to_world[:3, 3]
    print(f"{a.points} -> {a.out}  ({len(points.pixels)} points, reprojection RMS {fit.rms_px:.2f} px, max "
          f"{fit.residuals_px.max():.2f} px; camera at [{pos[0]:.3f}, {pos[1]:.3f}, {pos[2]:.3f}] m)")
    return 0


def cmd_check(a) -> int:
    """Each capture's ground truth read and checked as aat-eval does: readable, valid pixels, the frames' aspect
    ratio (the first frame is decoded, as aat-eval decodes it), units against --model's focus range."""
    from ..capture.folder import frame_files
    from ..capture.raw import load_frame

    focus_range = None
    if a.model:
        from ..infer.model import DfFModel
        from ..shipped import resolve

        focus_range = DfFModel(resolve(a.model, "models"), threads=1).focus_range_m  # a path or a shipped name
    bad = 0
    for c in a.captures:
        try:
            src = find_gt(c, a.allow_outside_links)
            if src is None:
                raise CaptureError(f"{c}: no ground truth (gt.json, gt_depth_m.npy/.pfm/.tif, gt_depth_mm.png)")
            gt = load_ground_truth(src, a.max_megapixels)
            if focus_range:
                check_units(gt, focus_range)
            frames = frame_files(c)
            if frames:  # decoded as aat-eval decodes it: inside the folder, within the pixel limit
                check_inside(c, frames[0], a.allow_outside_links)
            img = load_frame(frames[0], a.max_megapixels)[0] if frames else None
            if img is not None:
                check_aspect(gt.depth_m.shape, (img.shape[1], img.shape[0]), src.depth)
        except CaptureError as e:
            bad += 1
            print(one_line(f"aat-gt: error: {e}"), file=sys.stderr)
            continue
        except MemoryError:
            bad += 1
            print(f"aat-gt: error: {c}: out of memory reading its ground truth or frames", file=sys.stderr)
            continue
        except OSError as e:  # a folder that cannot be listed
            bad += 1
            print(f"aat-gt: error: {e.filename or c}: cannot read ({e.strerror or e})", file=sys.stderr)
            continue
        for w in gt.warnings + ([] if frames else [f"{c}: no frames beside it; its aspect ratio is not checked"]):
            print(f"aat-gt: warning: {w}", file=sys.stderr)
        h, w = gt.depth_m.shape
        print(f"{src.depth}: {w}x{h} px, scale_to_m {src.scale_to_m:g}, "
              f"{100 * gt.valid_fraction:.1f} % valid{', mask ' + src.mask.name if src.mask else ''}, depth "
              f"{np.nanmin(gt.depth_m):.3f}..{np.nanmax(gt.depth_m):.3f} m (median {np.nanmedian(gt.depth_m):.3f})"
              + (f", frames {img.shape[1]}x{img.shape[0]} px" if img is not None else ""))
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    """The command; Ctrl-C or SIGTERM at any point is one line and exit status 130/143 (common.run_guarded)."""
    return run_guarded("aat-gt", _main, argv)


def _main(argv: list[str] | None) -> int:
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    safe_output_streams()
    ap = parser("aat-gt", __doc__.split("\n")[0], quiet=False)
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="{render,pose,check}")
    r = subparser(sub, "render", "ray-cast a mesh into a depth map from the camera's pose")
    r.add_argument("mesh", type=Path, metavar="MESH")
    r.add_argument("--pose", type=Path, required=True, help="camera pose JSON (docs/contracts.md)")
    r.add_argument("--lens", type=Path, required=True,
                   help="intrinsics: a DfF model .onnx or a JSON (e.g. `aat-lens info LENS --json`)")
    r.add_argument("--out", type=Path, required=True, help="depth .png (mm) or an output/capture folder")
    r.add_argument("--width", type=int, help="image width in px (default: the sensor's)")
    r.add_argument("--height", type=int, help="image height in px (default: the sensor's)")
    r.add_argument("--pupil-to-sensor-mm", type=float, default=None,
                   help="entrance pupil to sensor plane distance (default: from the intrinsics)")
    r.add_argument("--mesh-scale", type=float, default=1.0, help="mesh units to metres (0.001 for mm)")
    r.add_argument("--max-incidence-deg", type=float, default=None,
                   help="drop hits more oblique than this (ray vs surface normal)")
    r.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p = subparser(sub, "pose", "the camera pose from clicked correspondences (pixel <-> mesh point)")
    p.add_argument("--points", type=Path, required=True,
                   help='JSON {"points": [{"pixel": [u, v], "world": [x, y, z]}, ...]} or CSV u,v,x,y,z')
    p.add_argument("--lens", type=Path, required=True, help="intrinsics, as for render")
    p.add_argument("--out", type=Path, required=True, help="the pose JSON to write (render's --pose)")
    p.add_argument("--init", type=Path, help="a starting pose to refine (any pose file render reads)")
    p.add_argument("--image", type=Path, help="the frame the pixels were clicked in: writes OUT.png, the clicks "
                   "and their reprojections")
    p.add_argument("--width", type=int, help="width in px of the image the pixels were clicked in")
    p.add_argument("--height", type=int, help="height in px of the image the pixels were clicked in")
    p.add_argument("--mesh-scale", type=float, default=1.0, help="world units of the points to metres")
    p.add_argument("--force", action="store_true", help="overwrite an existing pose file")
    c = subparser(sub, "check", "read captures' ground truth as aat-eval does")
    c.add_argument("captures", nargs="+", type=Path, metavar="CAPTURE_DIR")
    c.add_argument("--model", type=Path, help="also check the units against this model's focus range")
    add_reader_options(c)
    a = ap.parse_args(argv)
    if a.cmd == "check":
        check_reader_options(c, a)
    if a.cmd == "pose" and (a.mesh_scale <= 0 or a.out.suffix.lower() != ".json"):
        ap.error("--mesh-scale must be > 0 and --out a .json path")
    if a.cmd == "render" and (a.mesh_scale <= 0 or (a.max_incidence_deg is not None
                                                    and not 0 < a.max_incidence_deg <= 90)):
        ap.error("--mesh-scale must be > 0 and --max-incidence-deg in (0, 90]")
    try:
        return {"render": cmd_render, "pose": cmd_pose, "check": cmd_check}[a.cmd](a)
    except CaptureError as e:
        print(one_line(f"aat-gt: error: {e}"), file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
