"""Frame pixels to linear RGB float32 (H, W, 3).

- Camera RAW (anything LibRaw opens) through rawpy: black/white levels from the file, camera white
  balance, default demosaic, linear gamma (1, 1), no auto-brightening, 16-bit, sRGB primaries. Every frame is
  scaled by the file's white level, never by its own brightest pixel (LibRaw's default `adjust_maximum_thr`
  would, for frames whose maximum exceeds 0.75 of white, and so put a stack's frames on different scales by
  their content: up to 1.29 x between the shipped sample's frames, issue 32).
- 8/16-bit TIFF, PNG, JPEG through OpenCV, decoded from sRGB to linear; float TIFFs are taken as linear.
Values are in [0, 1] relative to the file's white level (the stack is normalised later anyway).
"""

from __future__ import annotations

import io
from pathlib import Path

import cv2
import numpy as np
import rawpy

from ..errors import CaptureError, read_input_bytes

RAW_EXTENSIONS = {".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".raf", ".orf", ".rw2",
                  ".pef", ".kdc", ".dcr", ".mrw", ".x3f", ".iiq", ".3fr", ".erf", ".mef", ".mos", ".srw", ".rwl",
                  ".raw", ".fff"}
IMAGE_EXTENSIONS = {".tif", ".tiff", ".png", ".jpg", ".jpeg"}
FRAME_EXTENSIONS = RAW_EXTENSIONS | IMAGE_EXTENSIONS


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] → linear (IEC 61966-2-1)."""
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear values (clipped to [0, 1]) → sRGB encoding in [0, 1]."""
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def is_raw(path: Path) -> bool:
    """True if the file extension names a camera RAW format."""
    return path.suffix.lower() in RAW_EXTENSIONS


def raw_size(path: Path) -> tuple[int, int] | None:
    """(width, height) of a RAW file's developed image, or None if LibRaw cannot open it."""
    try:
        with rawpy.imread(io.BytesIO(read_input_bytes(path))) as r:
            s = r.sizes
            w, h = int(s.width), int(s.height)
            return (h, w) if s.flip in (5, 6) else (w, h)
    except (rawpy.LibRawError, OSError, CaptureError):
        return None


def load_raw(path: Path) -> tuple[np.ndarray, dict]:
    """Develop a RAW file to linear sRGB-primaries float32 (H, W, 3); info has black/white levels and WB."""
    buf = read_input_bytes(path)  # LibRaw reads from memory: any file name works, a FIFO is never opened
    try:
        with rawpy.imread(io.BytesIO(buf)) as r:
            info = {"black_level": [int(v) for v in r.black_level_per_channel],
                    "white_level": int(r.white_level),
                    "camera_wb": [float(v) for v in r.camera_whitebalance]}
            rgb = r.postprocess(use_camera_wb=True, gamma=(1, 1), no_auto_bright=True, output_bps=16,
                                adjust_maximum_thr=0.0, output_color=rawpy.ColorSpace.sRGB)
    except rawpy.LibRawFileUnsupportedError:
        raise CaptureError(f"{path}: not a RAW format LibRaw can decode (unsupported or not an image)") from None
    except (rawpy.LibRawIOError, rawpy.LibRawDataError) as e:
        raise CaptureError(f"{path}: unreadable or truncated RAW file ({type(e).__name__})") from None
    except rawpy.LibRawError as e:
        raise CaptureError(f"{path}: RAW decoding failed ({type(e).__name__}: {e})") from None
    except OSError as e:
        raise CaptureError(f"{path}: cannot read ({e})") from None
    return rgb.astype(np.float32) / 65535.0, info


def _truncated(path: Path, buf: bytes) -> bool:
    ext = path.suffix.lower()
    if ext in (".jpg", ".jpeg"):
        return not buf.rstrip(b"\0\r\n ").endswith(b"\xff\xd9")
    if ext == ".png":
        return b"IEND" not in buf[-32:]
    return False


def load_image(path: Path) -> tuple[np.ndarray, dict]:
    """Decode an 8/16-bit (or float) TIFF/PNG/JPEG to linear float32 RGB (H, W, 3)."""
    buf = read_input_bytes(path)
    if _truncated(path, buf):
        raise CaptureError(f"{path}: truncated image file (no end marker)")
    img = cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if img is None:
        raise CaptureError(f"{path}: not a readable image (OpenCV could not decode it)")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    elif img.shape[2] == 4:
        img = img[..., :3]
    img = img[..., ::-1]  # BGR → RGB
    if img.dtype == np.uint8:
        return srgb_to_linear(img.astype(np.float32) / 255.0), {"bits": 8}
    if img.dtype == np.uint16:
        return srgb_to_linear(img.astype(np.float32) / 65535.0), {"bits": 16}
    if img.dtype in (np.float32, np.float64):
        return np.ascontiguousarray(img, dtype=np.float32), {"bits": 32, "linear": True}
    raise CaptureError(f"{path}: unsupported pixel type {img.dtype}")


def load_frame(path: str | Path) -> tuple[np.ndarray, dict]:
    """Linear RGB float32 (H, W, 3) of one frame file (RAW or image) and decoding info."""
    path = Path(path)
    if is_raw(path):
        return load_raw(path)
    if path.suffix.lower() in IMAGE_EXTENSIONS:
        return load_image(path)
    raise CaptureError(f"{path}: unknown frame type {path.suffix!r} (expected RAW, TIFF, PNG or JPEG)")
