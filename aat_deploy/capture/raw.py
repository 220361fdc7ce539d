"""Frame pixels to linear RGB float32 (H, W, 3); the decoder is chosen by the file's content (imagefile.frame_kind),
and the size its header claims is checked against the pixel limit before anything is decoded.

- Camera RAW (anything LibRaw opens) through rawpy: black/white levels from the file, camera white
  balance, default demosaic, linear gamma (1, 1), no auto-brightening, 16-bit, sRGB primaries. Every frame is
  scaled by the file's white level, never by its own brightest pixel (LibRaw's default `adjust_maximum_thr`
  would, for frames whose maximum exceeds 0.75 of white, and so put a stack's frames on different scales by
  their content: up to 1.29 x between the shipped sample's frames, issue 32).
- JPEG through libjpeg-turbo (simplejpeg) in strict mode, so a file whose data runs out (cut, even with an end
  marker appended) is refused instead of used grey-padded; decoded from sRGB to linear, EXIF orientation applied.
- 8/16-bit TIFF and PNG through OpenCV, decoded from sRGB to linear; float TIFFs are taken as linear (NaN or
  infinite values are refused).
Values are in [0, 1] relative to the file's white level (the stack is normalised later anyway).
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import cv2
import numpy as np
import rawpy
import simplejpeg

from ..errors import AatError, CaptureError
from ..io.color import srgb_codes_to_linear
from ..io.files import read_input_bytes
from .containers import container_of, find_blocks
from .imagefile import FRAME_EXTENSIONS, IMAGE_EXTENSIONS, RAW_EXTENSIONS, check_pixels, claimed_size, frame_header

__all__ = ["FRAME_EXTENSIONS", "IMAGE_EXTENSIONS", "RAW_EXTENSIONS", "load_frame", "load_mosaic", "load_raw"]


_BENIGN_JPEG = re.compile(r"extraneous bytes before marker")  # libjpeg warnings that lose no image data


def _load_raw(path: Path, buf: bytes, limit: float | None) -> tuple[np.ndarray, dict]:
    """Develop a RAW file to linear sRGB-primaries float32 (H, W, 3); info has black/white levels and WB."""
    try:
        with rawpy.imread(io.BytesIO(buf)) as r:  # LibRaw parses here and unpacks only in postprocess
            s = r.sizes
            check_pixels(path, (max(s.width, s.raw_width), max(s.height, s.raw_height)), limit)
            info = {"black_level": [int(v) for v in r.black_level_per_channel],
                    "white_level": int(r.white_level),
                    "camera_wb": [float(v) for v in r.camera_whitebalance]}
            rgb = r.postprocess(use_camera_wb=True, gamma=(1, 1), no_auto_bright=True, output_bps=16,
                                adjust_maximum_thr=0.0, output_color=rawpy.ColorSpace.sRGB)
    except rawpy.LibRawFileUnsupportedError:
        raise _Unsupported() from None
    except (rawpy.LibRawIOError, rawpy.LibRawDataError) as e:
        raise CaptureError(f"{path}: unreadable or truncated RAW file ({type(e).__name__})") from None
    except rawpy.LibRawError as e:
        raise CaptureError(f"{path}: RAW decoding failed ({type(e).__name__}: {e})") from None
    except OSError as e:
        raise CaptureError(f"{path}: cannot read ({e})") from None
    return rgb.astype(np.float32) / 65535.0, info


class _Unsupported(AatError):
    """LibRaw does not know the file."""


def load_raw(path: str | Path, max_megapixels: float | None = None) -> tuple[np.ndarray, dict]:
    """Develop a RAW file (LibRaw) to linear float32 RGB (H, W, 3), whatever its content; see load_frame."""
    path = Path(path)
    try:
        return _load_raw(path, read_input_bytes(path), max_megapixels)
    except _Unsupported:
        raise CaptureError(f"{path}: not a RAW format LibRaw can decode (unsupported or not an image)") from None


def load_mosaic(path: str | Path, max_megapixels: float | None = None) -> tuple[np.ndarray, dict]:
    """A RAW file's undeveloped sensor data: (H, W) float32, each photosite less its colour's black level over the
    white level less it (black = 0, white = 1; negatives kept), the visible area only; info has the levels and
    the 2 x 2 pattern (`raw_pattern`). For measuring the sensor itself (`diagnose.photon`), not for viewing."""
    path = Path(path)
    buf = read_input_bytes(path)
    try:
        with rawpy.imread(io.BytesIO(buf)) as r:
            s = r.sizes
            check_pixels(path, (max(s.width, s.raw_width), max(s.height, s.raw_height)), max_megapixels)
            raw = r.raw_image_visible.astype(np.float32)
            black = np.asarray(r.black_level_per_channel, np.float32)[r.raw_colors_visible]
            white = float(r.white_level)
            info = {"black_level": [int(v) for v in r.black_level_per_channel], "white_level": int(white),
                    "raw_pattern": np.asarray(r.raw_pattern).tolist()}
    except rawpy.LibRawFileUnsupportedError:
        raise CaptureError(f"{path}: not a RAW format LibRaw can decode (unsupported or not an image)") from None
    except rawpy.LibRawError as e:
        raise CaptureError(f"{path}: unreadable RAW sensor data ({type(e).__name__})") from None
    except OSError as e:
        raise CaptureError(f"{path}: cannot read ({e})") from None
    if raw.ndim != 2 or not np.all(white > black):
        raise CaptureError(f"{path}: no single-plane mosaic with a white level above its black level")
    return (raw - black) / (white - black), info


_ORIENT = {  # EXIF Orientation 2..8 → the upright image, as OpenCV applies it (tests compare every value)
    2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
    5: lambda a: a.transpose(1, 0, 2), 6: lambda a: np.rot90(a, -1),
    7: lambda a: a.transpose(1, 0, 2)[::-1, ::-1], 8: lambda a: np.rot90(a, 1)}


def exif_orientation(buf: bytes) -> int:
    """The EXIF Orientation (1..8) of an image file's first IFD; 1 if absent or unreadable."""
    try:
        for role, tb, first in find_blocks(buf).tiffs:
            if role == "main":
                v = tb.number(tb.ifd(first), 0x0112)
                return int(v) if v is not None and 1 <= v <= 8 else 1
    except (ValueError, IndexError, OverflowError, TypeError):
        pass
    return 1


def _decode_jpeg(path: Path, buf: bytes) -> np.ndarray:
    """8-bit RGB (H, W, 3) of a JPEG, refused if libjpeg reports lost data (truncated, damaged entropy data)."""
    try:
        _, _, colorspace, _ = simplejpeg.decode_jpeg_header(buf)
    except ValueError as e:
        raise CaptureError(f"{path}: not a readable JPEG ({e})") from None
    native = colorspace in ("CMYK", "YCCK")  # validated by libjpeg-turbo, converted by OpenCV
    try:
        img = simplejpeg.decode_jpeg(buf, colorspace="CMYK" if native else "RGB", strict=True)
    except ValueError as e:
        if not _BENIGN_JPEG.search(str(e)):
            raise CaptureError(f"{path}: damaged or truncated JPEG ({e})") from None
        img = simplejpeg.decode_jpeg(buf, colorspace="CMYK" if native else "RGB", strict=False)
    if native:
        img = cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
        if img is None:
            raise CaptureError(f"{path}: a {colorspace} JPEG OpenCV could not convert")
        img = img[..., ::-1]
    o = exif_orientation(buf)
    return np.ascontiguousarray(_ORIENT[o](img)) if o != 1 else img


def _decode_cv(path: Path, buf: bytes) -> np.ndarray:
    """A PNG or TIFF through OpenCV as RGB (H, W, 3) of its own depth (EXIF orientation applied by OpenCV)."""
    try:
        img = cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    except cv2.error as e:  # OpenCV's own checks (e.g. a header claiming a size past its limits) raise
        why = next((ln.split("error: ", 1)[-1] for ln in str(e).splitlines() if "error:" in ln), "decoder error")
        raise CaptureError(f"{path}: not a readable image (OpenCV refused it: {why.strip()[:160]})") from None
    if img is None:
        raise CaptureError(f"{path}: not a readable image (OpenCV could not decode it; damaged or truncated?)")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    elif img.shape[2] == 4:
        img = img[..., :3]
    return img[..., ::-1]  # BGR → RGB


def _load_image(path: Path, buf: bytes, kind: str) -> tuple[np.ndarray, dict]:
    """Decode a JPEG, PNG or (8/16-bit or float) TIFF to linear float32 RGB (H, W, 3)."""
    if kind == "png" and b"IEND" not in buf[-32:]:
        raise CaptureError(f"{path}: truncated PNG file (no end chunk)")
    img = _decode_jpeg(path, buf) if kind == "jpeg" else _decode_cv(path, buf)
    if img.dtype in (np.uint8, np.uint16):
        return srgb_codes_to_linear(img), {"bits": 8 * img.itemsize}
    if img.dtype in (np.float32, np.float64):
        img = np.ascontiguousarray(img, dtype=np.float32)
        bad = int(np.count_nonzero(~np.isfinite(img).all(axis=2)))
        if bad:
            raise CaptureError(f"{path}: {bad} pixel(s) are NaN or infinite (a float TIFF frame needs finite values)")
        return img, {"bits": 32, "linear": True}
    raise CaptureError(f"{path}: unsupported pixel type {img.dtype}")


def load_frame(path: str | Path, max_megapixels: float | None = None) -> tuple[np.ndarray, dict]:
    """Linear RGB float32 (H, W, 3) of one frame file (RAW or image, told apart by content) and decoding info.

    max_megapixels: the pixel limit (default $AAT_MAX_MEGAPIXELS or 200 MP): a header claiming more is a
    CaptureError before any decoding."""
    path = Path(path)
    buf = read_input_bytes(path)  # decoders read from memory: any file name works, a FIFO is never opened
    kind, _ = frame_header(path, buf, max_megapixels)
    if kind != "raw":
        return _load_image(path, buf, kind)
    try:
        return _load_raw(path, buf, max_megapixels)
    except _Unsupported:
        if container_of(buf) != "tiff" or _tiff_size_checked(path, buf, max_megapixels) is None:
            raise CaptureError(f"{path}: not a RAW format LibRaw can decode (unsupported or not an image)") from None
    return _load_image(path, buf, "tiff")  # a plain TIFF named like a RAW


def _tiff_size_checked(path: Path, buf: bytes, limit: float | None) -> tuple[int, int] | None:
    size = claimed_size(buf, "tiff")
    if size is not None:
        check_pixels(path, size, limit)
    return size
