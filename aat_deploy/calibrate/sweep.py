"""One chart sweep: its frames read as the runtime reads captures, the chart found, every tile's object distance
and focus peak (`peaks.py`), with one-line errors for what makes a sweep unusable.

A sweep folder is a capture folder (docs/contracts.md): the chart at one place, shot at many focus settings
(their reported focus from the metadata or `capture.json`). Frames larger than `max_side` are reduced (area
averaging) before measuring; field positions are normalised, so nothing else changes, and blur in pixels is
scaled back to the frames' own size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..capture.folder import read_capture
from ..capture.raw import load_frame
from ..errors import CaptureError
from .chart import ChartLayout
from .peaks import SweepPeaks, TileGrid, tile_peaks
from .pose import best_view, focal_from_view, intrinsics_matrix, plane_depth_mm, pose_from_view

MIN_TEXTURED_SHARE = 0.1  # of the frame's tiles: a chart covering less says little about the field
MIN_BRACKETED_SHARE = 0.5
MIN_FRAMES = 5
MAX_POSE_FOCAL_REL = 0.01  # a distance from the pose alone: its error is the focal length's (1 %: 0.01 D at 1 m)
MAX_START_FOCAL_REL = 0.1  # a bare `~`'s start from the pose: a focal length within 10 % (the fit does the rest)


class SweepError(CaptureError):
    """A sweep cannot be used (one line naming the folder and the problem)."""


@dataclass
class Sweep:
    """frames (S, 3, h, w) float32 linear at the working size, far to near: reported_m (S,) descending, so the
    reported diopters ascend; identity: make, model, lens, focal_length_mm, f_number (EXIF);
    size_px (W, H) of the frames as shot; scale: working width / shot width."""

    path: Path
    frames: np.ndarray
    reported_m: np.ndarray
    identity: dict
    size_px: tuple[int, int]
    scale: float
    warnings: list[str] = field(default_factory=list)

    @property
    def reported_d(self) -> np.ndarray:
        return 1.0 / self.reported_m


IDENTITY_KEYS = ("make", "model", "lens", "focal_length_mm", "f_number")


def identity_of(meta) -> dict:
    return {k: getattr(meta, k) for k in IDENTITY_KEYS}


def identity_differences(a: dict, b: dict) -> list[str]:
    """Keys whose values differ between two frames' identities (None on either side is not compared)."""
    out = []
    for k in IDENTITY_KEYS:
        va, vb = a.get(k), b.get(k)
        if va is None or vb is None or va == "" or vb == "":
            continue
        same = abs(float(va) / float(vb) - 1) < 1e-3 if isinstance(va, (int, float)) else str(va) == str(vb)
        if not same:
            out.append(f"{k} {va!r} vs {vb!r}")
    return out


def load_sweep(folder: str | Path, max_side: int | None = 1600, min_frames: int = MIN_FRAMES, *,
               max_megapixels: float | None = None, allow_outside_links: bool = False) -> Sweep:
    """Frames and reported focus of a sweep folder; SweepError for fewer than MIN_FRAMES frames, frames of other
    sizes, or frames from different cameras (make, model, lens, focal length, f-number in their EXIF).
    max_megapixels / allow_outside_links: the readers' pixel limit and links out of the folder, as aat-infer."""
    folder = Path(folder)
    try:
        cap = read_capture(folder, max_megapixels=max_megapixels, allow_outside_links=allow_outside_links)
    except CaptureError as e:
        raise SweepError(str(e)) from None
    frames = sorted(cap.frames, key=lambda f: -f.focus_m)  # far to near: reported diopters ascending
    if len(frames) < min_frames:
        raise SweepError(f"{folder}: {len(frames)} frames; a calibration sweep needs at least {min_frames} (better "
                         "15-25, evenly in diopters across the chart)")
    ids = [identity_of(f.meta) for f in frames]
    for f, i in zip(frames[1:], ids[1:]):
        diff = identity_differences(ids[0], i)
        if diff:
            raise SweepError(f"{f.path}: from another camera than {frames[0].path.name} ({'; '.join(diff)}): a sweep "
                             "is one camera, lens, aperture and zoom")
    images, size = [], None
    for f in frames:
        img, _ = load_frame(f.path, max_megapixels)
        if size is None:
            size = img.shape[:2]
        elif img.shape[:2] != size:
            raise SweepError(f"{f.path}: {img.shape[1]}x{img.shape[0]} px, the other frames {size[1]}x{size[0]} px")
        images.append(img)
    h, w = size
    scale = 1.0
    if max_side and max(h, w) > max_side:
        scale = max_side / max(h, w)
        wh = (max(1, round(w * scale)), max(1, round(h * scale)))
        images = [cv2.resize(im, wh, interpolation=cv2.INTER_AREA) for im in images]
        scale = wh[0] / w
    arr = np.stack([np.ascontiguousarray(im.transpose(2, 0, 1), np.float32) for im in images])
    identity = {k: next((i[k] for i in ids if i[k] not in (None, "")), None) for k in IDENTITY_KEYS}
    return Sweep(folder, arr, np.array([f.focus_m for f in frames], np.float64), identity, (w, h), scale,
                 list(cap.warnings))


@dataclass
class Geometry:
    """How distances were obtained: f_px (working px) or None, pupil_to_sensor_mm, how ("measured distance" |
    "pose"), notes."""

    pupil_to_sensor_mm: float
    how: str
    f_px: float | None = None
    notes: list[str] = field(default_factory=list)


@dataclass
class SweepMeasurement:
    """A measured sweep: peaks; object_d (ny, nx) the tiles' object diopters from the sensor plane; view; geometry;
    chart_distance_m on the optical axis (measured or from the pose); depth_ratio (H, W) the chart plane's
    distance from the pupil at each pixel over the one at the frame centre (what a change of the chart's distance
    scales); fit_distance: the chart distance is an unknown of the fit, chart_distance_m only its start
    (`fit.fit_calibration`)."""

    sweep: Sweep
    peaks: SweepPeaks
    object_d: np.ndarray
    view: object
    geometry: Geometry
    chart_distance_m: float
    depth_ratio: np.ndarray | None = None
    fit_distance: bool = False

    def object_dz(self) -> np.ndarray:
        """(ny, nx) D of each tile's object per mm of the chart's distance on the axis (negative: farther is fewer
        diopters); zeros without depth_ratio."""
        if self.depth_ratio is None:
            return np.zeros_like(self.object_d)
        z_mm = self._z_mm(self.chart_distance_m)
        return self.peaks.grid.mean(-1000.0 * self.depth_ratio / z_mm ** 2)

    def _z_mm(self, distance_m: float) -> np.ndarray:
        pupil = self.geometry.pupil_to_sensor_mm
        return (1000.0 * distance_m - pupil) * self.depth_ratio + pupil

    def at_distance(self, distance_m: float, how: str) -> SweepMeasurement:
        """The same sweep with the chart at another distance on the axis (its tiles' objects recomputed)."""
        from dataclasses import replace

        z_mm = self._z_mm(distance_m)
        if not np.all(z_mm > 0):
            raise SweepError(f"{self.sweep.path}: a chart distance of {distance_m:.4g} m puts the chart's plane "
                             "behind the camera")
        geo = replace(self.geometry, how=how)
        return replace(self, object_d=self.peaks.grid.mean(1000.0 / z_mm), chart_distance_m=float(distance_m),
                       geometry=geo)


# the fit's tiles: 1/24 of the frame's width (27 px on 640); 1/32 and 1/27 were judged and not adopted (docs/calibration.md)
TILES_PER_WIDTH = 24


def tile_px_for(width: int) -> int:
    """Tiles of about 1/TILES_PER_WIDTH of the frame width (1/24), at least 16 px."""
    return max(16, int(round(width / TILES_PER_WIDTH)))


def measure_sweep(sweep: Sweep, layout: ChartLayout, distance_m: float | None = None,
                  pupil_to_sensor_mm: float | None = None, sensor_mm: tuple[float, float] | None = None,
                  measure: str = "mlap2", window_px: float = 15.0, prefilter_px: float = 1.0,
                  estimator: str = "gauss", tile_px: int | None = None, fit_distance: bool = False,
                  tiles_to_edges: bool = False) -> SweepMeasurement:
    """The chart's distance at every tile and every tile's focus peak. distance_m: measured from the sensor plane
    to the chart point at the frame centre (recommended); without it the distance comes from the pose, with the
    focal length in pixels from the EXIF focal length and sensor_mm, else fitted from the chart's perspective.
    fit_distance: the distance (measured, or without distance_m from the pose: `--distance-m ...,~`) is only a
    start, fitted where the measured charts' tiles fit best (`fit.fit_calibration`; a chart too near for a tape's
    millimetre). tiles_to_edges: tiles spread from edge to edge instead of centred (`peaks.TileGrid`; a probe's,
    not the fit's default). SweepError (one line naming the folder) when a distance is needed from markers that give
    no pose."""
    s, _, h, w = sweep.frames.shape
    view = best_view(sweep.frames, layout)
    if view is None:
        raise SweepError(f"{sweep.path}: chart markers not found (fewer than 4 of {len(layout.ids)} markers in every "
                         "frame): is this the chart of the chart.json given, in focus in at least one frame, and "
                         "large enough (markers of 20 px or more)?")
    efl = sweep.identity.get("focal_length_mm")
    notes: list[str] = []
    if pupil_to_sensor_mm is None:
        pupil = float(efl) if efl else 0.0
        notes.append("entrance pupil assumed " + (f"a focal length ({pupil:g} mm) in front of the sensor" if efl else
                                                  "at the sensor (no focal length known)")
                     + ": give --pupil-to-sensor-mm if known")
    else:
        pupil = float(pupil_to_sensor_mm)
    grid = TileGrid(h, w, tile_px or tile_px_for(w), to_edges=tiles_to_edges)
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    cx, cy = (w - 1) / 2, (h - 1) / 2
    f_px = None
    if efl and sensor_mm:
        f_px = float(efl) / (sensor_mm[0] / w)
    if distance_m is not None:
        z_c = 1000.0 * distance_m - pupil
        depth = (z_c * view.depth_ratio(uu, vv, cx, cy) + pupil) / 1000.0
        geo = Geometry(pupil, "measured distance", f_px, notes)
        axis_m = float(distance_m)
    else:
        if fit_distance:  # a bare `~`: the fit's start is the marker pose
            why = f"{sweep.path}: a distance marked ~ alone starts from the chart's marker pose, and there is none"
            fix = ("give a start (~D, metres from the sensor plane to the chart at the frame centre), or "
                   "--sensor-mm with EXIF focal length, or tilt the chart 15-30 degrees so its perspective gives "
                   "the focal length")
        else:
            why = f"{sweep.path}: no chart distance"
            fix = ("give --distance-m (measured from the sensor plane to the chart at the frame centre), or "
                   "--sensor-mm with EXIF focal length, or tilt the chart 15-30 degrees so its perspective gives the "
                   "focal length")
        if f_px is None:
            f_px, rel = focal_from_view(view, w, h)
            limit = MAX_START_FOCAL_REL if fit_distance else MAX_POSE_FOCAL_REL
            if not (math.isfinite(f_px) and rel < limit):
                got = f"+-{100 * rel:.1f} %" if math.isfinite(rel) else "undetermined"
                raise SweepError(f"{why}: the chart is too square to the camera (or too small in the frame): its "
                                 f"perspective gives the focal length in pixels only to {got} "
                                 f"(need under {100 * limit:.0f} %): {fix}")
            notes.append(f"focal length {f_px:.1f} px fitted from the chart's perspective (+-{100 * rel:.2g} %)")
        k = intrinsics_matrix(f_px, w, h)
        try:
            r, t, _ = pose_from_view(view, k)
        except (ValueError, cv2.error):
            raise SweepError(f"{why}: the markers' pose could not be solved: {fix}") from None
        z = plane_depth_mm(r, t, k, uu, vv)
        depth = (z + pupil) / 1000.0
        axis_m = float(plane_depth_mm(r, t, k, cx, cy) + pupil) / 1000.0
        if not (math.isfinite(axis_m) and axis_m > 0):
            raise SweepError(f"{why}: the markers' pose puts the chart behind the camera (markers mismatched?)")
        geo = Geometry(pupil, "pose", f_px, notes + ([] if fit_distance else [
            "chart distance from the marker pose (no --distance-m): its error scales every distance of this sweep"]))
    if not np.all(depth > 0):
        raise SweepError(f"{sweep.path}: the chart's plane passes behind the camera (markers mismatched?)")
    mask = view.chart_mask(h, w, layout, margin_mm=0.02 * min(layout.size_mm))
    on = grid.mean(mask.astype(np.float32)) > 0.999
    object_d = grid.mean((1.0 / depth).astype(np.float64))
    pk = tile_peaks(sweep.frames, sweep.reported_d, grid, on, measure, window_px, prefilter_px, estimator)
    textured = pk.why == ""
    unbracketed = pk.why == "unbracketed"
    n_tex = int(textured.sum() + unbracketed.sum())
    need = max(12, int(math.ceil(MIN_TEXTURED_SHARE * on.size)))
    if n_tex < need:
        raise SweepError(f"{sweep.path}: too few textured tiles on the chart ({n_tex} of {on.size}, need {need}): "
                         f"{int(on.sum())} of {on.size} tiles lie on the chart; fill more of the frame with it and "
                         "light it evenly")
    if textured.sum() < MIN_BRACKETED_SHARE * n_tex:
        near, far = float(sweep.reported_m.min()), float(sweep.reported_m.max())
        lo, hi = float(np.nanmin(1 / object_d[on])), float(np.nanmax(1 / object_d[on]))
        raise SweepError(f"{sweep.path}: the sweep does not bracket the chart: {int(unbracketed.sum())} of {n_tex} "
                         f"textured tiles are sharpest in the first or last frame (reported focus {near:.3g}..{far:.3g}"
                         f" m, chart at {lo:.3g}..{hi:.3g} m): extend the sweep beyond the chart on both sides")
    ratio = (1000.0 * depth - pupil) / (1000.0 * axis_m - pupil)
    return SweepMeasurement(sweep, pk, object_d, view, geo, axis_m, ratio.astype(np.float32), bool(fit_distance))

