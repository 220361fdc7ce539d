"""Decoded frames -> depth maps: the part of aat-infer that works on arrays, shared by the capture pipeline
(aat_deploy.infer.pipeline) and the Python API (aat_deploy.api).

Steps: fit every frame to the model's sensor (centre crop to its aspect, resize), optional alignment against
focus breathing, normalisation (docs/contracts.md), inference (tiled if asked), and, with native=True, depth and
all-in-focus at the frames' own resolution (aat_deploy.infer.upsample).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import CaptureError
from ..optics.camera import Intrinsics
from ..progress import Progress, say, track
from .geometry import align_stack, equalise_exposure, fit_to_sensor, sensor_crop
from .method import DepthMethod
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
    frame_hw: tuple[int, int] | None = None  # (H, W) of the frames as given (before fitting)

    @property
    def working_size(self) -> tuple[int, int]:
        """(W, H) the method worked at."""
        return self.working.depth_m.shape[1], self.working.depth_m.shape[0]


Frame = np.ndarray | Callable[[], np.ndarray]  # a frame, or a function that decodes it (the pipeline: its file)


def _decoded(images: list[Frame], labels: list[str], name: str, quiet: bool):
    """Yield (index, frame (H, W, 3) float32) decoding lazily, with a progress bar for decoded files; frames of
    another size than the first are refused (one line naming both)."""
    size0 = None
    decoding = any(callable(im) for im in images)
    items = enumerate(images)
    if decoding:
        items = track(items, len(images), f"  {name}: decode", "frame", quiet)
    for i, im in items:
        img = im() if callable(im) else im
        if size0 is None:
            size0 = img.shape[:2]
        elif img.shape[:2] != size0:
            raise CaptureError(f"{labels[i]}: frame is {img.shape[1]}x{img.shape[0]} px, {labels[0]} is "
                               f"{size0[1]}x{size0[0]}: frames of different sizes")
        yield i, img


def _reduce(img: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    """The whole frame resized to size_wh (area averaging; the focus method keeps the frame's aspect)."""
    if (img.shape[1], img.shape[0]) == tuple(size_wh):
        return img
    return cv2.resize(np.ascontiguousarray(img), tuple(size_wh), interpolation=cv2.INTER_AREA).astype(np.float32)


def fitted_frames(images: list[Frame], model: DepthMethod, *, native: bool = False, name: str = "stack",
                  labels: list[str] | None = None, quiet: bool = True) -> tuple[list, dict, tuple, list | None, dict]:
    """The frames at the method's working size, decoded one at a time so that no native-size stack is ever held.

    images: S frames (H, W, 3) float32 linear RGB, or functions returning them (decoded on demand). A DfF model
    (or the focus method with a fixed size) fixes the working size from the first frame: each frame is fitted as
    it comes (`fit_to_sensor`). A method's automatic size (`DepthMethod.auto`: the focus method's) needs the
    stack's blur step first (`aat_deploy.focus.scale`): tiles are cut from each native frame and the frame is kept
    reduced by a factor the rule can only exceed (`DepthMethod.pre_reduction`); once the step is known the kept frames are
    reduced to the chosen size (or, when the rule wants less reduction than that, decoded again).
    Returns (frames (h, w, 3) float32, geometry (fit_to_sensor's), native size (H, W), native frames as float16
    (the whole frames, for `native_frames`) when native=True else None, the resolution choice (focus method))."""
    labels = labels or [f"frame {i}" for i in range(len(images))]
    auto = model.auto
    out, natives, regions, choice = [], [] if native else None, [], {}
    sampler = size0 = pre_wh = size_wh = None
    for i, img in _decoded(images, labels, name, quiet):
        if size0 is None:
            size0 = img.shape[:2]
            if auto:
                sampler = model.tile_sampler(size0)
                pre_wh = model.pre_reduction(size0)
            else:
                size_wh = model.working_size(size0)
        if auto:
            regions.append(sampler.sample(img))
            out.append(_reduce(img, pre_wh))
        else:
            out.append(fit_to_sensor(img, size_wh)[0])
        if natives is not None:
            natives.append(img.astype(np.float16))
        del img
    if not auto:
        return out, sensor_crop(size0, size_wh), size0, natives, choice
    size_wh, choice = model.choose_size(size0, [np.stack(lev) for lev in zip(*regions)])
    if size_wh[0] > pre_wh[0] or size_wh[1] > pre_wh[1]:  # less reduction than kept: from the native frames again
        out = [_reduce(img, size_wh) for _, img in _decoded(images, labels, name, True)]
        choice["decoded_twice"] = True
    else:
        out = [_reduce(im, size_wh) for im in out]
    h0, w0 = size0
    return out, {"crop_xywh": [0, 0, int(w0), int(h0)], "scale": size_wh[0] / w0}, size0, natives, choice


def depth_from_frames(images: list[Frame], focus_m: np.ndarray, model: DepthMethod, *, align: bool = False,
                      tile: int | None = None, native: bool = False, name: str = "stack",
                      where: str | None = None, labels: list[str] | None = None, quiet: bool = True,
                      lap: Callable[[str], None] = lambda stage: None) -> StackResult:
    """Depth, all-in-focus and uncertainty of one focal stack.

    images: S frames (H, W, 3) float32 linear RGB of one size, or functions that decode them (`fitted_frames`),
    sorted by focus near to far; focus_m: (S,) metres from the sensor, ascending. native: maps at the frames' own
    size (their crop to the sensor's aspect) instead of the working size. name names the stack in progress lines,
    where (default: name) in warnings, labels (one per frame) the frames; lap(stage) is called after each stage
    (decode, geometry, align, normalise, infer, native) for timings."""
    warnings: list[str] = []
    where = name if where is None else where
    images, geometry, size0, originals, choice = fitted_frames(images, model, native=native, name=name,
                                                               labels=labels, quiet=quiet)
    lap("decode")
    h_px, w_px = images[0].shape[:2]
    warnings += model.frame_warnings(size0, where)
    if tuple(geometry["crop_xywh"][2:]) == (w_px, h_px):
        originals = None  # native: nothing to do when the frames are the working size
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
    bar = Progress(None, f"  {name}: inference in tiles of {tile} px", "tile", leave=False) if tiled and not quiet else None
    res = model.infer(stack, focus_m, tile=tile, progress=bar)
    warnings += res.warnings
    lap("infer")

    info = res.info
    if choice:
        info = {**(info or {}), "working_resolution": choice}
    maps = working = DepthMaps(res.depth_m, res.aif, res.std_m, res.confidence)
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
    return StackResult(maps, camera, working, stack, geometry, align_info, warnings, info, tuple(size0))


def native_frames(images: list[np.ndarray], geometry: dict, align_info: list[dict] | None, scale: float,
                  size_wh: tuple[int, int]) -> list[np.ndarray]:
    """The decoded frames (H0, W0, 3) cropped as fit_to_sensor cropped them, aligned with the working size's
    warps (scaled to the crop's pixels) if any, and normalised with the stack's divisor; float16 (H, W, 3), one
    frame at a time in float32 (at 12 MP a float32 frame is 150 MB: the stack is kept at half that). The entries of
    `images` are released (set to None) as they are used: pass a list of your own."""
    x0, y0, cw, ch = geometry["crop_xywh"]
    out = []
    for i in range(len(images)):
        im, images[i] = images[i], None
        crop = np.ascontiguousarray(im[y0:y0 + ch, x0:x0 + cw], dtype=np.float32)
        if align_info is not None:
            m = native_warp(np.asarray(align_info[i]["matrix"], np.float64), (cw, ch), size_wh)
            crop = cv2.warpAffine(crop, m, (cw, ch), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_REFLECT)
        out.append(np.clip(crop / np.float32(scale), 0.0, 1.0).astype(np.float16))
    return out


def native_warp(m: np.ndarray, native_wh: tuple[int, int], work_wh: tuple[int, int]) -> np.ndarray:
    """A 2x3 affine warp in working-size pixels as the same warp in native pixels (pixel centres matched as
    cv2.resize matches them: x_work = sx (x_native + 0.5) - 0.5)."""
    sx, sy = work_wh[0] / native_wh[0], work_wh[1] / native_wh[1]
    a = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1]])
    full = np.vstack([m, [0, 0, 1]])
    return (np.linalg.inv(a) @ full @ a)[:2].astype(np.float32)
