"""The virtual camera: simulated focal stacks saved as a capture folder a real camera could have written.

One DNG per frame (RGGB Bayer mosaic, 14-bit with a black level, colour matrix, EXIF SubjectDistance, focal
length, F-number, Make/Model/LensModel) plus the ground truth beside it (docs/contracts.md): the runtime then
reads simulated captures through the same path as real ones.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from aat_deploy.capture.dng import write_dng
from aat_deploy.io.atomic import atomic_folder
from aat_deploy.io.color import linear_to_srgb
from aat_deploy.io.depth_png import encode_mm16
from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_data

# XYZ (D65) -> linear sRGB: the rendered RGB has sRGB primaries, so this is the camera's ColorMatrix1.
XYZ_TO_SRGB = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])
BLACK_LEVEL, WHITE_LEVEL = 512, 16383  # 14-bit sensor
# How the virtual sensor's RAW files describe themselves (every DNG it writes; raw_pipeline's twin frames too).
SENSOR_DNG = {"cfa_pattern": "RGGB", "black_level": BLACK_LEVEL, "white_level": WHITE_LEVEL,
              "color_matrix": XYZ_TO_SRGB}
MAKE, MODEL = "aat", "virtual camera"


def mosaic_rggb(rgb: np.ndarray) -> np.ndarray:
    """(3, H, W) -> (H, W): R at even rows/cols, B at odd rows/cols, G elsewhere."""
    _, h, w = rgb.shape
    out = np.empty((h, w), dtype=rgb.dtype)
    out[0::2, 0::2] = rgb[0, 0::2, 0::2]
    out[0::2, 1::2] = rgb[1, 0::2, 1::2]
    out[1::2, 0::2] = rgb[1, 1::2, 0::2]
    out[1::2, 1::2] = rgb[2, 1::2, 1::2]
    return out


def to_dn(linear: np.ndarray) -> np.ndarray:
    """Linear signal (1.0 = white level) to uint16 raw DN with the black level added (clipped like a sensor)."""
    dn = np.round(BLACK_LEVEL + np.asarray(linear, dtype=np.float64) * (WHITE_LEVEL - BLACK_LEVEL))
    return np.clip(dn, 0, WHITE_LEVEL).astype(np.uint16)


def write_capture(out_dir, frames: np.ndarray, focus_reported_m, lens: Lens, gt_depth_m: np.ndarray | None,
                  aif_linear: np.ndarray | None, info: dict, force: bool = False, frame_format: str = "dng",
                  tool: str = "aat-render") -> Path:
    """Write a capture folder atomically. frames (S, 3, H, W) linear (1.0 = white level), H and W even;
    focus_reported_m (S,) what the EXIF says; gt_depth_m (H, W) metres (0 = unknown); aif_linear (3, H, W).
    frame_format: "dng" (a RAW as a camera writes it: Bayer mosaic, 14-bit, EXIF focus) or "tiff" (float32 linear
    RGB with the focus distances in capture.json: the frames exactly as rendered, with no RAW pipeline). With force an
    existing folder is replaced only if it is an earlier output of `tool` (aat_deploy.io.marker)."""
    if frame_format not in ("dng", "tiff"):
        raise ValueError(f"frame_format must be 'dng' or 'tiff', got {frame_format!r}")
    out_dir = Path(out_dir)
    if out_dir.exists() and not force:
        raise FileExistsError(f"{out_dir}: exists (use --force to overwrite)")
    frames = np.asarray(frames)
    _, c, h, w = frames.shape
    if c != 3 or h % 2 or w % 2:
        raise ValueError(f"frames must be (S, 3, H, W) with even H, W; got {frames.shape}")
    p = paraxial_data(lens)
    with atomic_folder(out_dir, force, tool) as tmp:  # written whole or not at all; stale leftovers cleaned
        sidecar = []
        for i, (fr, f) in enumerate(zip(frames, np.asarray(focus_reported_m, dtype=np.float64))):
            if frame_format == "tiff":
                name = f"frame_{i:02d}.tif"
                rgb = np.ascontiguousarray(np.transpose(fr, (1, 2, 0))[..., ::-1], dtype=np.float32)  # BGR
                if not cv2.imwrite(str(tmp / name), rgb):
                    raise OSError(f"{tmp / name}: OpenCV could not write the float TIFF")
                sidecar.append({"file": name, "focus_m": float(f)})
                continue
            write_dng(tmp / f"frame_{i:02d}.dng", to_dn(mosaic_rggb(fr)), **SENSOR_DNG,
                      subject_distance_m=round(float(f), 4), focal_length_mm=round(p.efl_mm, 2),
                      f_number=round(p.fno, 2), make=MAKE, model=MODEL, lens_model=lens.name)
        if sidecar:
            (tmp / "capture.json").write_text(json.dumps({"frames": sidecar}, indent=1) + "\n")
        if gt_depth_m is not None:
            g = np.where(np.isfinite(gt_depth_m) & (gt_depth_m > 0), gt_depth_m, 0).astype(np.float32)
            np.save(tmp / "gt_depth_m.npy", g)
            cv2.imwrite(str(tmp / "gt_depth_mm.png"), encode_mm16(g)[0])
        if aif_linear is not None:
            srgb = linear_to_srgb(np.transpose(aif_linear, (1, 2, 0)))
            cv2.imwrite(str(tmp / "gt_aif.png"), np.round(srgb[..., ::-1] * 255).astype(np.uint8))
        (tmp / "virtual_camera.json").write_text(json.dumps(info, indent=2) + "\n")
        for f in tmp.iterdir():
            f.chmod(0o644)
    return out_dir


def shoot(lens: Lens, rgb: np.ndarray, depth_m: np.ndarray, focus_true_m, effects=(), psf=None, seed: int = 0,
          cell_px: int = 64, workers: int = 1, layer_blur_px: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A focal stack of a scene through the lens, torch-free: rgb (3, H, W) linear and depth_m (H, W) metres
    from the sensor (> 0) at the lens's full sensor; focus_true_m (S,) where the camera really focused. effects:
    registered effect names/specs (`aat_deploy.render.effects.parse`), rendered with the lens's PSFs from psf
    (its surrogate .onnx, or an `OnnxSource`; None = the thin-lens Gaussian, focusing paraxially). Returns frames (S, 3, H, W) float32
    linear as the sensor records them and the focus distances (S,) the metadata reports (the effects'
    `report_focus`). layer_blur_px: the depth layers' spacing in px of thin-lens blur (`LayeredConfig`). Effects
    that need torch raise `NeedsTorch` (`aat-render` renders those)."""
    from aat_deploy.render import effects as fx
    from aat_deploy.render.layered import LayeredConfig
    from aat_deploy.render.optical import optical_stack
    from aat_deploy.render.sources import GaussianSource, OnnxSource

    s = lens.sensor
    if rgb.shape[1:] != (s.height_px, s.width_px) or depth_m.shape != rgb.shape[1:]:
        raise ValueError(f"scene {rgb.shape} / {depth_m.shape} is not the lens's sensor {s.height_px}x{s.width_px}")
    src = psf if psf is None or isinstance(psf, OnnxSource) else OnnxSource(psf, lens, threads=workers)
    chosen = fx.parse(list(effects) if not isinstance(effects, str) else effects)
    if src is not None and "aberrations" not in [e.name for e in chosen]:
        chosen = fx.parse(["aberrations"] + [fx.spec(e) for e in chosen])
    from aat_deploy.optics.focus_table import paraxial_focus_table

    # the lens's focusing (sensor tilt, tolerances): the surrogate's real-ray table, else the paraxial one
    table = src.focus_table() if src is not None else None
    table = table if table is not None else paraxial_focus_table(lens)
    ctx = fx.SimContext(lens, (s.height_px, s.width_px), (0, 0), src, table,
                        src.exit_pupil_z_mm() if src is not None else None)
    for e in chosen:
        why = e.torch_reason(ctx) or ("it needs the lens's PSFs (give psf)" if e.uses_lens_psfs and src is None
                                      else "")
        if why:
            raise fx.NeedsTorch(f"effect {e.name!r}: {why}")
    focus = np.asarray(focus_true_m, np.float64).ravel()
    rng = np.random.default_rng(seed)
    frames = optical_stack(chosen, GaussianSource(lens), np.ascontiguousarray(rgb, np.float32),
                           np.ascontiguousarray(depth_m, np.float32), focus, ctx, LayeredConfig(cell_px=cell_px, layer_blur_px=layer_blur_px),
                           workers)
    frames = fx.post_stack(chosen, frames, focus, ctx, rng)
    reported = focus.copy()
    for e in chosen:
        reported = e.report_focus(reported, ctx, rng)
    return np.asarray(frames, np.float32), reported
