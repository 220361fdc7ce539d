"""A camera's first-order optics for the any-camera model: focal length (mm), f-number and pixel pitch (um at the
frames' native width), and where each came from.

Sources, in order: `--camera F_MM,N,PIXEL_UM` (all three), else a lens file / PSF surrogate / calibration given
for the aberration-aware map (their focal length, f-number and sensor), else the frames' EXIF: FocalLength and
FNumber, the sensor width from FocalPlaneXResolution (pixels per unit of the sensor) or from FocalLengthIn35mmFilm
(the crop factor: sensor diagonal = 43.27 mm / (f35 / f)). What none of them gives is refused in one line.
The defocus scale (blur diameter in px per diopter) is the thin lens's (`aat_deploy.optics.thin_lens`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import CaptureError

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)


@dataclass(frozen=True)
class CameraOptics:
    """focal_mm, f_number; pixel_um at native_width_px (the frames' width as captured); source: where each came from."""

    focal_mm: float
    f_number: float
    pixel_um: float
    native_width_px: int
    source: str

    def pixel_um_at(self, width_px: int) -> float:
        """Pixel pitch (um) of the frames resampled to width_px across (the same field of view)."""
        return self.pixel_um * self.native_width_px / float(width_px)

    def defocus_px_per_d(self, focus_m: float, width_px: int) -> float:
        """Blur-disk diameter (px at width_px across) per diopter of defocus near focus_m (m from the sensor): the
        thin lens's (`aat_deploy.calibrate.format.thin_lens_defocus_scale_px_per_d`, as a calibration without a
        measured blur growth gives it)."""
        from ..calibrate.format import thin_lens_defocus_scale_px_per_d

        return thin_lens_defocus_scale_px_per_d(self.focal_mm, self.f_number, self.pixel_um_at(width_px), focus_m)

    def as_json(self) -> dict:
        return {"focal_length_mm": self.focal_mm, "f_number": self.f_number, "pixel_um": self.pixel_um,
                "native_width_px": self.native_width_px, "source": self.source}


def parse_camera(text: str, native_width_px: int) -> CameraOptics:
    """--camera F_MM,N,PIXEL_UM (pixel pitch of the frames as captured) -> CameraOptics; ValueError in one line."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != 3 or not all(math.isfinite(v) and v > 0 for v in vals):
        raise ValueError(f"--camera {text!r}: expected focal length (mm), f-number and pixel pitch (um) as three "
                         "positive numbers, e.g. 50,1.8,4.3")
    f, n, p = vals
    if not (0.5 <= f <= 2000 and 0.5 <= n <= 64 and 0.1 <= p <= 100):
        raise ValueError(f"--camera {text!r}: focal length 0.5-2000 mm, f-number 0.5-64 and pixel pitch 0.1-100 um "
                         "expected")
    return CameraOptics(f, n, p, int(native_width_px), "--camera")


def from_exif(frames_meta, native_width_px: int, where: str) -> CameraOptics:
    """The optics the frames' EXIF gives (every frame should agree; the first one with values is used).
    CaptureError naming what is missing when the focal length, f-number or sensor size is not there."""
    focal = next((m.focal_length_mm for m in frames_meta if m.focal_length_mm), None)
    fno = next((m.f_number for m in frames_meta if m.f_number), None)
    f35 = next((m.focal_length_35mm for m in frames_meta if getattr(m, "focal_length_35mm", None)), None)
    plane = next((m.focal_plane_px_per_mm for m in frames_meta if getattr(m, "focal_plane_px_per_mm", None)), None)
    exif_w = next((m.width for m in frames_meta if m.width), None)
    exif_h = next((m.height for m in frames_meta if m.height), None)
    missing = [n for n, v in (("focal length", focal), ("f-number", fno)) if not v]
    pixel_um, how = None, ""
    if plane:
        pixel_um, how = 1000.0 / plane, "FocalPlaneXResolution"
    elif f35 and focal:
        w, h = (exif_w, exif_h) if exif_w and exif_h else (native_width_px, None)
        aspect = (w / h) if h else 1.5
        diag = FULL_FRAME_DIAGONAL_MM * focal / f35
        width_mm = diag * aspect / math.hypot(aspect, 1.0)
        pixel_um, how = 1000.0 * width_mm / (w or native_width_px), "FocalLengthIn35mmFilm"
    else:
        missing.append("sensor size (FocalPlaneXResolution or FocalLengthIn35mmFilm)")
    if pixel_um and exif_w and exif_w != native_width_px:  # EXIF describes the image as written; frames resized
        pixel_um *= exif_w / native_width_px
    if missing:
        raise CaptureError(f"{where}: the any-camera model needs the camera's focal length, f-number and pixel "
                           f"pitch; EXIF lacks the {', '.join(missing)}: give --camera F_MM,N,PIXEL_UM "
                           "(or --lens / --calibration)")
    return CameraOptics(float(focal), float(fno), float(pixel_um), int(native_width_px), f"EXIF ({how})")
