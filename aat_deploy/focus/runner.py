"""The classical method behind `aat-infer --method focus` as a `DepthMethod` (`aat_deploy.infer.method`): the
array function `classical_depth` at the capture's own resolution.

- working size: by default chosen from the stack's blur step (`aat_deploy.focus.scale`: reduced while the blur
  between adjacent frames stays several pixels; `auto`, `pre_reduction`, `choose_size`); or reduced so the longer
  side is at most `max_side` px (area averaging); `max_side=0`: the frames' own size;
- lens: none (thin-lens mapping; camera identity is not checked), or a best-focus map from `--lens LENS` (the
  map stored next to the lens file, else traced now with torch) or `--psf PSF.onnx` (the map stamped in its
  metadata): aberration-aware mapping, and the lens's focal length / F-number are compared with the EXIF ones;
  or a camera calibration (`--calibration mycam.json`, `aat_deploy.calibrate`): every frame's reported focus
  mapped to what is in focus at every pixel, and the calibrated camera's lens, focal length and F-number compared
  with the EXIF ones;
- focal length in pixels for the recording: from the lens (EFL over the sensor's width at the working size),
  else an assumed horizontal field of view of about 53 degrees (f = the longer side in px), said in the summary.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import CaptureError
from ..infer.method import DepthMethod, DepthOutput
from ..optics.camera import Intrinsics
from . import scale
from .bestfocus import BestFocusError, BestFocusMap, for_lens, from_psf
from .method import FocusConfig, classical_depth

MAX_FRAMES = 10_000


def _scaled(frame_hw: tuple[int, int], k: float) -> tuple[int, int]:
    """(W, H) of a frame of frame_hw = (H, W) reduced by k (>= 1), at least 1 px."""
    h, w = int(frame_hw[0]), int(frame_hw[1])
    return max(1, round(w / k)), max(1, round(h / k))


class FocusMethod(DepthMethod):
    """The classical focus method as a `DepthMethod`: it places frames with equal reported focus itself and, without
    --max-side, chooses its working size from the stack's blur step."""

    noun = "method"
    places_tied_frames = True

    def __init__(self, config: FocusConfig = FocusConfig(), lens: str | Path | None = None,
                 psf: str | Path | None = None, max_side: int | None = None, progress: bool = False,
                 calibration=None):
        if sum(v is not None for v in (lens, psf, calibration)) > 1:
            raise CaptureError("give one of --lens, --psf or --calibration")
        self.config, self.max_side = config, max_side
        self.best_focus: BestFocusMap | None = None
        self.calibration = None
        self.map_source = None
        self.lens_name = None
        self.focal_length_mm = self.f_number = self.sensor_mm = None
        if calibration is not None:
            from ..calibrate.format import CameraCalibration, load_calibration

            # a path (a bad file is a ConfidenceCalibrationError, a CaptureError: one line) or a calibration in memory
            self.calibration = calibration if isinstance(calibration, CameraCalibration) else \
                load_calibration(calibration)
            self.map_source = "in memory" if isinstance(calibration, CameraCalibration) else str(calibration)
            cam = self.calibration.camera
            self.lens_name = cam.lens or None
            self.focal_length_mm, self.f_number = cam.focal_length_mm, cam.f_number
            self.sensor_mm = self.calibration.sensor_mm
        try:
            if psf is not None:
                self.best_focus, self.map_source = from_psf(psf), str(psf)
            elif lens is not None:
                self.best_focus, self.map_source = for_lens(lens, progress=progress)
        except BestFocusError as e:
            raise CaptureError(str(e)) from None
        if lens is not None:
            self._lens_identity(Path(lens))
        elif psf is not None:
            self._psf_identity(Path(psf))
        self.stack_range = (3, MAX_FRAMES)
        # (a calibration's range is checked in the method, on the on-axis focus its error model gives)
        self.focus_range_m = self.best_focus.focus_range_m if self.best_focus else (0.0, float("inf"))

    def _lens_identity(self, path: Path) -> None:
        from aat_deploy.lens.io import load_lens
        from aat_deploy.optics.paraxial import paraxial_data

        lens = load_lens(path)
        p = paraxial_data(lens)
        self.lens_name, self.focal_length_mm, self.f_number = lens.name, p.efl_mm, p.fno
        self.sensor_mm = (lens.sensor.width_mm, lens.sensor.height_mm)

    def _psf_identity(self, path: Path) -> None:
        from ..psf.surrogate import PSFSurrogate

        meta = PSFSurrogate(path, threads=1).meta
        self.lens_name = meta.get("aat.lens_name")
        efl, epd = float(meta.get("aat.efl_mm", "nan")), float(meta.get("aat.entrance_pupil_mm", "nan"))
        self.focal_length_mm = efl if np.isfinite(efl) else None
        self.f_number = efl / epd if np.isfinite(efl) and np.isfinite(epd) and epd > 0 else None
        self.sensor_mm = tuple(json.loads(meta["aat.sensor_mm"])) if "aat.sensor_mm" in meta else None

    # -- what the pipeline asks of a depth method -------------------------------------------------------------
    def describe(self) -> str:
        return "the classical focus method"

    def for_arrays(self, frame_hw, focus_m, *, camera=None, lens=None, psf=None, calibration=None) -> FocusMethod:
        """With a lens, PSF or calibration: a copy mapping focus through it (aberration-aware); camera= is the
        any-camera model's."""
        if camera is not None:
            raise CaptureError("the classical focus method takes no camera= (the any-camera model's): lens=, psf= "
                               "or calibration= make it aberration-aware")
        if lens is None and psf is None and calibration is None:
            return self
        return FocusMethod(self.config, lens=lens, psf=psf, max_side=self.max_side, calibration=calibration)

    @property
    def auto(self) -> bool:
        """The working size is chosen from the stack's blur step (no --max-side)."""
        return self.max_side is None

    def working_size(self, frame_hw: tuple[int, int]) -> tuple[int, int]:
        """(W, H) the frames are processed at with a fixed size: their own size (max_side 0), or scaled so the
        longer side is `max_side`."""
        h, w = int(frame_hw[0]), int(frame_hw[1])
        if self.max_side and max(h, w) > self.max_side:
            s = self.max_side / max(h, w)
            return max(1, round(w * s)), max(1, round(h * s))
        return w, h

    def tile_sampler(self, frame_hw: tuple[int, int]) -> scale.TileSampler:
        """The tiles the blur step is measured on (`aat_deploy.focus.scale.TileSampler`)."""
        return scale.TileSampler.for_size(frame_hw)

    def pre_reduction(self, frame_hw: tuple[int, int]) -> tuple[int, int]:
        """(W, H) to keep each frame at while the blur step is not yet known: reduced by the largest whole factor
        the rule allows whatever the step (its size floor), so the chosen size can be reached without decoding
        again unless the step is small."""
        return _scaled(frame_hw, max(1, int(max(frame_hw) // scale.SIDE_MIN_PX)))

    def choose_size(self, frame_hw: tuple[int, int], levels: list[np.ndarray]) -> tuple[tuple[int, int], dict]:
        """(W, H) by the rule of `aat_deploy.focus.scale` from the frames' tiles (per pyramid level (S, N, R, R),
        frames sorted by focus: `scale.TileSampler`), and what summary.json reports about the choice."""
        step, details = scale.blur_step_px(levels)
        k = scale.working_factor(step, frame_hw)
        size = _scaled(frame_hw, k)
        return size, {"blur_step_px": None if step is None else round(step, 2), "factor": round(k, 3),
                      "size_px": list(size), "native_px": [int(frame_hw[1]), int(frame_hw[0])],
                      "rule": scale.rule_text(), "tiles": details,
                      **({} if step is not None else {"note": "blur step not measurable (too few textured tiles "
                                                               "with a focus peak): the frames' own size"})}

    def intrinsics(self, size_wh: tuple[int, int]) -> Intrinsics:
        """Pinhole intrinsics at the working size (aat_deploy.optics.camera): the focal length from the lens, else the
        assumed one (focal_length_px_at); the pinhole a focal length in front of the sensor (thin lens at infinity),
        at the sensor when the focal length in mm is unknown."""
        w, h = int(size_wh[0]), int(size_wh[1])
        f = self.focal_length_px_at((w, h))
        if self.focal_length_mm and self.sensor_mm:
            return Intrinsics(w, h, f, f, (w - 1) / 2, (h - 1) / 2, float(self.focal_length_mm),
                              f"--method focus: focal length of {self.lens_name}",
                              ["pupil_to_sensor_mm unknown: the focal length is used (thin lens focused at infinity)"])
        return Intrinsics(w, h, f, f, (w - 1) / 2, (h - 1) / 2, 0.0, "--method focus: no lens given",
                          ["focal length assumed: the longer side in px (about 53 degrees across); give --lens",
                           "pupil_to_sensor_mm unknown: 0 (the pinhole at the sensor)"])

    def focal_length_px_at(self, size_wh: tuple[int, int]) -> float:
        if self.focal_length_mm and self.sensor_mm:
            return float(self.focal_length_mm / (self.sensor_mm[0] / size_wh[0]))
        return float(max(size_wh))

    def frame_warnings(self, frame_hw: tuple[int, int], where) -> list[str]:
        """The aberration-aware mapping assumes the frames span the lens's sensor: warn on another aspect."""
        if self.calibration is not None:
            msg = self.calibration.aspect_warning(*frame_hw, where=str(where) + ": frames")
            return [msg] if msg else []
        if self.best_focus is None:
            return []
        sw, sh = self.best_focus.sensor_mm
        h, w = frame_hw
        if abs(w / h - sw / sh) > 0.01 * (sw / sh):
            return [f"{where}: frames are {w}x{h} px, the lens's sensor is {sw:g}x{sh:g} mm: field radii assume "
                    "the frames span the sensor"]
        return []

    def summary(self) -> dict:
        mapping = "calibration" if self.calibration else "aberration_aware" if self.best_focus else "thin_lens"
        return {"method": "focus", "mapping": mapping,
                "best_focus_map" if self.calibration is None else "calibration": self.map_source, "lens_name": self.lens_name,
                "focal_length_mm": self.focal_length_mm, "f_number": self.f_number, "max_side": self.max_side,
                "focal_length_px": "from the lens" if self.focal_length_mm and self.sensor_mm else
                "assumed: the longer side in px (no lens given)",
                "config": {k: v for k, v in self.config.__dict__.items()}}

    def infer(self, stack: np.ndarray, focus_m: np.ndarray, tile: int | None = None, progress=None) -> DepthOutput:
        """stack (S, 3, H, W) normalised, focus_m (S,) metres; `tile` is not needed (memory is a few stacks)."""
        try:
            r = classical_depth(stack, focus_m, self.best_focus, self.config, calibration=self.calibration)
        except ValueError as e:
            raise CaptureError(str(e)) from None
        # the maps are per pixel: nothing to reorder whatever order the method sorted the frames in
        return DepthOutput(r.depth_m, r.aif, r.std_m, r.confidence, r.warnings, r.info)
