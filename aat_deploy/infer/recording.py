"""Write a capture's results as a rerun recording (.rrd) for `aat-view` / the rerun viewer.

Entities (all under `world/camera`, a pinhole at the origin looking along +z, RDF axes):
- `world/camera` Pinhole with the output camera's intrinsics (aat_deploy.optics.camera).
- `world/camera/frames` Image of each input frame on the `focus` timeline (sequence = frame index, near to far),
  with `focus_m` Scalars beside it.
- `world/camera/depth` DepthImage in metres from the sensor (meter = 1) with an explicit colour map and range,
  `world/camera/aif` the all-in-focus image, `world/camera/std_m` the uncertainty (metres, a DepthImage so the
  viewer colours it), `world/camera/gt_depth` ground truth if known (the depth's colour map and range).
- `world/points` the depth back-projected through the pinhole (camera frame, aat_deploy.optics.camera), coloured by the
  all-in-focus image: the points of points.ply.
The recording carries a default blueprint: focal stack, depth, all-in-focus, the 3-D view, uncertainty and the
focus distances side by side. The 3-D view shows the points and the camera, not the depth images (rerun would
back-project them from the pinhole, but they are measured from the sensor). Static entities are logged after
`reset_time()` (rerun timelines are sticky).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..io.colorize import ColorScale
from ..optics.camera import Intrinsics

MAX_POINTS = 200_000


def blueprint(has_gt: bool) -> rrb.Blueprint:
    """The layout the viewer opens on: stack, depth, all-in-focus / 3-D, uncertainty, focus distances."""
    view2d = lambda entity, name: rrb.Spatial2DView(origin="world/camera", contents=[f"+ {entity}"], name=name)
    top = [view2d("world/camera/frames", "focal stack"), view2d("world/camera/depth", "depth (m from sensor)"),
           view2d("world/camera/aif", "all-in-focus")]
    bottom = [rrb.Spatial3DView(origin="world", contents=["+ world/points", "+ world/camera"], name="3-D points"),
              view2d("world/camera/std_m", "uncertainty (m)")]
    if has_gt:
        bottom.append(view2d("world/camera/gt_depth", "ground truth depth"))
    bottom.append(rrb.TimeSeriesView(origin="focus_m", name="focus distance (m)"))
    return rrb.Blueprint(rrb.Vertical(rrb.Horizontal(*top), rrb.Horizontal(*bottom)), collapse_panels=False)


def write_recording(path: str | Path, *, frames_srgb8: list[np.ndarray], focus_m: list[float],
                    depth_m: np.ndarray, aif_srgb8: np.ndarray, std_m: np.ndarray | None, camera: Intrinsics,
                    points: np.ndarray, point_colors: np.ndarray, depth_scale: ColorScale,
                    std_scale: ColorScale | None = None, gt_depth_m: np.ndarray | None = None,
                    name: str = "aat") -> None:
    """Save a recording to `path`.

    frames_srgb8: S images (H, W, 3) uint8 sRGB in focus order; focus_m: S distances (m); depth_m, std_m: (H, W)
    float32 metres; aif_srgb8: (H, W, 3) uint8; camera: intrinsics of (H, W); points (N, 3) metres in the camera
    frame with point_colors (N, 3) uint8; depth_scale / std_scale: the colour maps and ranges of the previews.
    """
    h, w = depth_m.shape
    safe = name.encode("utf-8", "backslashreplace").decode("utf-8")  # a non-UTF-8 folder name (surrogates)
    rec = rr.RecordingStream(application_id="aat", recording_id=safe)
    bp = blueprint(gt_depth_m is not None and gt_depth_m.shape == depth_m.shape)
    mem = None
    try:
        str(path).encode("utf-8")
        rec.save(str(path), default_blueprint=bp)
    except UnicodeEncodeError:  # rerun takes UTF-8 paths only: record in memory, Python writes the file
        mem = rec.memory_recording()
        rec.send_blueprint(bp)
    rec.log("world/camera", rr.ViewCoordinates.RDF, static=True)
    rec.log("world/camera", rr.Pinhole(image_from_camera=[[camera.fx, 0, camera.cx + 0.5],
                                                          [0, camera.fy, camera.cy + 0.5], [0, 0, 1]],
                                       width=w, height=h, camera_xyz=rr.ViewCoordinates.RDF), static=True)
    for i, (img, f) in enumerate(zip(frames_srgb8, focus_m)):
        rec.set_time("focus", sequence=i)
        rec.log("world/camera/frames", rr.Image(img))
        rec.log("focus_m", rr.Scalars(float(f)))
    rec.reset_time()
    depth_kw = dict(meter=1.0, colormap=depth_scale.colormap, depth_range=(depth_scale.lo_m, depth_scale.hi_m))
    rec.log("world/camera/depth", rr.DepthImage(np.nan_to_num(depth_m, nan=0.0).astype(np.float32), **depth_kw),
            static=True)
    rec.log("world/camera/aif", rr.Image(aif_srgb8), static=True)
    if std_m is not None:
        std_kw = dict(meter=1.0) if std_scale is None else dict(
            meter=1.0, colormap=std_scale.colormap, depth_range=(std_scale.lo_m, std_scale.hi_m))
        rec.log("world/camera/std_m", rr.DepthImage(np.nan_to_num(std_m, nan=0.0).astype(np.float32), **std_kw),
                static=True)
    if gt_depth_m is not None and gt_depth_m.shape == depth_m.shape:
        gt = np.where(np.isfinite(gt_depth_m), gt_depth_m, 0).astype(np.float32)
        rec.log("world/camera/gt_depth", rr.DepthImage(gt, **depth_kw), static=True)
    rec.log("world/points", rr.Points3D(points, colors=point_colors), static=True)
    rec.flush()
    if mem is not None:
        Path(path).write_bytes(mem.drain_as_bytes())
    rec.disconnect()
