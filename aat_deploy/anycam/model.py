"""The any-camera ONNX model (`models/dfv_aat.onnx`, docs/contracts.md "DfF model with focus maps").

Inputs: stack (B, S, 3, H, W) normalised (frames near -> far), focus_diopters (B, S, H, W), defocus_px_per_d
(B, 1, H, W); outputs depth_m, aif, std_m as every DfF model. It has no lens or sensor of its own: before it runs
on a capture it is told the camera (`for_capture`: optics from `--camera`, the lens / calibration, or EXIF) and
how frames map to in-focus distances (`aat_deploy.anycam.maps.FocusMapping`); then it behaves as a `DfFModel` for
the pipeline (working size, intrinsics, tiled inference).

Working size: the frames' own, reduced (area averaging) so the longer side is at most `max_side` px and the
thin-lens blur growth at most `K_MAX_PX_PER_D` px per diopter (the largest the net was trained on with margin):
more pixels than that only make the blur wider than the net's reach.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import onnxruntime as ort

from ..errors import CaptureError, ModelError
from ..infer.model import DfFModel, _meta_int
from ..optics.camera import Intrinsics
from .maps import FocusMapping
from .optics import CameraOptics, from_exif

REQUIRED = ("aat.kind", "aat.inputs", "aat.stack_min", "aat.stack_max", "aat.size_multiple")
K_MAX_PX_PER_D = 48.0
DEFAULT_MAX_SIDE = 1024


def own_tiles(tile_px: int) -> tuple[int, int]:
    """(tile, overlap) px the runtime runs frames larger than an any-camera model's aat.tile_px in: tiles of that side
    (the net is worse the farther a pixel lies from the border of the images it trained on), an eighth of it
    overlapping and blended. An eighth (16 px of 128) scored 0.99 [0.97, 1.02]x the MAE of a quarter's overlap on 20
    RF50 validation stacks (1.00 [0.98, 1.02]x on 60), 1.01 [0.99, 1.03]x on the held-out paper lens, and runs 1.44
    instead of 1.87 px per frame pixel at 960 x 640; 8 px failed the held-out check (BENCHMARKS.md, the any-camera
    model's speed; benchmarks/probes/anycam_tiles.py --overlaps)."""
    return int(tile_px), int(tile_px) // 8


class FocusMapModel(DfFModel):
    """`DfFModel` for the any-camera model; `for_capture` binds a camera and mapping (a copy)."""

    required_meta = REQUIRED
    inputs = ("stack", "focus_diopters", "defocus_px_per_d")

    def __init__(self, path: str | Path, threads: int | None = None, mapping: FocusMapping | None = None,
                 camera: str | None = None, max_side: int = DEFAULT_MAX_SIDE):
        super().__init__(path, threads)
        self.optics: CameraOptics | None = None
        self._focus_mid_m = 2.0
        self.configure(mapping, camera, max_side)

    def configure(self, mapping: FocusMapping | None = None, camera: str | None = None,
                  max_side: int = DEFAULT_MAX_SIDE) -> FocusMapModel:
        """Set the focus mapping (None: thin lens), the --camera text (parsed per capture: its pixel pitch is at the
        capture's width) and the working size's limit. Returns self."""
        self.mapping = mapping or FocusMapping("thin_lens")
        self.camera_arg = camera
        if int(max_side) < 32:
            raise CaptureError(f"--max-side {max_side}: at least 32 px")
        self.max_side = int(max_side)
        if self.mapping.lens_optics is not None:  # compared with the captures' EXIF (pipeline.identity_warnings)
            self.focal_length_mm, self.f_number = self.mapping.lens_optics[:2]
            self.lens_name = self.mapping.lens_name
        return self

    def _validate_meta(self) -> None:
        m = self.meta
        if m.get("aat.inputs") != "focus_map":
            raise ModelError(f"{self.path}: not an any-camera model (metadata aat.inputs = {m.get('aat.inputs')!r})")
        self.size_multiple = _meta_int(self.path, m, "aat.size_multiple", 1, 4096)
        self.stack_range = (_meta_int(self.path, m, "aat.stack_min", 1, 4096),
                            _meta_int(self.path, m, "aat.stack_max", 1, 4096))
        self.focus_range_m = (0.02, 1.0e4)  # any camera: the capture's own sweep
        # the largest images it trained on: larger frames run as overlapping tiles of this side (0: whole frames)
        self.tile_px = _meta_int(self.path, m, "aat.tile_px", 0, 1 << 20) if "aat.tile_px" in m else 0
        self.lens_name = None  # set by for_capture when a lens file gives the map
        self.focal_length_mm = self.f_number = None
        self.pixel_um = None
        self.sensor_px = None

    # -- binding a camera -------------------------------------------------------------------------------------
    def describe(self) -> str:
        return "the any-camera model"

    def for_capture(self, capture, frame_hw=None) -> FocusMapModel:
        """A copy told this capture's camera: optics from --camera, else the mapping's lens or calibration, else
        the frames' EXIF (CaptureError naming what is missing). frame_hw: the frames' (H, W), or a function
        returning it (decodes the first frame); None: EXIF's width."""
        where = str(capture.path)
        metas = [f.meta for f in capture.frames]
        hw = frame_hw() if callable(frame_hw) else frame_hw
        w = hw[1] if hw else next((m.width for m in metas if m.width), None)
        optics = self._optics(metas, w, where)
        focus = np.array([f.focus_m for f in capture.frames], np.float64)
        return self.bound(optics, focus)

    def for_arrays(self, frame_hw: tuple[int, int], focus_m, *, camera=None, lens=None, psf=None,
                   calibration=None) -> FocusMapModel:
        """A copy told the camera of frames given as arrays: optics from `camera` ((focal mm, f-number, pixel um)
        or the text "F,N,PIXEL_UM") or the lens / PSF / calibration file, the focus mapping from that file (else a
        thin lens). CaptureError (one line) when nothing gives the camera."""
        from .optics import parse_camera

        width = int(frame_hw[1])
        net = copy.copy(self).configure(mapping_from_args(lens, psf, calibration), max_side=self.max_side)
        if camera is not None:
            text = camera if isinstance(camera, str) else ",".join(str(float(v)) for v in camera)
            try:
                optics = parse_camera(text, width)
            except ValueError as e:
                raise CaptureError(str(e)) from None
        else:
            optics = net.mapping_optics(width)
        if optics is None and not net.mapping.measured_blur:
            raise CaptureError("the any-camera model needs the camera: camera=(focal_mm, f_number, pixel_um) or a "
                               "lens, psf or calibration file")
        return net.bound(optics, focus_m)

    def bound(self, optics: CameraOptics | None, focus_m) -> FocusMapModel:
        """A copy with these optics (None: only a calibration's measured scale can serve) and sweep."""
        out = copy.copy(self)
        out.optics = optics
        out.mapping = copy.copy(self.mapping)
        out.mapping.optics = optics
        f = np.asarray(focus_m, np.float64)
        out._focus_mid_m = float(2.0 / (1.0 / f.min() + 1.0 / f.max()))
        if optics is not None:
            out.focal_length_mm, out.f_number = optics.focal_mm, optics.f_number
        return out

    def _optics(self, metas, width_px, where: str) -> CameraOptics:
        if width_px is None:
            raise CaptureError(f"{where}: the frames' size is unknown")
        if self.camera_arg:
            from .optics import parse_camera

            try:
                return parse_camera(self.camera_arg, width_px)
            except ValueError as e:
                raise CaptureError(str(e)) from None
        lens_optics = self.mapping_optics(width_px)
        if lens_optics is not None:
            return lens_optics
        return from_exif(metas, width_px, where)

    def mapping_optics(self, width_px: int) -> CameraOptics | None:
        """Optics from the mapping's lens / PSF / calibration file (frames taken to span its sensor)."""
        src = self.mapping.lens_optics
        if src is None:
            return None
        focal, fno, sensor_w_mm, what = src
        return CameraOptics(focal, fno, 1000.0 * sensor_w_mm / width_px, int(width_px), what)

    # -- what the pipeline asks of a model --------------------------------------------------------------------
    def _k_native(self, width_px: int) -> float:
        if self.mapping.measured_blur:
            return float(np.median(self.mapping.defocus_px_per_d([self._focus_mid_m], 8, width_px)))
        if self.optics is None:
            raise CaptureError("the any-camera model has not been told the camera (focal length, f-number, pixels)")
        return self.optics.defocus_px_per_d(self._focus_mid_m, width_px)

    def working_size(self, frame_hw: tuple[int, int]) -> tuple[int, int]:
        """(W, H): the frames' size, reduced so the longer side is <= max_side and the blur growth <= K_MAX."""
        h, w = int(frame_hw[0]), int(frame_hw[1])
        s = min(1.0, self.max_side / max(h, w), K_MAX_PX_PER_D / max(self._k_native(w), 1e-9))
        return max(32, round(w * s)), max(32, round(h * s))

    def intrinsics(self, size_wh: tuple[int, int] | None = None) -> Intrinsics:
        w, h = (int(size_wh[0]), int(size_wh[1])) if size_wh else (640, 480)
        if self.optics is None:
            f = float(max(w, h))
            return Intrinsics(w, h, f, f, (w - 1) / 2, (h - 1) / 2, 0.0, "dfv_aat: no focal length known",
                              ["focal length assumed: the longer side in px"])
        f = self.optics.focal_mm / (self.optics.pixel_um_at(w) / 1000.0)
        return Intrinsics(w, h, f, f, (w - 1) / 2, (h - 1) / 2, float(self.optics.focal_mm),
                          f"dfv_aat: {self.optics.source}",
                          ["pupil_to_sensor_mm unknown: the focal length is used (thin lens focused at infinity)"])

    def focal_length_px_at(self, size_wh: tuple[int, int]) -> float:
        return self.intrinsics(size_wh).fx

    def summary(self) -> dict:
        s = {"path": str(self.path), "kind": "any_camera", "net": self.meta.get("aat.net"),
             "config_hash": self.meta.get("aat.config_hash"), "version": self.meta.get("aat.version"),
             "focus_mapping": self.mapping.summary()}
        if "aat.route" in self.meta:  # two nets in one file, chosen by the frame count (training.train.route)
            s["route"] = self.meta["aat.route"]  # metadata values are read as JSON (infer.model)
        return s

    # -- inference --------------------------------------------------------------------------------------------
    def maps(self, focus_m, height: int, width: int) -> np.ndarray:
        """(S + 1, H, W) float32: the in-focus diopters of every frame and the defocus scale, at this size."""
        fd = self.mapping.frame_diopters(focus_m, height, width)
        k = self.mapping.defocus_px_per_d(focus_m, height, width)
        return np.concatenate([fd, k], 0).astype(np.float32)

    def infer(self, stack: np.ndarray, focus_m: np.ndarray, tile: int | None = None, overlap: int = 32,
              progress=None, field_xy: np.ndarray | None = None):
        h, w = stack.shape[2:]
        maps = self.maps(focus_m, h, w) if field_xy is None else field_xy
        if tile is None and self.tile_px:  # the net's own tiles (aat.tile_px), an eighth of them overlapping
            tile, overlap = own_tiles(self.tile_px)
        return super().infer(stack, focus_m, tile, overlap, progress, field_xy=maps)

    def _feeds(self, stack: np.ndarray, focus_m: np.ndarray, field_xy: np.ndarray | None, ph: int, pw: int) -> dict:
        """field_xy carries the maps (S + 1, H, W) (`maps`), padded by continuing them linearly."""
        from ..infer.model import _pad_linear

        maps = _pad_linear(np.asarray(field_xy, np.float32), ph, pw)
        return {"stack": np.ascontiguousarray(stack[None], dtype=np.float32),
                "focus_diopters": np.ascontiguousarray(maps[None, :-1]),
                "defocus_px_per_d": np.ascontiguousarray(maps[None, -1:])}


def open_model(path: str | Path, threads: int | None = None) -> DfFModel:
    """A DfF model file as the right class: the any-camera model (metadata aat.inputs = focus_map,
    `FocusMapModel`, not yet told its camera) or a lens-specific `DfFModel` (`aat_deploy.infer.model`). It lives here,
    above both classes, so that `aat_deploy.infer.model` does not import this module back."""
    path = Path(path)
    if path.is_file():
        try:
            meta = dict(ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
                        .get_modelmeta().custom_metadata_map)
        except Exception:  # noqa: BLE001 (DfFModel reports an unloadable file in one line)
            meta = {}
        if meta.get("aat.inputs") == "focus_map":
            return FocusMapModel(path, threads=threads)
    return DfFModel(path, threads=threads)


def mapping_from_args(lens=None, psf=None, calibration=None) -> FocusMapping:
    """The focus mapping of `--lens`, `--psf` or `--calibration` (at most one; none: thin lens), with the optics
    that file gives (`lens_optics`: focal length, f-number, sensor width (mm), description). CaptureError in one
    line for a file that cannot serve."""
    given = [n for n, v in (("--lens", lens), ("--psf", psf), ("--calibration", calibration)) if v is not None]
    if len(given) > 1:
        raise CaptureError(f"give one of --lens, --psf, --calibration, not {' and '.join(given)}")
    from ..focus.bestfocus import BestFocusError, for_lens, from_psf

    try:
        if lens is not None:
            from ..lens.io import load_lens
            from ..optics.paraxial import paraxial_data

            fmap, src = for_lens(lens)
            ln = load_lens(lens)
            p = paraxial_data(ln)
            mp = FocusMapping("best_focus", best_focus=fmap, source=src)
            mp.lens_optics = (p.efl_mm, p.fno, ln.sensor.width_mm, f"lens file {lens}")
            mp.lens_name = ln.name
            return mp
        if psf is not None:
            from ..psf.surrogate import PSFSurrogate

            fmap = from_psf(psf)
            meta = PSFSurrogate(psf, threads=1).meta
            mp = FocusMapping("best_focus", best_focus=fmap, source=str(psf))
            efl, epd = float(meta.get("aat.efl_mm", "nan")), float(meta.get("aat.entrance_pupil_mm", "nan"))
            if np.isfinite(efl) and np.isfinite(epd) and epd > 0:
                mp.lens_optics = (efl, efl / epd, float(fmap.sensor_mm[0]), f"PSF surrogate {psf}")
            return mp
    except BestFocusError as e:
        raise CaptureError(str(e)) from None
    if calibration is not None:
        from ..calibrate.format import load_calibration

        cal = load_calibration(calibration)
        mp = FocusMapping("calibration", calibration=cal, source=str(calibration))
        c = cal.camera
        if c.focal_length_mm and c.f_number and cal.sensor_mm:
            mp.lens_optics = (c.focal_length_mm, c.f_number, cal.sensor_mm[0], f"calibration {calibration}")
        return mp
    return FocusMapping("thin_lens")


__all__ = ["FocusMapModel", "mapping_from_args", "own_tiles", "K_MAX_PX_PER_D", "DEFAULT_MAX_SIDE"]
