"""Calibrate a camera (body + lens at one aperture and zoom) from focus sweeps of a flat chart, with no optical
prescription: what each frame has in focus at each sensor position, the reported focus's error, and the blur
growth per diopter. Torch-free (docs/calibration.md; the file format, `aat-camera-calibration-v1`, in
docs/contracts.md).

What consumers call (`format.py`):

    from aat_deploy.calibrate import load_calibration, in_focus_diopters, defocus_scale_px_per_d
    cal = load_calibration("mycam.json")
    d = in_focus_diopters(cal, reported_focus_m, height, width)   # (S, H, W) float32 diopters from the sensor plane
    k = defocus_scale_px_per_d(cal, height, width)               # (H, W) float32 blur diameter px per diopter
    m = measured_mask(cal, reported_focus_m, height, width)       # (S, H, W) bool: False where d is extrapolated
"""

from .format import (
    FORMAT,
    CalibrationError,
    CameraCalibration,
    CameraIdentity,
    FieldPoly,
    FocusError,
    defocus_scale_px_per_d,
    in_focus_diopters,
    load_calibration,
    measured_mask,
    on_axis_diopters,
    save_calibration,
    thin_lens_defocus_scale_px_per_d,
)

__all__ = ["FORMAT", "CalibrationError", "CameraCalibration", "CameraIdentity", "FieldPoly", "FocusError",
           "defocus_scale_px_per_d", "in_focus_diopters", "load_calibration", "measured_mask",
           "on_axis_diopters", "save_calibration",
           "thin_lens_defocus_scale_px_per_d"]
