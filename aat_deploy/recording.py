"""Write a capture's results as a rerun recording (.rrd) for `aat-view` / the rerun viewer.

Entities (all under `world/camera`, a pinhole at the origin looking along +z, RDF axes):
- `world/camera` Pinhole from the model's lens: focal length px = focal_length_mm / pixel pitch mm.
- `world/camera/frames` Image of each input frame on the `focus` timeline (sequence = frame index, near to far),
  with `focus_m` Scalars beside it.
- `world/camera/depth` DepthImage in metres (meter = 1), `world/camera/aif` the all-in-focus image,
  `world/camera/std_m` the uncertainty (metres, float image), `world/camera/gt_depth` ground truth if known.
- `world/points` the depth back-projected through the pinhole, coloured by the all-in-focus image.
Static entities are logged after `reset_time()` (rerun timelines are sticky).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

MAX_POINTS = 200_000


def backproject(depth_m: np.ndarray, f_px: float, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) in metres (x right, y down, z forward) of depth_m (H, W) through a centred pinhole,
    and the (N, 2) integer pixel (row, col) they came from. Pixels with non-finite or non-positive depth skipped."""
    h, w = depth_m.shape
    rows, cols = np.mgrid[0:h:stride, 0:w:stride]
    z = depth_m[rows, cols]
    ok = np.isfinite(z) & (z > 0)
    rows, cols, z = rows[ok], cols[ok], z[ok]
    x = (cols + 0.5 - w / 2) / f_px * z
    y = (rows + 0.5 - h / 2) / f_px * z
    return np.stack([x, y, z], -1).astype(np.float32), np.stack([rows, cols], -1)


def write_recording(path: str | Path, *, frames_srgb8: list[np.ndarray], focus_m: list[float],
                    depth_m: np.ndarray, aif_srgb8: np.ndarray, std_m: np.ndarray, f_px: float,
                    gt_depth_m: np.ndarray | None = None, name: str = "aat") -> None:
    """Save a recording to `path`.

    frames_srgb8: S images (H, W, 3) uint8 sRGB in focus order; focus_m: S distances (m);
    depth_m, std_m: (H, W) float32 metres; aif_srgb8: (H, W, 3) uint8; f_px: focal length in pixels.
    """
    h, w = depth_m.shape
    safe = name.encode("utf-8", "backslashreplace").decode("utf-8")  # a non-UTF-8 folder name (surrogates)
    rec = rr.RecordingStream(application_id="aat", recording_id=safe)
    mem = None
    try:
        str(path).encode("utf-8")
        rec.save(str(path))
    except UnicodeEncodeError:  # rerun takes UTF-8 paths only: record in memory, Python writes the file
        mem = rec.memory_recording()
    rec.log("world/camera", rr.ViewCoordinates.RDF, static=True)
    rec.log("world/camera", rr.Pinhole(focal_length=float(f_px), width=w, height=h,
                                       camera_xyz=rr.ViewCoordinates.RDF), static=True)
    for i, (img, f) in enumerate(zip(frames_srgb8, focus_m)):
        rec.set_time("focus", sequence=i)
        rec.log("world/camera/frames", rr.Image(img))
        rec.log("focus_m", rr.Scalars(float(f)))
    rec.reset_time()
    rec.log("world/camera/depth", rr.DepthImage(depth_m.astype(np.float32), meter=1.0), static=True)
    rec.log("world/camera/aif", rr.Image(aif_srgb8), static=True)
    rec.log("world/camera/std_m", rr.Image(std_m.astype(np.float32), color_model="L"), static=True)
    if gt_depth_m is not None and gt_depth_m.shape == depth_m.shape:
        gt = np.where(np.isfinite(gt_depth_m), gt_depth_m, 0).astype(np.float32)
        rec.log("world/camera/gt_depth", rr.DepthImage(gt, meter=1.0), static=True)
    stride = max(1, int(np.ceil(np.sqrt(h * w / MAX_POINTS))))
    pts, rc = backproject(depth_m, f_px, stride)
    rec.log("world/points", rr.Points3D(pts, colors=aif_srgb8[rc[:, 0], rc[:, 1]]), static=True)
    rec.flush()
    if mem is not None:
        Path(path).write_bytes(mem.drain_as_bytes())
    rec.disconnect()
