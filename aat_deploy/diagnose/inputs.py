"""A capture folder with ground truth, loaded the way `aat-infer` sees it: frames decoded to linear RGB, fitted
to the model's sensor, sorted by focus; ground truth depth and (if supplied) all-in-focus at the same geometry."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from aat_deploy.capture.folder import read_capture
from aat_deploy.capture.raw import load_frame, srgb_to_linear
from aat_deploy.errors import CaptureError
from aat_deploy.geometry import fit_to_sensor
from aat_deploy.model import DfFModel
from aat_deploy.pipeline import _ground_truth


@dataclass
class CaptureData:
    name: str
    path: Path
    frames: np.ndarray  # (S, 3, H, W) float32 linear RGB at the model's sensor geometry, ascending focus
    focus_m: np.ndarray  # (S,) reported focus distances, m from the sensor, ascending
    gt_m: np.ndarray  # (H, W) float32 ground-truth depth, m from the sensor; NaN = unknown
    aif_linear: np.ndarray | None = None  # (3, H, W) supplied all-in-focus (gt_aif.png), linear
    warnings: list[str] = field(default_factory=list)


def has_ground_truth(folder: Path) -> bool:
    return (folder / "gt_depth_m.npy").is_file() or (folder / "gt_depth_mm.png").is_file()


def find_captures(root: str | Path) -> list[Path]:
    """ROOT itself if it is a capture folder with ground truth, else its sub-folders (recursively) that are."""
    root = Path(root)
    if not root.is_dir():
        raise CaptureError(f"{root}: not a folder")
    if has_ground_truth(root):
        return [root]
    return sorted(p for p in root.rglob("*") if p.is_dir() and has_ground_truth(p))


def load_capture_data(folder: str | Path, model: DfFModel, use_exiftool: bool = True) -> CaptureData:
    folder = Path(folder)
    cap = read_capture(folder, use_exiftool=use_exiftool)
    frames = sorted(cap.frames, key=lambda f: f.focus_m)
    w_px, h_px = model.sensor_px
    images, size0 = [], None
    for f in frames:
        img, _ = load_frame(f.path)
        if size0 is None:
            size0 = img.shape[:2]
        elif img.shape[:2] != size0:
            raise CaptureError(f"{f.path}: frame size differs from {frames[0].path.name}")
        images.append(fit_to_sensor(img, (w_px, h_px))[0].transpose(2, 0, 1))
    warnings = list(cap.warnings)
    gt = _ground_truth(cap, size0, (w_px, h_px), warnings)
    if gt is None or not np.isfinite(gt).any():
        raise CaptureError(f"{folder}: no usable ground-truth depth (gt_depth_m.npy or gt_depth_mm.png)")
    aif = None
    if cap.gt_aif is not None:
        img = cv2.imread(str(cap.gt_aif), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise CaptureError(f"{cap.gt_aif}: unreadable all-in-focus image")
        scale = 65535.0 if img.dtype == np.uint16 else 255.0
        rgb = srgb_to_linear(cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / scale)
        aif = fit_to_sensor(rgb, (w_px, h_px))[0].transpose(2, 0, 1).astype(np.float32)
    return CaptureData(cap.name, folder, np.stack(images).astype(np.float32),
                       np.array([f.focus_m for f in frames], np.float64), gt, aif, warnings)
