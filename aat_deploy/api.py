"""Depth from focus in memory: a focal stack and its focus distances in, depth and all-in-focus out.

    from aat_deploy.api import depth_from_focus, read_stack

    stack, focus_m = read_stack("captures/sample_rf50")     # (S, H, W, 3) linear RGB, (S,) metres
    result = depth_from_focus(stack, focus_m)               # the shipped DFVNet by default
    result = depth_from_focus(stack, focus_m, "dfv_aat", camera=(50, 1.8, 4.3))   # any camera: f mm, N, pixel um
    result = depth_from_focus(stack, focus_m, "dfv_aat", lens="lenses/canon_rf50mm_f1.8.json")  # aberration-aware
    result = depth_from_focus(stack, focus_m, method="focus")                    # classical, no trained model
    result = depth_from_focus(stack, focus_m, method="focus", calibration="mycam.json")  # your camera's map
    result.depth_m, result.aif, result.std_m, result.confidence, result.camera
    result.save("out/sample")                               # the files aat-infer writes

The same code as `aat-infer` (aat_deploy.infer.process), without the capture folder: frames from anywhere (a camera
SDK, a simulator, a video) as numpy arrays. Errors are ValueError with one line saying what is wrong.
"""

from __future__ import annotations

import warnings as _warnings
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from .anycam.model import open_model
from .capture.folder import focus_problem, read_capture
from .confidence import MIN_CONFIDENCE, mark_unknown
from .errors import CaptureError
from .infer.frames import FrameReader
from .infer.method import DepthMethod
from .infer.model import DfFModel
from .infer.outputs import DepthMaps, RecordingInputs, summary_fields, to_srgb8, write_outputs, write_summary
from .infer.process import depth_from_frames
from .io.atomic import atomic_folder, writing
from .io.color import srgb_to_linear
from .io.guard import check_output_dir
from .optics.camera import Intrinsics
from .shipped import resolve

DEFAULT_MODEL = "rf50_dfvnet_aat_field"
METHODS = ("model", "focus")  # a trained model (model=), or the classical focus method (no model)


@dataclass
class DepthResult:
    """depth_m (H, W) float32 metres from the sensor plane; aif (H, W, 3) float32 linear RGB in the stack's
    normalised units (about [0, 1]); std_m (H, W) float32 metres (uncertainty); camera: the maps' pinhole
    intrinsics (aat_deploy.optics.camera); focus_m (S,) the focus distances used, near to far; warnings: one line each;
    confidence (H, W) float32, the chance that the depth is within 10 % of the truth (aat_deploy.confidence), or
    None for a model without a calibration; unknown: the unknown share and threshold (NaN in depth_m)."""

    depth_m: np.ndarray
    aif: np.ndarray
    std_m: np.ndarray
    camera: Intrinsics
    focus_m: np.ndarray
    model: dict
    warnings: list[str] = field(default_factory=list)
    frames: np.ndarray | None = field(default=None, repr=False)  # (S, 3, h, w) what the model saw
    confidence: np.ndarray | None = None
    unknown: dict | None = None

    @property
    def aif_srgb8(self) -> np.ndarray:
        """The all-in-focus image as (H, W, 3) uint8 sRGB."""
        return to_srgb8(self.aif)

    def save(self, folder: str | Path, *, force: bool = False, recording: bool = True) -> Path:
        """Write the output files aat-infer writes (docs/contracts.md, "Runtime outputs") into `folder`, whole
        or not at all; an existing folder is replaced only with force, and only an earlier output."""
        folder = Path(folder)
        try:
            check_output_dir(folder, [], force, tool="aat-infer")
        except CaptureError as e:
            raise ValueError(str(e)) from None
        maps = DepthMaps(self.depth_m, self.aif.transpose(2, 0, 1), self.std_m, self.confidence)
        rec = RecordingInputs(self.frames, self.focus_m) if recording and self.frames is not None else None
        with writing(folder), atomic_folder(folder, force, "aat-infer") as tmp:
            info = write_outputs(tmp, maps, self.camera, rec)
            write_summary(tmp, {"source": "aat_deploy.api", **summary_fields(info, self.camera, self.focus_m, self.model,
                                                                            self.unknown, self.warnings)})
        return folder


@lru_cache(maxsize=4)
def load_model(model: str | Path = DEFAULT_MODEL, threads: int | None = None) -> DfFModel:
    """A DfF model by path or shipped name (cached: loading takes a moment); the any-camera model (`dfv_aat`) as
    a `FocusMapModel` not yet told its camera."""
    try:
        return open_model(resolve(model, "models"), threads=threads)
    except CaptureError as e:
        raise ValueError(str(e)) from None


def _method(model, method: str, threads: int | None) -> DepthMethod:
    """The depth method `model` and `method` name: a DepthMethod as given, the classical focus method, or a DfF
    model by name or path (default: the shipped main model)."""
    if isinstance(model, str) and model == "focus":  # the older spelling of method="focus"
        _warnings.warn('depth_from_focus(..., "focus") is now depth_from_focus(..., method="focus")',
                       DeprecationWarning, stacklevel=3)
        model, method = None, "focus"
    if method not in METHODS:
        raise ValueError(f"method: {method!r}, expected one of {', '.join(METHODS)}")
    if isinstance(model, DepthMethod):
        return model
    if method == "focus":
        if model is not None:
            raise ValueError("model: method='focus' runs no trained model (give one of them)")
        from .focus.runner import FocusMethod

        return FocusMethod()
    return load_model(DEFAULT_MODEL if model is None else model, threads)


def read_stack(folder: str | Path, use_exiftool: bool = True, *, max_megapixels: float | None = None,
               allow_outside_links: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A capture folder's frames as (S, H, W, 3) float32 linear RGB and their focus distances (S,) in metres,
    near to far, read as aat-infer reads them (RAW through LibRaw, images decoded from sRGB; the kind of each file
    from its content). max_megapixels: the pixel limit per frame (default $AAT_MAX_MEGAPIXELS or 200): a header
    claiming more is refused before decoding. allow_outside_links: follow symlinks leading out of the folder.
    Errors (including running out of memory) are a ValueError with one line naming the file or folder."""
    try:
        cap = read_capture(folder, use_exiftool=use_exiftool, max_megapixels=max_megapixels,
                           allow_outside_links=allow_outside_links)
        frames = sorted(cap.frames, key=lambda f: f.focus_m)
        images = FrameReader([f.path for f in frames], max_megapixels).read_all()  # aat-infer's reader
        return images, np.array([f.focus_m for f in frames], np.float64)
    except CaptureError as e:
        raise ValueError(str(e)) from None
    except MemoryError:
        raise ValueError(f"{folder}: out of memory reading its frames (lower max_megapixels, or read fewer or "
                         "smaller frames)") from None


def _frames(stack, srgb: bool | None) -> list[np.ndarray]:
    """(S, H, W, 3) or a sequence of (H, W, 3) -> list of float32 linear RGB frames."""
    if isinstance(stack, (str, bytes, dict)) or not hasattr(stack, "__iter__"):
        raise ValueError(f"stack: expected an (S, H, W, 3) array or a sequence of (H, W, 3) frames, got "
                         f"{type(stack).__name__}")
    frames = [np.asarray(f) for f in stack]
    if not frames:
        raise ValueError("stack: no frames")
    shape = frames[0].shape
    if len(shape) != 3 or shape[2] != 3 or min(shape[:2]) < 2:
        raise ValueError(f"stack: frames must be (H, W, 3) RGB, got {shape}")
    if any(f.shape != shape for f in frames):
        raise ValueError(f"stack: frames of different shapes ({shape} and others)")
    out = []
    for f in frames:
        if np.issubdtype(f.dtype, np.integer):  # 8/16-bit images are sRGB-encoded
            x = srgb_to_linear(f.astype(np.float32) / np.iinfo(f.dtype).max)
        elif np.issubdtype(f.dtype, np.floating):
            x = srgb_to_linear(f) if srgb else f.astype(np.float32)
        else:
            raise ValueError(f"stack: unsupported dtype {f.dtype}")
        if not np.isfinite(x).all() or (x < 0).any():
            raise ValueError("stack: values must be finite and >= 0")
        out.append(np.ascontiguousarray(x, dtype=np.float32))
    return out


def depth_from_focus(stack, focus_m, model: str | Path | DepthMethod | None = None, *, method: str = "model",
                     srgb: bool | None = None,
                     align: bool = False, native_res: bool = False, tile: int | None = None,
                     threads: int | None = None, camera=None, lens: str | Path | None = None,
                     psf: str | Path | None = None, calibration: str | Path | None = None,
                     min_confidence: float = MIN_CONFIDENCE) -> DepthResult:
    """Depth (m from the sensor), all-in-focus and uncertainty of one focal stack.

    stack: (S, H, W, 3) array (or S arrays (H, W, 3)): float = linear RGB of any non-negative scale (srgb=True:
    sRGB-encoded in [0, 1]); uint8/uint16 = sRGB-encoded images. focus_m: (S,) focus distance of each frame in
    metres from the sensor plane, any order (frames are sorted near to far). model: a shipped model's name, a
    path, or a loaded depth method (`aat_deploy.infer.method.DepthMethod`: a DfFModel, a FocusMethod with your
    settings); None: the shipped main model. The frames are centre-cropped to the model's sensor aspect and resized to its
    size; native_res=True returns maps at the frames' own size (the crop), upsampled guided by the all-in-focus
    image. align: affine alignment against focus breathing; tile: run in tiles of this many pixels.
    The any-camera model (model="dfv_aat") also needs the camera: camera=(focal length mm, f-number, pixel pitch um
    of the frames as given), or a lens file (lens=), PSF surrogate (psf=) or calibration (calibration=), which
    also make it aberration-aware (what each frame has in focus at each pixel); frames span the sensor.
    method="focus": the classical method, no trained model (`aat-infer --method focus`), at a working size it
    chooses from the stack; lens=, psf= or calibration= (your camera's, from `aat-calibrate fit`: a path or a
    `CameraCalibration`) make it aberration-aware. (model="focus", the older spelling, still works and warns.)
    The result's confidence (H, W) is the chance that the depth is within 10 % of the truth: the classical
    method's always, a model's when a calibration ships beside it (else None).
    min_confidence: depth whose calibrated confidence is below it is NaN (unknown); 0 keeps every pixel."""
    frames = _frames(stack, srgb)
    try:
        focus = np.asarray(focus_m, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"focus_m: expected one focus distance in metres per frame, got {type(focus_m).__name__}"
                         ) from None
    if len(focus) != len(frames):
        raise ValueError(f"focus_m: {len(focus)} distances for {len(frames)} frames")
    for i, f in enumerate(focus):
        why = focus_problem(float(f))
        if why is not None:
            raise ValueError(f"focus_m[{i}] = {float(f):g}: not a focus distance in metres ({why})")
    if len(set(np.round(focus, 6))) != len(focus):
        raise ValueError("focus_m: two frames have the same focus distance")
    net = _method(model, method, threads)
    lo, hi = net.stack_range
    if not lo <= len(frames) <= hi:
        raise ValueError(f"stack: {len(frames)} frames, the {net.noun} takes {lo}..{hi}")
    if tile is not None and (not isinstance(tile, int) or tile < 16):
        raise ValueError("tile: an integer >= 16 (px) or None")
    order = np.argsort(focus, kind="stable")
    frames, focus = [frames[i] for i in order], focus[order].astype(np.float32)
    try:
        net = net.for_arrays(frames[0].shape[:2], focus, camera=camera, lens=lens, psf=psf, calibration=calibration)
        res = depth_from_frames(frames, focus, net, align=align, tile=tile, native=native_res)
    except CaptureError as e:
        raise ValueError(str(e)) from None
    m = res.maps
    depth, unknown = mark_unknown(m.depth_m, m.confidence, min_confidence)
    return DepthResult(depth, np.ascontiguousarray(m.aif.transpose(1, 2, 0)), m.std_m, res.camera,
                       focus.astype(np.float64), net.summary(), res.warnings, res.stack, m.confidence, unknown)


__all__ = ["DepthResult", "depth_from_focus", "load_model", "read_stack"]
