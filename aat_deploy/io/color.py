"""The sRGB transfer function (IEC 61966-2-1) both ways: decoding 8/16-bit or [0, 1] sRGB images to linear RGB
(the frame readers, the Python API) and encoding linear RGB for 8-bit pictures (the outputs)."""

from __future__ import annotations

import functools

import cv2
import numpy as np


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] → linear (IEC 61966-2-1)."""
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


@functools.cache
def _srgb_lut(dtype) -> np.ndarray:
    """srgb_to_linear of every code of an 8- or 16-bit image (the same float32 values, about 15x faster to apply
    to a 12-MP frame than the formula)."""
    top = np.iinfo(dtype).max
    return srgb_to_linear(np.arange(top + 1, dtype=np.float32) / np.float32(top))


def srgb_codes_to_linear(img: np.ndarray) -> np.ndarray:
    """8- or 16-bit sRGB-encoded values (any shape) -> linear float32 in [0, 1] (the same values as
    srgb_to_linear(img / max code), by table lookup)."""
    if img.dtype == np.uint8 and img.ndim <= 3 and (img.ndim < 3 or img.shape[2] <= 4):
        return cv2.LUT(np.ascontiguousarray(img), _srgb_lut(img.dtype))  # OpenCV's lookup: 3x numpy's at 12 MP
    if img.dtype in (np.uint8, np.uint16):
        return np.take(_srgb_lut(img.dtype), img)
    raise TypeError(f"srgb_codes_to_linear: 8- or 16-bit codes expected, got {img.dtype}")


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear values (clipped to [0, 1]) → sRGB encoding in [0, 1]."""
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)
