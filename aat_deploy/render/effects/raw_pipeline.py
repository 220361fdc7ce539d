"""raw_pipeline: the camera's RAW development: each photosite measures one colour (RGGB Bayer mosaic, 14-bit) and the
other two are interpolated (demosaicking).

A real capture's frames went through this; the simulator's are full RGB per pixel. It changes fine detail and,
with `noise` (which runs first, on the linear signal), gives the noise the spatial and cross-channel correlation
of a developed RAW: one independent draw per photosite, spread by the interpolation, instead of three per pixel.
That changes a focus measure's noise floor, which is what a DfF net sees.

demosaic="libraw" (default) develops each frame exactly as the runtime develops a camera's RAW file: the mosaic is
written as a 14-bit DNG and decoded by LibRaw (`aat_deploy.capture.raw.load_raw`, AHD demosaicking). "bilinear"
is the textbook interpolation, written out here (no file round trip), for tests and for reasoning about the noise.
"""

from __future__ import annotations

import cv2
import numpy as np

from aat_deploy.capture.virtual import SENSOR_DNG, mosaic_rggb, to_dn
from aat_deploy.render.effects import Effect, SimContext, register

DEMOSAIC = ("libraw", "bilinear")

# Bilinear demosaicking as two normalised convolutions: green has 4 neighbours in a cross, red and blue 4 (or 2) in
# a 3x3 box. Dividing by the convolved sampling mask keeps the weights summing to one at the borders too.
_CROSS = np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]], np.float32) / 4
_BOX = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]], np.float32) / 4


def rggb_masks(h: int, w: int) -> np.ndarray:
    """(3, H, W) float32: 1 where the RGGB mosaic samples that channel (R at even rows and columns)."""
    m = np.zeros((3, h, w), np.float32)
    m[0, 0::2, 0::2] = 1
    m[1, 0::2, 1::2] = 1
    m[1, 1::2, 0::2] = 1
    m[2, 1::2, 1::2] = 1
    return m


def demosaic_bilinear(mosaic: np.ndarray) -> np.ndarray:
    """(H, W) RGGB mosaic -> (3, H, W) float32 by bilinear interpolation (measured samples kept as they are)."""
    h, w = mosaic.shape
    masks = rggb_masks(h, w)
    out = np.empty((3, h, w), np.float32)
    for c, k in ((0, _BOX), (1, _CROSS), (2, _BOX)):
        num = cv2.filter2D(mosaic.astype(np.float32) * masks[c], -1, k, borderType=cv2.BORDER_REFLECT_101)
        den = cv2.filter2D(masks[c], -1, k, borderType=cv2.BORDER_REFLECT_101)
        out[c] = np.where(masks[c] > 0, mosaic, num / den)
    return out


def develop_libraw(mosaic_linear: np.ndarray) -> np.ndarray:
    """(H, W) RGGB mosaic, linear (1.0 = white level), H and W even -> (3, H, W) float32 as the runtime develops a
    RAW frame: 14-bit DN with a black level, a DNG on disk, LibRaw's development (`load_raw`)."""
    import tempfile
    from pathlib import Path

    from aat_deploy.capture.dng import write_dng
    from aat_deploy.capture.raw import load_raw

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "frame.dng"
        write_dng(path, to_dn(mosaic_linear), **SENSOR_DNG, subject_distance_m=1.0, focal_length_mm=50.0,
                  f_number=2.0, make="aat", model="twin", lens_model="twin")  # EXIF fields: unused here
        rgb, _ = load_raw(path)
    return np.ascontiguousarray(rgb.transpose(2, 0, 1))


@register
class RawPipeline(Effect):
    name = "raw_pipeline"
    description = ("RAW development: RGGB Bayer sampling at 14 bits, then demosaicking: 'libraw' (default) as the "
                   "runtime develops a RAW file, or 'bilinear' (with noise: one draw per photosite, spread by the "
                   "interpolation)")
    order = 92  # after the sensor's noise, before nothing else that touches pixels
    defaults = {"demosaic": "libraw"}

    def __init__(self, **params):
        super().__init__(**params)
        if self.params["demosaic"] not in DEMOSAIC:
            raise ValueError(f"effect 'raw_pipeline': demosaic must be one of {DEMOSAIC}, got {self.params['demosaic']!r}")

    def binned(self, factor: int):
        """Binning averages the mosaic's interpolation away (each block holds every colour): left out of the
        diagnosis's reduced-resolution search, an approximation there only."""
        return self if factor == 1 else None

    def sensor(self, frame: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        if frame.shape[0] != 3:
            raise ValueError(f"effect 'raw_pipeline' needs RGB frames (3, H, W), got {frame.shape}")
        # The crop's origin decides which photosite colour its first pixel is: keep the sensor's phase.
        r0, c0 = ctx.origin[0] % 2, ctx.origin[1] % 2
        h, w = frame.shape[1:]
        if self.params["demosaic"] == "bilinear":
            padded = np.pad(frame, ((0, 0), (r0, 0), (c0, 0)), mode="reflect")
            out = demosaic_bilinear(mosaic_rggb(padded))[:, r0:, c0:]
        else:  # a DNG wants even sides of >= 22 photosites
            pad_r, pad_c = max((h + r0) % 2, 22 - h - r0), max((w + c0) % 2, 22 - w - c0)
            padded = np.pad(frame, ((0, 0), (r0, max(pad_r, 0)), (c0, max(pad_c, 0))), mode="reflect")
            out = develop_libraw(mosaic_rggb(padded))[:, r0:r0 + h, c0:c0 + w]
        return out.astype(frame.dtype, copy=False)
