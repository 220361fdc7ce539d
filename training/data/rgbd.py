"""Real RGB-D scenes for rendering focal stacks: Middlebury 2014 "Motorcycle" and any image + depth map.

Images come back as linear RGB (H, W, 3) float32 in [0, 1] (8/16-bit sRGB files are decoded), depth as (H, W)
float32 metres from the sensor with 0 where unknown. `aat_deploy.gt.holes.fill_holes` gives a hole-free copy for
the renderer (the ground truth keeps its zeros).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from aat_deploy.errors import AatError
from aat_deploy.io.color import srgb_to_linear

SHARED_MIDDLEBURY = Path(__file__).resolve().parents[3] / "shared" / "data" / "middlebury2014_motorcycle"
# Calibration of the x4-downsampled Motorcycle images that scikit-image ships (Middlebury calib.txt / 4).
MOTORCYCLE_F_PX, MOTORCYCLE_DOFFS_PX, MOTORCYCLE_BASELINE_MM = 994.978, 31.086, 193.001


class RGBDError(AatError):
    """A scene file that cannot be used (message names the file and the problem)."""


def read_rgb(path) -> np.ndarray:
    """8- or 16-bit sRGB image file -> linear RGB (H, W, 3) float32 in [0, 1]."""
    path = Path(path)
    im = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if im is None:
        raise RGBDError(f"{path}: not a readable image")
    if im.ndim == 2:
        im = np.repeat(im[..., None], 3, -1)
    im = im[..., :3][..., ::-1]  # BGR(A) -> RGB
    if im.dtype == np.uint8:
        x = im.astype(np.float32) / 255.0
    elif im.dtype == np.uint16:
        x = im.astype(np.float32) / 65535.0
    else:
        raise RGBDError(f"{path}: expected an 8- or 16-bit image, got {im.dtype}")
    return srgb_to_linear(x)


def read_depth(path, scale_m: float | None = None) -> np.ndarray:
    """Depth map -> (H, W) float32 metres, 0 = unknown.

    .npy: metres (times scale_m if given). 16-bit PNG/TIFF: integer units of scale_m metres (default 0.001:
    millimetres). Float TIFF: metres. NaN, inf and negative values become 0 (unknown)."""
    path = Path(path)
    if not path.is_file():
        raise RGBDError(f"{path}: no such depth file")
    if path.suffix.lower() == ".npy":
        try:
            d = np.load(path).astype(np.float32)
        except Exception as e:
            raise RGBDError(f"{path}: not a readable .npy ({e})") from None
        d = d * np.float32(scale_m or 1.0)
    else:
        d = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if d is None:
            raise RGBDError(f"{path}: not a readable depth image")
        if d.ndim != 2:
            raise RGBDError(f"{path}: depth must be single-channel, got shape {d.shape}")
        if d.dtype == np.uint16:
            d = d.astype(np.float32) * np.float32(0.001 if scale_m is None else scale_m)
        elif d.dtype == np.float32:
            d = d * np.float32(scale_m or 1.0)
        else:
            raise RGBDError(f"{path}: depth must be 16-bit integer (mm) or float32 (m), got {d.dtype}")
    if d.ndim != 2:
        raise RGBDError(f"{path}: depth must be 2-D, got shape {d.shape}")
    d = np.where(np.isfinite(d) & (d > 0), d, 0).astype(np.float32)
    if not (d > 0).any():
        raise RGBDError(f"{path}: no valid depth (all zero, NaN or negative)")
    return d


def load_rgbd(rgb_path, depth_path, depth_scale_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A generic scene: image file + depth file of the same size (see read_rgb, read_depth)."""
    rgb, depth = read_rgb(rgb_path), read_depth(depth_path, depth_scale_m)
    if rgb.shape[:2] != depth.shape:
        raise RGBDError(f"{depth_path}: depth is {depth.shape[1]}x{depth.shape[0]} but {rgb_path} is "
                        f"{rgb.shape[1]}x{rgb.shape[0]}")
    return rgb, depth


def load_middlebury_motorcycle(shared_dir: Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Middlebury 2014 Motorcycle at 500 x 741 (x4 down-sampled): linear RGB and metric depth (m, 0 = unknown).

    RGB and disparity from scikit-image (`skimage.data.stereo_motorcycle`); depth = f * baseline / (disp + doffs)
    with the x4 calibration. If ../shared/data/middlebury2014_motorcycle is present its full-resolution depth
    (mm) is block-median down-sampled instead (the same numbers to 1e-4)."""
    from skimage.data import stereo_motorcycle

    left, _, disp = stereo_motorcycle()
    rgb = srgb_to_linear(left.astype(np.float32) / 255.0)
    d = shared_dir or SHARED_MIDDLEBURY
    full = d / "Motorcycle-perfect_depth_fullres_mm.png"
    if full.is_file():
        mm = cv2.imread(str(full), cv2.IMREAD_UNCHANGED).astype(np.float32)
        h, w = rgb.shape[:2]
        blocks = mm[: 4 * h, : 4 * w].reshape(h, 4, w, 4).transpose(0, 2, 1, 3).reshape(h, w, 16)
        blocks = np.where(blocks > 0, blocks, np.nan)
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                depth = np.nanmedian(blocks, -1) / 1000.0
        depth = np.where(np.isfinite(depth), depth, 0).astype(np.float32)
    else:
        disp = np.asarray(disp, dtype=np.float64)
        ok = np.isfinite(disp)
        depth = np.where(ok, MOTORCYCLE_F_PX * MOTORCYCLE_BASELINE_MM / (np.where(ok, disp, 0) + MOTORCYCLE_DOFFS_PX)
                         / 1000.0, 0).astype(np.float32)
    return rgb, depth

