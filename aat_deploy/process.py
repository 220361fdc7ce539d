"""Decoded frames -> depth maps: the part of aat-infer that works on arrays, shared by the capture pipeline
(aat_deploy.pipeline) and the Python API (aat_deploy.api).

Steps: fit every frame to the model's sensor (centre crop to its aspect, resize), optional alignment against
focus breathing, normalisation (docs/contracts.md), inference (tiled if asked), and, with native=True, depth and
all-in-focus at the frames' own resolution (aat_deploy.upsample).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from tqdm import tqdm

from .camera import Intrinsics
from .geometry import align_stack, equalise_exposure, fit_to_sensor
from .model import DfFModel
from .normalise import normalise_scale, normalise_stack
from .outputs import DepthMaps
from .upsample import native_maps


@dataclass
class StackResult:
    """maps and their camera (the model's sensor size, or the frames' with native=True); working: the model's own
    output at its sensor size; stack: the normalised frames the model saw (S, 3, h, w), near to far; geometry:
    the crop and scale (fit_to_sensor); align_info per frame or None; warnings (one line each)."""

    maps: DepthMaps
    camera: Intrinsics
    working: DepthMaps
    stack: np.ndarray
    geometry: dict
    align_info: list[dict] | None
    warnings: list[str] = field(default_factory=list)
    info: dict | None = None  # what the method reports about itself (the focus method's settings, placements)

    @property
    def working_size(self) -> tuple[int, int]:
        """(W, H) the method worked at."""
        return self.working.depth_m.shape[1], self.working.depth_m.shape[0]


class _TileBar:
    """progress(done, total) for DfFModel.infer's tiles as a tqdm bar (created at the first tile)."""

    def __init__(self, desc: str):
        self.desc, self.bar = desc, None

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            self.bar = tqdm(total=total, desc=f"  {self.desc}", unit="tile", leave=False, file=sys.stderr)
        self.bar.update(done - self.bar.n)
        if done >= total:
            self.bar.close()


def say(quiet: bool, msg: str) -> None:
    """A progress line on stderr for a stage without steps to count (one onnxruntime call, writing files)."""
    if not quiet:
        print(f"  {msg}", file=sys.stderr, flush=True)


def depth_from_frames(images: list[np.ndarray], focus_m: np.ndarray, model: DfFModel, *, align: bool = False,
                      tile: int | None = None, native: bool = False, name: str = "stack",
                      where: str | None = None, labels: list[str] | None = None, quiet: bool = True,
                      lap: Callable[[str], None] = lambda stage: None) -> StackResult:
    """Depth, all-in-focus and uncertainty of one focal stack.

    images: S frames (H, W, 3) float32 linear RGB of one size, sorted by focus near to far; focus_m: (S,) metres
    from the sensor, ascending. native: maps at the frames' own size (their crop to the sensor's aspect) instead of
    the model's sensor size. name names the stack in progress lines, where (default: name) in warnings, labels
    (one per frame) the frames; lap(stage) is called after each stage (geometry, align, normalise, infer, native) for timings."""
    warnings: list[str] = []
    where = name if where is None else where
    size0 = images[0].shape[:2]
    w_px, h_px = model.working_size(size0)  # a model's sensor; the focus method's frame size (or --max-side)
    if getattr(model, "kind", "model") == "method":
        warnings += model.frame_warnings(size0, where)
    fitted = [fit_to_sensor(im, (w_px, h_px)) for im in images]
    geometry = fitted[0][1]
    # native: keep the decoded frames for the native maps (nothing to do when they are the working size)
    originals = images if native and tuple(geometry["crop_xywh"][2:]) != (w_px, h_px) else None
    images = [im for im, _ in fitted]
    if abs(size0[1] / size0[0] - w_px / h_px) > 0.01 * (w_px / h_px):
        warnings.append(f"{where}: frames are {size0[1]}x{size0[0]} px, the model's sensor is {w_px}x{h_px}: "
                        "centre-cropped to its aspect ratio")
    lap("geometry")

    align_info = None
    if align:
        images, align_info = align_stack(images, ref=len(images) // 2)
        images, gains = equalise_exposure(images, ref=len(images) // 2)
        for a, g in zip(align_info, gains):
            a["exposure_gain"] = g
        names = labels or [f"frame {i}" for i in range(len(images))]
        bad = [names[i] for i, a in enumerate(align_info) if not a["converged"]]
        if bad:
            warnings.append(f"{where}: alignment did not converge for {', '.join(bad)} (left unaligned)")
    lap("align")

    raw = np.stack([im.transpose(2, 0, 1) for im in images])
    scale = float(normalise_scale(raw))
    stack = normalise_stack(raw)
    del images, raw
    lap("normalise")

    s, _, h, w = stack.shape
    tiled = bool(tile) and max(h, w) > tile
    say(quiet or tiled, f"{name}: inference, {s} frames of {w}x{h} px")
    bar = _TileBar(f"{name}: inference in tiles of {tile} px") if tiled and not quiet else None
    res = model.infer(stack, focus_m, tile=tile, progress=bar)
    warnings += getattr(res, "warnings", [])
    lap("infer")

    maps = working = DepthMaps(res.depth_m, res.aif, res.std_m, getattr(res, "confidence", None))
    camera = model.intrinsics((w_px, h_px))
    if originals is not None:
        say(quiet, f"{name}: depth and all-in-focus at the capture's "
                   f"{geometry['crop_xywh'][2]}x{geometry['crop_xywh'][3]} px")
        natives = native_frames(originals, geometry, align_info, scale, (w_px, h_px))
        depth_n, aif_n, std_n = native_maps(res.depth_m, res.std_m, natives, focus_m)
        del natives
        conf = working.confidence
        if conf is not None:
            conf = cv2.resize(conf.astype(np.float32), depth_n.shape[::-1], interpolation=cv2.INTER_LINEAR)
        maps = DepthMaps(depth_n, aif_n, std_n, conf)
        camera = camera.resized(depth_n.shape[1], depth_n.shape[0])
    lap("native")
    return StackResult(maps, camera, working, stack, geometry, align_info, warnings, getattr(res, "info", None))


def native_frames(images: list[np.ndarray], geometry: dict, align_info: list[dict] | None, scale: float,
                  size_wh: tuple[int, int]) -> list[np.ndarray]:
    """The decoded frames (H0, W0, 3) cropped as fit_to_sensor cropped them, aligned with the working size's
    warps (scaled to the crop's pixels) if any, and normalised with the stack's divisor."""
    x0, y0, cw, ch = geometry["crop_xywh"]
    out = []
    for i, im in enumerate(images):
        crop = np.ascontiguousarray(im[y0:y0 + ch, x0:x0 + cw])
        if align_info is not None:
            m = native_warp(np.asarray(align_info[i]["matrix"], np.float64), (cw, ch), size_wh)
            crop = cv2.warpAffine(crop, m, (cw, ch), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_REFLECT)
        out.append(np.clip(crop / np.float32(scale), 0.0, 1.0).astype(np.float32))
    return out


def native_warp(m: np.ndarray, native_wh: tuple[int, int], work_wh: tuple[int, int]) -> np.ndarray:
    """A 2x3 affine warp in working-size pixels as the same warp in native pixels (pixel centres matched as
    cv2.resize matches them: x_work = sx (x_native + 0.5) - 0.5)."""
    sx, sy = work_wh[0] / native_wh[0], work_wh[1] / native_wh[1]
    a = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1]])
    full = np.vstack([m, [0, 0, 1]])
    return (np.linalg.inv(a) @ full @ a)[:2].astype(np.float32)
