"""What each frame has in focus at each pixel, and how fast blur grows there: the two maps the any-camera model
takes besides the stack.

- `thin_lens`: every pixel of frame s focuses at the reported distance F_s (object diopters 1/F_s everywhere);
- `best_focus`: a lens's best-focus map (`aat_deploy.focus.bestfocus`, from `--lens` or `--psf`): at normalised image
  radius r the frame focuses at the traced (and calibrated) object diopters; the frames are taken to span the lens's
  sensor (as `--method focus` takes them);
- `calibration`: a camera calibration (`--calibration`, format aat-camera-calibration-v1), which also corrects the
  reported focus distances' own error and may carry the measured blur growth.

Diopters are 1/m with distances from the sensor plane; the defocus scale is the blur-disk diameter in pixels (at
the working size) per diopter of defocus: measured when a calibration carries it, else the thin lens's from the
camera's optics (`aat_deploy.anycam.optics`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..focus.bestfocus import BestFocusMap
from .optics import CameraOptics

KINDS = ("thin_lens", "best_focus", "calibration")


@dataclass
class FocusMapping:
    """kind: one of KINDS; best_focus: the lens's map (kind best_focus); calibration: the loaded calibration (kind
    calibration); source: the file it came from; optics: the camera's (for the thin-lens defocus scale);
    lens_optics: what the lens / PSF / calibration file says of the camera, for captures without EXIF."""

    kind: str
    optics: CameraOptics | None = None
    best_focus: BestFocusMap | None = None
    calibration: object | None = None
    source: str | None = None
    notes: list[str] = field(default_factory=list)
    lens_optics: tuple | None = None  # (focal mm, f-number, sensor width mm, description) the file gives
    lens_name: str | None = None

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"focus mapping kind must be one of {KINDS}, got {self.kind!r}")

    @property
    def measured_blur(self) -> bool:
        """A camera calibration that measured the blur growth: it gives the defocus scale without the optics."""
        return self.kind == "calibration" and self.calibration.blur is not None

    def frame_diopters(self, focus_m, height: int, width: int) -> np.ndarray:
        """(S, H, W) float32 object diopters in best focus at every pixel of frames (spanning the sensor) whose
        reported focus distances are focus_m (S,) metres."""
        f = np.asarray(focus_m, np.float64).ravel()
        if self.kind == "thin_lens":
            return np.broadcast_to((1.0 / f)[:, None, None], (f.size, height, width)).astype(np.float32)
        if self.kind == "best_focus":
            r = self.best_focus.radius_px(height, width).ravel()
            return self.best_focus.frame_diopters(f, r).reshape(f.size, height, width).astype(np.float32)
        from ..calibrate.format import in_focus_diopters

        return np.asarray(in_focus_diopters(self.calibration, f, height, width), np.float32)

    def defocus_px_per_d(self, focus_m, height: int, width: int) -> np.ndarray:
        """(1, H, W) float32 blur-diameter growth per diopter (px at this size): the calibration's measured one if it
        has it, else the thin lens's at the middle of the sweep (in diopters)."""
        f = np.asarray(focus_m, np.float64).ravel()
        mid = 2.0 / (1.0 / f.min() + 1.0 / f.max())
        if self.measured_blur:
            from ..calibrate.format import defocus_scale_px_per_d

            return np.asarray(defocus_scale_px_per_d(self.calibration, height, width, mid), np.float32)[None]
        if self.optics is None:
            raise ValueError("the thin-lens defocus scale needs the camera's optics")
        return np.full((1, height, width), self.optics.defocus_px_per_d(mid, width), np.float32)

    def summary(self) -> dict:
        return {"mapping": self.kind, "source": self.source,
                "optics": None if self.optics is None else self.optics.as_json(), "notes": self.notes}
