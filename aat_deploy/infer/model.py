"""An ONNX depth-from-focus model (docs/contracts.md, "DfF model"): loading, metadata, padding, tiling.

The model takes stack (B, S, 3, H, W) normalised, focus_m (B, S) ascending, and returns depth_m (B, H, W),
aif (B, 3, H, W), std_m (B, H, W). H and W must be multiples of `aat.size_multiple`: we pad with reflection
and crop back. Large images run in overlapping tiles blended with a linear ramp, so memory stays bounded (small tiles
run several to a batch, `TILE_BATCH_PX`).
Field-aware models (an input `field_xy`, metadata `aat.field_channels`) also get each pixel's normalised sensor
position; by default the stack is taken to cover the whole sensor, as the runtime's frames do.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import onnxruntime as ort

from ..confidence import ConfidenceCalibrationError, model_calibration, model_calibration_path, std_confidence
from ..errors import ModelError
from ..io.files import file_kind
from ..machine import bound_threads
from ..optics.camera import Intrinsics, model_intrinsics
from ..optics.field import pixel_fields
from ..shipped import not_shipped_note, shipped_hint
from .method import DepthMethod, DepthOutput

REQUIRED_META = ("aat.kind", "aat.lens_name", "aat.focal_length_mm", "aat.f_number", "aat.sensor_px",
                 "aat.pixel_um", "aat.focus_range_m", "aat.stack_min", "aat.stack_max", "aat.size_multiple")
SUMMARY_META = ("aat.kind", "aat.net", "aat.size", "aat.simulator", "aat.effects", "aat.lens_name", "aat.lens_hash",
                "aat.focal_length_mm", "aat.f_number", "aat.sensor_mm", "aat.sensor_px", "aat.pixel_um",
                "aat.focus_range_m", "aat.stack_min", "aat.stack_max", "aat.size_multiple",
                "aat.input_normalisation", "aat.config_hash", "aat.version", "aat.distances")


def _decode(v: str):
    try:
        return json.loads(v)
    except (json.JSONDecodeError, TypeError):
        return v


def _bad_meta(path: Path, meta: dict, key: str, want: str) -> ModelError:
    return ModelError(f"{path}: metadata {key} must be {want}, got {str(meta.get(key))[:60]!r}")


def _finite_positive(v) -> float | None:
    """float(v) if v is a JSON number (not a bool), finite and > 0, else None."""
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return None
    try:
        f = float(v)
    except OverflowError:
        return None
    return f if math.isfinite(f) and f > 0 else None


def _meta_int(path: Path, meta: dict, key: str, lo: int, hi: int) -> int:
    v = meta.get(key)
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise _bad_meta(path, meta, key, f"an integer in {lo}..{hi}")
    return v


def _meta_float(path: Path, meta: dict, key: str) -> float:
    f = _finite_positive(meta.get(key))
    if f is None:
        raise _bad_meta(path, meta, key, "a finite number > 0")
    return f


def _meta_pair(path: Path, meta: dict, key: str, integer: bool = False) -> tuple:
    """Two finite numbers > 0 (integers in 1..65536 if `integer`)."""
    v = meta.get(key)
    want = "two integers in 1..65536" if integer else "two finite numbers > 0"
    if not isinstance(v, list) or len(v) != 2:
        raise _bad_meta(path, meta, key, want)
    out = []
    for x in v:
        if integer:
            if not isinstance(x, int) or isinstance(x, bool) or not 1 <= x <= 65536:
                raise _bad_meta(path, meta, key, want)
            out.append(x)
        else:
            f = _finite_positive(x)
            if f is None:
                raise _bad_meta(path, meta, key, want)
            out.append(f)
    return tuple(out)


# tiles run together in one batch up to this many pixels (8 tiles of 128 px): faster on several threads, while a
# --tile chosen to bound memory (512 px and more) still runs one tile at a time
TILE_BATCH_PX = 8 * 128 * 128
CONTRACT_RANK = {"stack": (5, "(B, S, 3, H, W)"), "focus_m": (2, "(B, S)"), "field_xy": (4, "(B, 2, H, W)"),
                 "depth_m": (3, "(B, H, W)"), "aif": (4, "(B, 3, H, W)"), "std_m": (3, "(B, H, W)"),
                 "focus_diopters": (4, "(B, S, H, W)"), "defocus_px_per_d": (4, "(B, 1, H, W)")}


class DfFModel(DepthMethod):
    """An aat DfF ONNX model on onnxruntime's CPU provider (a `DepthMethod`): its std_m becomes a calibrated
    confidence when a `<stem>.confidence.json` lies beside it (`aat_deploy.confidence`)."""

    required_meta = REQUIRED_META
    inputs = ("stack", "focus_m")

    def __init__(self, path: str | Path, threads: int | None = None):
        path = Path(path)
        kind = file_kind(path)
        if kind == "missing":
            raise ModelError(f"{path}: no such model file{shipped_hint('models')}{not_shipped_note(path)}")
        if kind is not None:
            raise ModelError(f"{path}: is {kind}, expected an ONNX model file (.onnx)")
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = bound_threads(threads)
            opts.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:  # noqa: BLE001 (onnxruntime's pybind errors derive from Exception only)
            raise ModelError(f"{path}: not a loadable ONNX model ({str(e).splitlines()[0][:200]})") from None
        self.path = path
        raw = dict(self.session.get_modelmeta().custom_metadata_map)
        if raw.get("aat.kind") != "dff":
            raise ModelError(f"{path}: not an aat depth-from-focus model (metadata aat.kind = {raw.get('aat.kind')!r})")
        missing = [k for k in self.required_meta if k not in raw]
        if missing:
            raise ModelError(f"{path}: metadata lacks {', '.join(missing)}")
        self.meta = {k: _decode(v) for k, v in raw.items()}
        names_in = {i.name for i in self.session.get_inputs()}
        names_out = {o.name for o in self.session.get_outputs()}
        if not set(self.inputs) <= names_in or not {"depth_m", "aif", "std_m"} <= names_out:
            raise ModelError(f"{path}: inputs {sorted(names_in)} / outputs {sorted(names_out)} do not follow the "
                             f"contract ({', '.join(self.inputs)} -> depth_m, aif, std_m)")
        for io_list, what in ((self.session.get_inputs(), "input"), (self.session.get_outputs(), "output")):
            for a in io_list:  # checked at load, so a wrong model fails once (exit 2), not per capture
                want = CONTRACT_RANK.get(a.name)
                if want is not None and a.shape is not None and len(a.shape) != want[0]:
                    raise ModelError(f"{path}: {what} {a.name!r} has rank {len(a.shape)} {list(a.shape)}, the "
                                     f"contract says {want[0]} {want[1]} (docs/contracts.md)")
        self._validate_meta()
        self.field_aware = "field_xy" in names_in
        try:  # <stem>.confidence.json next to the model: its std_m as a calibrated confidence (aat_deploy.confidence)
            self.confidence_calibration = model_calibration(path)
        except ConfidenceCalibrationError as e:
            raise ModelError(str(e)) from None

    def _validate_meta(self) -> None:
        """Types, ranges and finiteness of the metadata the runtime computes with; ModelError naming the key."""
        m = self.meta
        self.size_multiple = _meta_int(self.path, m, "aat.size_multiple", 1, 4096)
        self.stack_range = (_meta_int(self.path, m, "aat.stack_min", 1, 4096),
                            _meta_int(self.path, m, "aat.stack_max", 1, 4096))
        if self.stack_range[0] > self.stack_range[1]:
            raise _bad_meta(self.path, m, "aat.stack_max", f">= aat.stack_min ({self.stack_range[0]})")
        self.sensor_px = _meta_pair(self.path, m, "aat.sensor_px", integer=True)  # (W, H)
        self.focus_range_m = _meta_pair(self.path, m, "aat.focus_range_m")
        if not self.focus_range_m[0] < self.focus_range_m[1]:
            raise _bad_meta(self.path, m, "aat.focus_range_m", "[near, far] in metres with near < far")
        if "aat.sensor_mm" in m:
            _meta_pair(self.path, m, "aat.sensor_mm")
        self.focal_length_mm = _meta_float(self.path, m, "aat.focal_length_mm")
        self.f_number = _meta_float(self.path, m, "aat.f_number")
        self.pixel_um = _meta_float(self.path, m, "aat.pixel_um")
        name = m["aat.lens_name"]
        if isinstance(name, (dict, list)) or name is None:
            raise _bad_meta(self.path, m, "aat.lens_name", "a string")
        self.lens_name = str(name)

    def describe(self) -> str:
        return f"{self.path.name} is a lens-specific model"

    def summary(self) -> dict:
        """Path and the metadata subset worth recording with results."""
        cal = model_calibration_path(self.path) if self.confidence_calibration is not None else None
        return {"path": str(self.path), **{k: self.meta[k] for k in SUMMARY_META if k in self.meta},
                "confidence_calibration": None if cal is None else str(cal)}

    def intrinsics(self, size_wh: tuple[int, int] | None = None) -> Intrinsics:
        """Pinhole intrinsics of the model's sensor (aat_deploy.optics.camera), or of the same field of view sampled on
        size_wh = (W, H) px."""
        cam = model_intrinsics(self.meta, str(self.path))
        return cam if size_wh is None or tuple(size_wh) == (cam.width, cam.height) else cam.resized(*size_wh)

    def working_size(self, frame_hw: tuple[int, int]) -> tuple[int, int]:
        """(W, H) the pipeline brings frames to: the model's sensor, whatever the frames' size."""
        return self.sensor_px

    def focal_length_px_at(self, size_wh: tuple[int, int]) -> float:
        """Focal length in pixels at the working size (the model's sensor)."""
        return self.focal_length_px

    @property
    def focal_length_px(self) -> float:
        """Focal length in pixels of the model's sensor (focal length mm / pixel pitch mm)."""
        return self.focal_length_mm / (self.pixel_um * 1e-3)

    # -- inference -------------------------------------------------------------------------------------------
    def _run(self, stack: np.ndarray, focus_m: np.ndarray, field_xy: np.ndarray | None = None) -> DepthOutput:
        """One padded run: stack (S, 3, H, W) with H, W any size (field_xy (2, H, W) for field-aware models);
        crops back to H, W."""
        return self._run_batch([stack], focus_m, [field_xy])[0]

    def _run_batch(self, stacks: list[np.ndarray], focus_m: np.ndarray, fields: list[np.ndarray | None]
                   ) -> list[DepthOutput]:
        """`_run` of stacks of one shape (S, 3, H, W) (tiles) as one batch of the graph's B axis: the same numbers
        (every sample is computed on its own) with larger tensors per operator, which multi-threaded onnxruntime
        runs faster (8 tiles of 8 x 128 x 128 in one run: ~20 % less time on 2 threads, the same on 1)."""
        _, _, h, w = stacks[0].shape
        m = self.size_multiple
        ph, pw = (-h) % m, (-w) % m
        feeds = []
        for stack, field_xy in zip(stacks, fields):
            if ph or pw:
                mode = "reflect" if ph < h and pw < w else "symmetric"
                stack = np.pad(stack, ((0, 0), (0, 0), (0, ph), (0, pw)), mode=mode)
            feeds.append(self._feeds(stack, focus_m, field_xy, ph, pw))
        batch = feeds[0] if len(feeds) == 1 else {k: np.concatenate([f[k] for f in feeds]) for k in feeds[0]}
        depth, aif, std = self.session.run(["depth_m", "aif", "std_m"], batch)
        return [DepthOutput(depth[i, :h, :w], aif[i, :, :h, :w], std[i, :h, :w]) for i in range(len(stacks))]

    def _feeds(self, stack: np.ndarray, focus_m: np.ndarray, field_xy: np.ndarray | None, ph: int, pw: int) -> dict:
        """onnxruntime's inputs for one padded stack (S, 3, H + ph, W + pw); field_xy unpadded, padded here."""
        feeds = {"stack": np.ascontiguousarray(stack[None], dtype=np.float32),
                 "focus_m": np.asarray(focus_m, np.float32)[None]}
        if self.field_aware:
            feeds["field_xy"] = _pad_linear(np.asarray(field_xy, np.float32), ph, pw)[None]
        return feeds

    def infer(self, stack: np.ndarray, focus_m: np.ndarray, tile: int | None = None, overlap: int = 32,
              progress=None, field_xy: np.ndarray | None = None) -> DepthOutput:
        """Depth, all-in-focus, uncertainty and (with a calibration) confidence for one normalised stack.

        stack: (S, 3, H, W) float32 normalised, frames sorted by focus (ascending); focus_m: (S,) metres.
        tile: tile side in pixels (rounded up to size_multiple); None or 0 = whole image at once.
        progress: optional callable(done, total) for tiles.
        field_xy: (2, H, W) normalised sensor position of each pixel, for field-aware models; default: the
        stack covers the whole sensor.
        """
        s = stack.shape[0]
        if stack.ndim != 4 or stack.shape[1] != 3 or len(focus_m) != s:
            raise ModelError(f"stack must be (S, 3, H, W) with S focus distances, got {stack.shape}, {len(focus_m)}")
        lo, hi = self.stack_range
        if not lo <= s <= hi:
            raise ModelError(f"{self.path}: the model takes {lo}..{hi} frames, the capture has {s}")
        h, w = stack.shape[2:]
        if self.field_aware and field_xy is None:
            field_xy = np.stack(pixel_fields(h, w, (h, w))).astype(np.float32)
        if not tile or (h <= tile and w <= tile):
            return self._with_confidence(self._run(stack, focus_m, field_xy))
        tile, overlap, ys, xs = tile_grid(h, w, tile, overlap, self.size_multiple)
        acc_d = np.zeros((h, w), np.float64)
        acc_s = np.zeros((h, w), np.float64)
        acc_a = np.zeros((3, h, w), np.float64)
        acc_w = np.zeros((h, w), np.float64)
        origins = [(y, x) for y in ys for x in xs]
        per_run = max(1, TILE_BATCH_PX // (tile * tile))  # every tile has one shape: min(tile, h) x min(tile, w)
        total, done = len(origins), 0
        for i in range(0, total, per_run):
            group = origins[i:i + per_run]
            outs = self._run_batch([stack[:, :, y:y + tile, x:x + tile] for y, x in group], focus_m,
                                   [None if field_xy is None else field_xy[:, y:y + tile, x:x + tile]
                                    for y, x in group])
            for (y, x), out in zip(group, outs):
                th, tw = out.depth_m.shape
                wgt = np.outer(_ramp(th, overlap, y > 0, y + th < h), _ramp(tw, overlap, x > 0, x + tw < w))
                acc_d[y:y + th, x:x + tw] += wgt * out.depth_m
                acc_s[y:y + th, x:x + tw] += wgt * out.std_m
                acc_a[:, y:y + th, x:x + tw] += wgt * out.aif
                acc_w[y:y + th, x:x + tw] += wgt
                done += 1
                if progress:
                    progress(done, total)
        acc_w = np.maximum(acc_w, 1e-12)
        return self._with_confidence(DepthOutput((acc_d / acc_w).astype(np.float32),
                                                 (acc_a / acc_w).astype(np.float32),
                                                 (acc_s / acc_w).astype(np.float32)))

    def _with_confidence(self, out: DepthOutput) -> DepthOutput:
        """The std made a calibrated confidence when the model has a calibration (aat_deploy.confidence)."""
        if self.confidence_calibration is not None:
            out.confidence = std_confidence(self.confidence_calibration, out.depth_m, out.std_m)
        return out


def tile_grid(h: int, w: int, tile: int, overlap: int, multiple: int = 1) -> tuple[int, int, list[int], list[int]]:
    """How `DfFModel.infer` tiles an H x W image: (tile side rounded up to `multiple`, overlap (at most a quarter of
    the tile), tile origins ys, xs). Tiles step by tile - overlap; the last row and column end at the image's edge."""
    tile = int(math.ceil(tile / multiple) * multiple)
    overlap = min(int(overlap), tile // 4)
    step = tile - overlap
    ys = list(range(0, max(h - tile, 0) + 1, step))
    xs = list(range(0, max(w - tile, 0) + 1, step))
    if ys[-1] + tile < h:
        ys.append(h - tile)
    if xs[-1] + tile < w:
        xs.append(w - tile)
    return tile, overlap, [max(0, y) for y in ys], [max(0, x) for x in xs]


def _pad_linear(field: np.ndarray, ph: int, pw: int) -> np.ndarray:
    """(C, H, W) coordinates padded at the bottom/right by continuing them linearly (they are linear in the
    pixel index), as training.nets.model.pad_field does in torch."""
    if pw:
        step = field[:, :, -1:] - field[:, :, -2:-1] if field.shape[2] > 1 else 0 * field[:, :, -1:]
        field = np.concatenate([field, field[:, :, -1:] + step * np.arange(1, pw + 1, dtype=field.dtype)], 2)
    if ph:
        step = field[:, -1:, :] - field[:, -2:-1, :] if field.shape[1] > 1 else 0 * field[:, -1:, :]
        k = np.arange(1, ph + 1, dtype=field.dtype)[:, None]
        field = np.concatenate([field, field[:, -1:, :] + step * k], 1)
    return field


def _ramp(n: int, overlap: int, ramp_start: bool, ramp_end: bool) -> np.ndarray:
    """Blend weights along one tile axis: linear ramps over `overlap` pixels on sides shared with a neighbour."""
    r = np.ones(n, np.float64)
    if overlap > 0:
        k = np.arange(1, overlap + 1, dtype=np.float64) / (overlap + 1)
        if ramp_start:
            r[:overlap] = np.minimum(r[:overlap], k)
        if ramp_end:
            r[-overlap:] = np.minimum(r[-overlap:], k[::-1])
    return r
