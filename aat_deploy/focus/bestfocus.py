"""The aberration-aware focus mapping: at each field position, which object distance is in best focus in a frame.

A thin lens focused at F metres has every object at F metres in focus, across the whole field. A real lens does
not: field curvature and astigmatism move best focus with the field radius (on the RF50 the corners focus about
0.08 D farther than the centre). Depth from focus turns "pixel p is sharpest in frame s" into a distance; with
this map it uses the distance that frame s really has in focus at p's field radius instead of its nominal focus.

The map is a table over (normalised image radius r, 0 = centre, 1 = sensor corner; frame focus setting in
diopters) of object diopters (1/m, metres from the sensor), real-ray traced on the training side
(`training.optics.field_focus`): for a frame focused at F (sensor where the on-axis point at F is in best focus,
`training.optics.focus`), the object distance whose image at field r has its smallest RMS spot exactly on that
sensor. Optionally `offset_diopters`, a calibration measured on rendered stacks (`training.render.
focus_calibration`), is added: where the focus measure's peak sits relative to that min-RMS focus (spherical
aberration and astigmatism make them differ). Interpolation is bilinear in (r^2, focus diopters) on the offset
from the nominal focus (object diopters minus frame diopters), held constant beyond the table's focus range.

Stored as JSON (`save_json`, format FORMAT) in `<lens folder>/best_focus/<lens stem>.json` and/or in a PSF
surrogate's ONNX metadata under METADATA_KEY (`aat-lens focus-map LENS --stamp PSF.onnx`). Reading it needs no torch.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import AatError
from ..eval.stats import field_radius
from ..extensions import ExtensionUnavailable
from ..extensions import load as load_extension
from ..io.atomic import write_text_atomic

FORMAT = "aat-best-focus-map-v1"
METADATA_KEY = "aat.best_focus_map"
SUBFOLDER = "best_focus"


class BestFocusError(AatError):
    """A best-focus map is missing or malformed (message: one line naming the file)."""


@dataclass(frozen=True)
class BestFocusMap:
    """radius (R,) ascending in [0, 1]; focus_diopters (F,) ascending; object_diopters (R, F) traced;
    offset_diopters (R, F) or None: calibration added to object_diopters; sensor_mm (W, H) of the lens's sensor
    (the frames are assumed to span it); notes: how it was made."""

    radius: np.ndarray
    focus_diopters: np.ndarray
    object_diopters: np.ndarray
    sensor_mm: tuple[float, float]
    offset_diopters: np.ndarray | None = None
    lens_name: str = ""
    lens_hash: str = ""
    notes: dict = field(default_factory=dict)

    def __post_init__(self):
        r, f, d = (np.asarray(a, np.float64) for a in (self.radius, self.focus_diopters, self.object_diopters))
        if r.ndim != 1 or f.ndim != 1 or d.shape != (r.size, f.size) or r.size < 2 or f.size < 2:
            raise BestFocusError(f"best-focus map: shapes radius {r.shape}, focus {f.shape}, object {d.shape}")
        if np.any(np.diff(r) <= 0) or np.any(np.diff(f) <= 0) or not np.isfinite(d).all():
            raise BestFocusError("best-focus map: radius and focus must ascend and values be finite")
        object.__setattr__(self, "radius", r)
        object.__setattr__(self, "focus_diopters", f)
        object.__setattr__(self, "object_diopters", d)
        if self.offset_diopters is not None:
            o = np.asarray(self.offset_diopters, np.float64)
            if o.shape != d.shape or not np.isfinite(o).all():
                raise BestFocusError(f"best-focus map: offset {o.shape} does not match {d.shape}")
            object.__setattr__(self, "offset_diopters", o)

    # -- queries ---------------------------------------------------------------------------------------------
    @property
    def focus_range_m(self) -> tuple[float, float]:
        """(near, far) focus distances (m) the table covers."""
        f = self.focus_diopters
        return 1.0 / f[-1], (1.0 / f[0] if f[0] > 0 else float("inf"))

    def shift_diopters(self, calibrated: bool = True) -> np.ndarray:
        """(R, F) object diopters minus the frame's nominal diopters."""
        d = self.object_diopters + (self.offset_diopters if calibrated and self.offset_diopters is not None else 0)
        return d - self.focus_diopters[None]

    def frame_diopters(self, focus_m, radius, calibrated: bool = True) -> np.ndarray:
        """Object diopters in best focus for frames focused at focus_m (S,) at radii (N,): (S, N) float64."""
        fd = 1.0 / np.asarray(focus_m, np.float64).ravel()
        r2 = np.clip(np.asarray(radius, np.float64).ravel(), 0.0, self.radius[-1]) ** 2
        shift = self.shift_diopters(calibrated)
        # bilinear: first along focus (per table radius), then along r^2
        per_r = np.stack([np.interp(fd, self.focus_diopters, row) for row in shift], 1)  # (S, R)
        out = np.stack([np.interp(r2, self.radius ** 2, row) for row in per_r])  # (S, N)
        return out + fd[:, None]

    def radial_lut(self, focus_m, n_bins: int = 256, calibrated: bool = True) -> np.ndarray:
        """(S, n_bins) float32 object diopters at the centres of n_bins even radius bins over [0, 1]."""
        centres = (np.arange(n_bins) + 0.5) / n_bins
        return self.frame_diopters(focus_m, centres, calibrated).astype(np.float32)

    def radius_px(self, h: int, w: int) -> np.ndarray:
        """(H, W) float32 field radius of each pixel centre of an H x W frame spanning the sensor, measured on it
        in mm (`aat_deploy.eval.stats.field_radius`)."""
        return field_radius(h, w, self.sensor_mm).astype(np.float32)

    # -- storage ---------------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {"format": FORMAT, "lens_name": self.lens_name, "lens_hash": self.lens_hash,
             "sensor_mm": [float(v) for v in self.sensor_mm],
             "units": "radius: normalised image radius (0 centre, 1 sensor corner); diopters: 1/m, distances "
                      "from the sensor plane",
             "radius": self.radius.tolist(), "focus_diopters": self.focus_diopters.tolist(),
             "object_diopters": np.round(self.object_diopters, 7).tolist(),
             "offset_diopters": None if self.offset_diopters is None else np.round(self.offset_diopters, 7).tolist(),
             "notes": self.notes}
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "best-focus map") -> BestFocusMap:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise BestFocusError(f"{source}: not a best-focus map (format {FORMAT!r} expected)")
        try:
            return cls(np.array(d["radius"], np.float64), np.array(d["focus_diopters"], np.float64),
                       np.array(d["object_diopters"], np.float64), tuple(float(v) for v in d["sensor_mm"]),
                       None if d.get("offset_diopters") is None else np.array(d["offset_diopters"], np.float64),
                       str(d.get("lens_name", "")), str(d.get("lens_hash", "")), dict(d.get("notes") or {}))
        except BestFocusError as e:
            raise BestFocusError(f"{source}: {e}") from None
        except (KeyError, TypeError, ValueError) as e:
            raise BestFocusError(f"{source}: malformed best-focus map ({type(e).__name__}: {e})") from None

    def save_json(self, path: str | Path) -> Path:
        """Write atomically (temporary file renamed into place)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps(self.to_dict(), indent=1))
        return path


def map_path_for_lens(lens_path: str | Path) -> Path:
    """Where a lens file's map lives: `<lens folder>/best_focus/<lens stem>.json`."""
    p = Path(lens_path)
    return p.parent / SUBFOLDER / f"{p.stem}.json"


def load_json(path: str | Path) -> BestFocusMap:
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise BestFocusError(f"{path}: cannot read a best-focus map ({e})") from None
    return BestFocusMap.from_dict(d, str(path))


def from_psf(path: str | Path) -> BestFocusMap:
    """The map stamped into a PSF surrogate's metadata."""
    from aat_deploy.psf.surrogate import PSFSurrogate

    try:
        meta = PSFSurrogate(path, threads=1).meta
    except (FileNotFoundError, ValueError) as e:
        raise BestFocusError(str(e)) from None
    if METADATA_KEY not in meta:
        raise BestFocusError(f"{path}: this PSF surrogate carries no best-focus map; add it with "
                             "`aat-lens focus-map LENS --stamp PSF.onnx` (needs the train extra)")
    try:
        d = json.loads(meta[METADATA_KEY])
    except json.JSONDecodeError as e:
        raise BestFocusError(f"{path}: metadata {METADATA_KEY} is not JSON ({e})") from None
    m = BestFocusMap.from_dict(d, f"{path} ({METADATA_KEY})")
    if meta.get("aat.lens_hash") and m.lens_hash and meta["aat.lens_hash"] != m.lens_hash:
        raise BestFocusError(f"{path}: its best-focus map is of another lens than the surrogate")
    return m


def for_lens(lens_path: str | Path, compute: bool = True, progress: bool = False) -> tuple[BestFocusMap, str]:
    """The map of a lens file: `best_focus/<stem>.json` next to it (checked against the lens's prescription), else
    traced now on a coarse grid when the train extra is installed (the extension `best_focus_tracer`,
    `aat_deploy.extensions`; uncalibrated, about half a minute), else a one-line error saying how to make it.
    Returns the map and where it came from."""
    from aat_deploy.lens.io import load_lens

    lens_path = Path(lens_path)
    try:
        lens = load_lens(lens_path)
    except Exception as e:  # noqa: BLE001 (the lens readers raise several types; report them in one line)
        raise BestFocusError(f"{lens_path}: not a readable lens file ({str(e).splitlines()[0][:200]})") from None
    stored = map_path_for_lens(lens_path)
    if stored.is_file():
        m = load_json(stored)
        if m.lens_hash and m.lens_hash != lens.prescription_hash():
            raise BestFocusError(f"{stored}: made for another prescription than {lens_path} (lens hash differs); "
                                 f"remake it with `aat-lens focus-map {lens_path} --force`")
        return m, str(stored)
    how = (f"make it with `aat-lens focus-map {lens_path}` (writes {stored}; needs the train extra) "
           "or pass --psf with the lens's stamped PSF surrogate")
    if not compute:
        raise BestFocusError(f"{lens_path}: no best-focus map ({stored} missing); {how}")
    try:
        trace = load_extension("best_focus_tracer")
    except ExtensionUnavailable as e:
        raise BestFocusError(f"{lens_path}: no best-focus map ({stored} missing) and torch is not installed to "
                             f"trace it ({e}); {how}") from None
    m = trace(lens, progress=progress)  # 7 radii x 9 focus settings, uncalibrated
    return m, f"traced now (uncalibrated, coarse; for the calibrated map run aat-lens focus-map {lens_path})"
