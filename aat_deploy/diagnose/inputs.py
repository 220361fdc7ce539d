"""A capture folder with ground truth, loaded the way `aat-infer` sees it: frames decoded to linear RGB, fitted
to the model's sensor, sorted by focus; ground truth depth and (if supplied) all-in-focus at the same geometry."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aat_deploy.capture.folder import read_capture
from aat_deploy.capture.raw import load_frame
from aat_deploy.errors import CaptureError
from aat_deploy.eval import batch
from aat_deploy.gt.read import check_units, find_gt, load_ground_truth, to_sensor
from aat_deploy.infer.frames import FrameReader
from aat_deploy.infer.geometry import fit_to_sensor
from aat_deploy.infer.model import DfFModel


@dataclass
class CaptureData:
    name: str
    path: Path
    frames: np.ndarray  # (S, 3, H, W) float32 linear RGB at the model's sensor geometry, ascending focus
    focus_m: np.ndarray  # (S,) reported focus distances, m from the sensor, ascending
    gt_m: np.ndarray  # (H, W) float32 ground-truth depth, m from the sensor; NaN = unknown
    aif_linear: np.ndarray | None = None  # (3, H, W) supplied all-in-focus (gt_aif.png), linear
    warnings: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)  # frame file names, in the frames' order


def find_captures(root: str | Path, exclude: list[Path] = ()) -> list[Path]:
    """Capture folders with ground truth under ROOT (ROOT included), as `aat-eval` finds them."""
    return batch.find_captures(Path(root), list(exclude))[0]


def load_capture_data(folder: str | Path, model: DfFModel, use_exiftool: bool = True, *,
                      max_megapixels: float | None = None, allow_outside_links: bool = False) -> CaptureData:
    """max_megapixels / allow_outside_links: the readers' pixel limit and links out of the folder, as aat-infer."""
    folder = Path(folder)
    cap = read_capture(folder, use_exiftool=use_exiftool, max_megapixels=max_megapixels,
                       allow_outside_links=allow_outside_links)
    frames = sorted(cap.frames, key=lambda f: f.focus_m)
    w_px, h_px = model.sensor_px
    reader = FrameReader([f.path for f in frames], max_megapixels)  # aat-infer's frame reader (sizes checked)
    images = []
    for img in reader.frames():
        fitted, geometry = fit_to_sensor(img, (w_px, h_px))
        images.append(fitted.transpose(2, 0, 1))
    size0 = reader.first_hw()
    warnings = list(cap.warnings)
    src = find_gt(folder, allow_outside_links)
    if src is None:
        raise CaptureError(f"{folder}: no ground-truth depth (see docs/contracts.md)")
    truth = load_ground_truth(src, max_megapixels)
    check_units(truth, model.focus_range_m)
    warnings += truth.warnings
    gt = to_sensor(truth.depth_m, (size0[1], size0[0]), geometry["crop_xywh"], (w_px, h_px), src.depth)
    aif = None
    if src.aif is not None:
        rgb, _ = load_frame(src.aif, max_megapixels)  # the frame reader: kind from content, pixel limit, sRGB to linear
        aif = fit_to_sensor(rgb, (w_px, h_px))[0].transpose(2, 0, 1).astype(np.float32)
    return CaptureData(cap.name, folder, np.stack(images).astype(np.float32),
                       np.array([f.focus_m for f in frames], np.float64), gt, aif, warnings,
                       [f.path.name for f in frames])
