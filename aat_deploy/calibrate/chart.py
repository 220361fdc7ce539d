"""The calibration chart: a flat target with a multi-scale random texture for the focus measure and ArUco markers
from which its pose, and so every pixel's true distance, is measured (`aat-calibrate chart`).

The texture is a "dead leaves" image (ISO 19567-2's texture target; Cao, Guichard, Hornung 2010): opaque discs of
random grey with radii distributed as r^-3 between `leaf_min_mm` and `leaf_max_mm`, drawn until the chart is
covered. It is statistically the same at every scale, so the focus measure sees texture at any chart distance and
focal length. Its sharp disc edges put far more of its power at the finest detail than photographs have (at 0.25-0.5
cycles per pixel 17 % against 3 %), and where a lens is astigmatic the focus measure then peaks elsewhere than on
the scenes depth from focus will see: `texture_sigma_mm` softens the texture (not the markers) with a Gaussian,
and `texture_sigma_for` sets it to SOFT_SENSOR_PX pixels of the camera's image where the chart fills the frame
(`aat-calibrate chart --frame-px W`), which gives the texture the photographs' share of fine detail
(benchmarks/probes/chart_texture.py; docs/calibration.md). Markers (OpenCV's predefined ArUco dictionary `DICT_4X4_250`) sit on a regular grid, each on a white
quiet zone one module wide; the texture fills everything between them.

Coordinates: chart millimetres with the origin at the chart's centre, x right, y down (as printed, seen from the
front), z into the chart. `ChartLayout` (saved as `chart.json` beside the image, format `aat-chart-v1`) holds the
size and every marker's corners in that frame; `aat-calibrate fit` needs it to measure the pose.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..errors import CaptureError
from ..io.files import load_json

FORMAT = "aat-chart-v1"
DICTIONARY = "DICT_4X4_250"
MARKER_BITS = 4  # modules of data per side; plus a black border of one module on each side
QUIET_MODULES = 1.0  # white margin around each marker, in modules
# the texture's softening (Gaussian SD) in pixels of the camera's image where the chart fills the frame: the
# value whose finest band's power share (0.25-0.5 cycles/px, 3.3 %) is the nearest, on a 0.1 px grid, to the
# training photographs' (2.9 %; the dead leaves' 16.5 %), chosen so before any sweep was rendered with it
# (benchmarks/probes/chart_texture.py --spectra)
SOFT_SENSOR_PX = 0.7


class ChartError(CaptureError):
    """A chart layout file is missing or malformed (one line naming the file)."""


@dataclass(frozen=True)
class ChartSpec:
    """size_mm (W, H) of the printed chart; markers (nx, ny) on a regular grid; marker_mm: side of a marker
    (black border included; default: a quarter of the grid spacing, at most the spacing minus the quiet zone);
    dpi: pixels per inch of the image; leaf_min_mm / leaf_max_mm: the texture's smallest and largest disc radius
    (defaults: 1.5 px and a tenth of the shorter side); seed: the texture's random draw; texture_sigma_mm: the
    texture's Gaussian softening (SD, chart mm; 0: sharp discs; `texture_sigma_for`)."""

    size_mm: tuple[float, float] = (600.0, 400.0)
    markers: tuple[int, int] = (6, 4)
    marker_mm: float | None = None
    dpi: float = 150.0
    leaf_min_mm: float | None = None
    leaf_max_mm: float | None = None
    seed: int = 0
    texture_sigma_mm: float = 0.0

    def __post_init__(self):
        w, h = self.size_mm
        if not (math.isfinite(self.texture_sigma_mm) and self.texture_sigma_mm >= 0):
            raise ValueError(f"texture softening {self.texture_sigma_mm} mm: give a number >= 0")
        nx, ny = self.markers
        if not (w > 0 and h > 0 and math.isfinite(w) and math.isfinite(h)):
            raise ValueError(f"chart size {self.size_mm} mm: give two positive numbers")
        if not (1 <= nx <= 30 and 1 <= ny <= 30 and nx * ny <= 250):
            raise ValueError(f"markers {self.markers}: 1..30 per side, at most 250 ({DICTIONARY})")
        if not 10 <= self.dpi <= 1200:
            raise ValueError(f"dpi {self.dpi}: 10..1200")
        px = self.px_per_mm
        if w * px * h * px > 1.2e8:
            raise ValueError(f"{w:g} x {h:g} mm at {self.dpi:g} dpi is over 120 Mpx: lower --dpi")
        m = self.marker_side_mm
        pitch = min(self.pitch_mm)
        if not 0 < m * (1 + 2 * QUIET_MODULES / (MARKER_BITS + 2)) < pitch:
            raise ValueError(f"markers of {m:.3g} mm with their quiet zone do not fit their spacing of {pitch:.3g} mm")
        if m * px < (MARKER_BITS + 2) * 3:
            raise ValueError(f"markers of {m:.3g} mm are under 3 px per module at {self.dpi:g} dpi: raise --dpi "
                             "or use fewer, larger markers")

    @property
    def px_per_mm(self) -> float:
        return self.dpi / 25.4

    @property
    def pitch_mm(self) -> tuple[float, float]:
        return self.size_mm[0] / self.markers[0], self.size_mm[1] / self.markers[1]

    @property
    def marker_side_mm(self) -> float:
        if self.marker_mm is not None:
            return float(self.marker_mm)
        return 0.25 * min(self.pitch_mm)


@dataclass(frozen=True)
class ChartLayout:
    """size_mm (W, H); ids (N,) marker ids; corners_mm (N, 4, 2) each marker's corners (top-left, top-right,
    bottom-right, bottom-left as printed) in chart mm (origin at the centre, x right, y down); dictionary;
    image_px (W, H) and px_per_mm of the chart image; spec: how it was made."""

    size_mm: tuple[float, float]
    ids: np.ndarray
    corners_mm: np.ndarray
    dictionary: str = DICTIONARY
    image_px: tuple[int, int] = (0, 0)
    px_per_mm: float = 0.0
    spec: dict | None = None

    def board(self):
        """The OpenCV board of these markers (object points in mm, z = 0)."""
        obj = [np.concatenate([c, np.zeros((4, 1))], 1).astype(np.float32) for c in self.corners_mm]
        return cv2.aruco.Board(obj, aruco_dictionary(self.dictionary), self.ids.astype(np.int32).reshape(-1, 1))

    def to_dict(self) -> dict:
        return {"format": FORMAT, "units": "mm; origin at the chart's centre, x right, y down, as printed",
                "size_mm": [float(v) for v in self.size_mm], "dictionary": self.dictionary,
                "image_px": [int(v) for v in self.image_px], "px_per_mm": float(self.px_per_mm),
                "markers": [{"id": int(i), "corners_mm": np.round(c, 4).tolist()}
                            for i, c in zip(self.ids, self.corners_mm)],
                "spec": self.spec or {}}

    @classmethod
    def from_dict(cls, d, source: str = "chart") -> ChartLayout:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ChartError(f"{source}: not a chart layout (format {FORMAT!r} expected; the chart.json "
                             "`aat-calibrate chart` wrote beside the image)")
        try:
            ids = np.array([int(m["id"]) for m in d["markers"]], np.int64)
            corners = np.array([m["corners_mm"] for m in d["markers"]], np.float64)
            size = tuple(float(v) for v in d["size_mm"])
            dictionary = str(d.get("dictionary", DICTIONARY))
            aruco_dictionary(dictionary)
            if corners.shape != (len(ids), 4, 2) or not np.isfinite(corners).all() or len(ids) == 0:
                raise ValueError(f"markers' corners must be 4 x [x, y] each, got {corners.shape}")
            if len(set(ids.tolist())) != len(ids) or len(size) != 2 or min(size) <= 0:
                raise ValueError("marker ids must be distinct and size_mm two positive numbers")
            return cls(size, ids, corners, dictionary, tuple(int(v) for v in d.get("image_px", (0, 0))),
                       float(d.get("px_per_mm", 0.0)), dict(d.get("spec") or {}))
        except (KeyError, TypeError, ValueError) as e:
            what = f"missing key {e}" if isinstance(e, KeyError) else str(e).splitlines()[0][:200]
            raise ChartError(f"{source}: malformed chart layout ({what})") from None


def aruco_dictionary(name: str):
    if not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
        raise ValueError(f"unknown ArUco dictionary {name!r}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def load_layout(path: str | Path) -> ChartLayout:
    """A chart.json; ChartError naming the file if it is not one."""
    return ChartLayout.from_dict(load_json(Path(path), ChartError), str(path))


def dead_leaves(height: int, width: int, r_min_px: float, r_max_px: float, rng: np.random.Generator,
                coverage: float = 6.0) -> np.ndarray:
    """(H, W) uint8 dead-leaves texture: discs of uniform random grey in 20..235 with radii ~ r^-3 on
    [r_min_px, r_max_px], drawn in random order (each on top of the last) until their total area is `coverage`
    times the image's; the background starts at mid grey."""
    a, b = float(r_min_px), float(max(r_max_px, r_min_px * 1.01))
    mean_area = math.pi * 2 * a * a * b * b / (b * b - a * a) * math.log(b / a)  # E[pi r^2] for p(r) ~ r^-3
    n = int(coverage * height * width / mean_area) + 1
    u = rng.random(n)
    r = 1.0 / np.sqrt(1 / a ** 2 - u * (1 / a ** 2 - 1 / b ** 2))  # inverse CDF of p(r) ~ r^-3
    cx = rng.uniform(-b, width + b, n)
    cy = rng.uniform(-b, height + b, n)
    grey = rng.integers(20, 236, n)
    img = np.full((height, width), 128, np.uint8)
    shift = 4  # sub-pixel centres and radii (cv2 fixed point)
    s = 1 << shift
    for i in range(n):  # random order: what stays visible is the scale-invariant dead-leaves image
        cv2.circle(img, (int(cx[i] * s), int(cy[i] * s)), max(int(r[i] * s), s // 2), int(grey[i]), -1,
                   cv2.LINE_AA, shift)
    return img


def texture_sigma_for(frame_width_mm: float, frame_px: int, sensor_px: float = SOFT_SENSOR_PX) -> float:
    """The texture's softening (mm of chart) that is `sensor_px` pixels of an image frame_px pixels wide whose
    width spans frame_width_mm of the chart (a chart filling the frame: its width)."""
    if not (frame_px > 0 and frame_width_mm > 0):
        raise ValueError(f"frame of {frame_px} px over {frame_width_mm} mm: give positive numbers")
    return float(sensor_px) * float(frame_width_mm) / float(frame_px)


def chart_px(spec: ChartSpec) -> tuple[int, int]:
    """(W, H) pixels of the chart image."""
    px = spec.px_per_mm
    return int(round(spec.size_mm[0] * px)), int(round(spec.size_mm[1] * px))


def make_chart(spec: ChartSpec = ChartSpec(), texture: np.ndarray | None = None,
               texture_name: str | None = None) -> tuple[np.ndarray, ChartLayout]:
    """The chart image (H, W) uint8 (print it at spec.dpi) and its layout. texture: another (H, W) uint8
    sRGB-encoded texture than the dead leaves, the markers drawn on it as on them (`chart_px` gives its size;
    texture_name goes into the layout's spec); a probe's, e.g. a mosaic of photographs
    (benchmarks/probes/chart_texture.py)."""
    px = spec.px_per_mm
    w_mm, h_mm = spec.size_mm
    wp, hp = chart_px(spec)
    rng = np.random.default_rng(spec.seed)
    leaf_min = spec.leaf_min_mm if spec.leaf_min_mm is not None else 1.5 / px
    leaf_max = spec.leaf_max_mm if spec.leaf_max_mm is not None else 0.1 * min(w_mm, h_mm)
    if texture is None:
        img = dead_leaves(hp, wp, leaf_min * px, leaf_max * px, rng)
    else:
        if texture.shape != (hp, wp) or texture.dtype != np.uint8:
            raise ValueError(f"chart texture {texture.shape} {texture.dtype}: ({hp}, {wp}) uint8 expected")
        img = texture.copy()
    if spec.texture_sigma_mm > 0:
        img = cv2.GaussianBlur(img, (0, 0), spec.texture_sigma_mm * px)
    dictionary = aruco_dictionary(DICTIONARY)
    nx, ny = spec.markers
    side = spec.marker_side_mm
    module = side / (MARKER_BITS + 2)
    pitch_x, pitch_y = spec.pitch_mm
    ids, corners = [], []
    for j in range(ny):
        for i in range(nx):
            k = j * nx + i
            cx, cy = (i + 0.5) * pitch_x - w_mm / 2, (j + 0.5) * pitch_y - h_mm / 2  # marker centre, chart mm
            x0, y0 = cx - side / 2, cy - side / 2
            q = QUIET_MODULES * module
            # quiet zone, then the marker drawn at its exact pixel size
            qa = (int(round((x0 - q + w_mm / 2) * px)), int(round((y0 - q + h_mm / 2) * px)))
            qb = (int(round((x0 + side + q + w_mm / 2) * px)), int(round((y0 + side + q + h_mm / 2) * px)))
            img[qa[1]:qb[1], qa[0]:qb[0]] = 255
            m0 = (int(round((x0 + w_mm / 2) * px)), int(round((y0 + h_mm / 2) * px)))
            n_px = int(round(side * px))
            marker = cv2.aruco.generateImageMarker(dictionary, k, n_px, borderBits=1)
            img[m0[1]:m0[1] + n_px, m0[0]:m0[0] + n_px] = marker
            # corners of the drawn marker in chart mm (pixel edges, not centres)
            xa, ya = m0[0] / px - w_mm / 2, m0[1] / px - h_mm / 2
            xb, yb = (m0[0] + n_px) / px - w_mm / 2, (m0[1] + n_px) / px - h_mm / 2
            ids.append(k)
            corners.append([[xa, ya], [xb, ya], [xb, yb], [xa, yb]])
    s = {"size_mm": list(spec.size_mm), "markers": list(spec.markers), "marker_mm": side, "dpi": spec.dpi,
         "leaf_min_mm": leaf_min, "leaf_max_mm": leaf_max, "seed": spec.seed,
         "texture": "dead leaves, r^-3" if texture is None else (texture_name or "given"),
         "texture_sigma_mm": float(spec.texture_sigma_mm)}
    return img, ChartLayout((w_mm, h_mm), np.array(ids), np.array(corners, np.float64), DICTIONARY, (wp, hp), px, s)


def write_chart(out_png: str | Path, spec: ChartSpec = ChartSpec(), force: bool = False) -> tuple[Path, Path]:
    """Write the chart image (PNG with its dpi) and chart.json beside it (`<stem>.json`), atomically; existing
    files are replaced only with force."""
    from ..io.atomic import atomic_files

    out_png = Path(out_png)
    out_json = out_png.with_suffix(".json")
    for p in (out_png, out_json):
        if p.exists() and not force:
            raise ChartError(f"{p}: exists (use --force to overwrite)")
    img, layout = make_chart(spec)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ChartError(f"{out_png}: OpenCV could not encode the chart")
    data = _with_dpi(buf.tobytes(), spec.dpi)
    with atomic_files(out_png, out_json) as (tp, tj):
        tp.write_bytes(data)
        tj.write_text(json.dumps(layout.to_dict(), indent=1) + "\n")
    return out_png, out_json


def _with_dpi(png: bytes, dpi: float) -> bytes:
    """A PNG with a pHYs chunk (pixels per metre), so printing at 100 % gives the chart's size."""
    import struct
    import zlib

    ppm = int(round(dpi / 0.0254))
    body = b"pHYs" + struct.pack(">IIB", ppm, ppm, 1)
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    i = 8 + 25  # after the signature and the IHDR chunk (13 bytes of data + 12)
    return png[:i] + chunk + png[i:]
