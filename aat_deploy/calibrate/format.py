"""The camera calibration file, `aat-camera-calibration-v1`: what one camera (body + lens + aperture + zoom) has
in focus at each sensor position for each reported focus distance, and how fast blur grows with defocus there.

Made by `aat-calibrate fit` from focus sweeps of a flat chart (or blind, from scenes); read by `aat-infer --method
focus --calibration`, the any-camera net and the Python API. Torch-free; format in docs/contracts.md
("Camera calibration").

The model, in diopters (1/m of distances from the sensor plane):

- the **reported-focus error** (`FocusError`, the families of the diagnosis and of the `focus_metadata` effect:
  none, offset, scale, monotone): the on-axis in-focus diopters t of a frame whose metadata says F metres,
  t = curve((1/F - bias_d) * scale) with `curve` the monotone knots `map_d` (identity when empty);
- the **field term** (`FieldPoly`): at normalised field (x right, y up, -1..1 from edge to edge of the frames) the
  in-focus diopters are t + sum_k sum_j c[k, j] x^a_k y^b_k P_j(tau), P_j the Legendre polynomials and tau the
  on-axis focus t mapped linearly from the calibrated range [lo, hi] to [-1, 1] (held beyond it). The terms have
  no constant: the centre of the frame is where t is defined. Any smooth non-radial surface: sensor tilt (x, y),
  field curvature (x^2 + y^2 ...), a decentred element's asymmetry;
- the **blur growth** (`FieldPoly` with a constant term): the defocus blur's diameter in pixels of the calibrated
  frames per diopter of defocus (a thin-lens disk's diameter; a measured Gaussian-like blur is converted with
  diameter = 4 sigma, the disk's second moment), at each field position, a function of the on-axis focus.

The API for consumers:

    cal = load_calibration("mycam.json")
    d = in_focus_diopters(cal, reported_focus_m, height, width)   # (S, H, W) float32 diopters
    k = defocus_scale_px_per_d(cal, height, width)               # (H, W) float32 px per diopter at that size

Frames are assumed to span the calibrated frames' field of view (same framing; any resolution of the same aspect,
`aspect_warning` says when not).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import CaptureError
from ..io.atomic import write_text_atomic
from ..io.files import file_kind
from ..optics.thin_lens import blur_diameter_px
from ..render.effects.focus_metadata import curve_d

FORMAT = "aat-camera-calibration-v1"
FAMILIES = ("none", "offset", "scale", "monotone")  # the diagnosis's vocabulary (aat_deploy.diagnose.focusfit)
MAX_TERMS = 64
MAX_DEGREE = 12
MAX_VALUE = 1e4  # no diopter, px/D or coefficient of a camera is this large: a bound keeps every map finite
# FieldPoly beyond the tiles: held along the radius beyond radius_max, continued from there to first order, or held
# at the nearest point of the rectangle of the tile centres (`FieldPoly.rectangle`)
BEYOND = ("held", "linear", "rectangle")
MIN_DIOPTERS = 1e-3  # reported focus beyond 1 km is treated as 1 km (the focus method's clamp)
UNITS = ("diopters: 1/m of distances from the sensor plane along the optical axis; field: x right, y up, -1..1 "
         "from edge to edge of the calibrated frames; blur: diameter in px of the calibrated frames per diopter")


class CalibrationError(CaptureError):
    """A calibration file is missing or malformed, or does not fit the frames (one line naming the file)."""


# -- the pieces --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraIdentity:
    """What the calibration was made for; captures from another camera are warned about (`mismatch`).
    Strings as the frames' EXIF says ("" = unknown); focal length in mm and f-number (None = unknown)."""

    make: str = ""
    model: str = ""
    lens: str = ""
    focal_length_mm: float | None = None
    f_number: float | None = None

    def mismatch(self, make=None, model=None, lens=None, focal_length_mm=None, f_number=None) -> list[str]:
        """What differs between this camera and another's metadata (values None/"" on either side are not
        compared): one short phrase each. Focal length within 2 %, f-number within 5 %."""
        out = []
        for name, mine, theirs in (("make", self.make, make), ("model", self.model, model), ("lens", self.lens, lens)):
            if mine and theirs and mine.strip().lower() != str(theirs).strip().lower():
                out.append(f"{name} {theirs!r} (calibrated: {mine!r})")
        for name, mine, theirs, tol, unit in (("focal length", self.focal_length_mm, focal_length_mm, 0.02, " mm"),
                                              ("f-number", self.f_number, f_number, 0.05, "")):
            if mine and theirs and abs(float(theirs) / float(mine) - 1) > tol:
                out.append(f"{name} {float(theirs):g}{unit} (calibrated: {float(mine):g}{unit})")
        return out


@dataclass(frozen=True)
class FocusError:
    """Reported focus -> on-axis in-focus diopters: t = curve((reported_d - bias_d) * scale, map_d). `family` names
    the model chosen (FAMILIES); bias_d (diopters, reported minus true), scale (reported distance / true
    distance), map_d knots [reported_d0, true_d0, reported_d1, ...] ascending (empty = identity) as the
    `focus_metadata` effect and the diagnosis write them. intervals: {"bias_d" | "scale": [lo, hi]} 95 %;
    support: {family: share of bootstrap replicates choosing it}; quantisation: the reported values' step
    (e.g. {"mode": "diopter", "step_d": 0.05}) or None."""

    family: str = "none"
    bias_d: float = 0.0
    scale: float = 1.0
    map_d: tuple[float, ...] = ()
    intervals: dict = field(default_factory=dict)
    support: dict = field(default_factory=dict)
    quantisation: dict | None = None

    def __post_init__(self):
        if self.family not in FAMILIES:
            raise ValueError(f"focus error family {self.family!r} (one of {', '.join(FAMILIES)})")
        if not (abs(self.bias_d) <= MAX_VALUE and 1 / MAX_VALUE <= self.scale <= MAX_VALUE):
            raise ValueError(f"focus error: bias_d {self.bias_d!r} must be finite and scale {self.scale!r} > 0")
        k = np.asarray(self.map_d, np.float64)
        if k.size % 2 or (k.size and k.size < 4) or not np.all(np.abs(k) <= MAX_VALUE):
            raise ValueError("focus error: map_d needs at least 2 pairs reported_d, true_d of finite numbers")
        if k.size and (np.any(np.diff(k[0::2]) <= 0) or np.any(np.diff(k[1::2]) < 0)):
            raise ValueError("focus error: map_d must rise in reported diopters and not fall in true ones")
        object.__setattr__(self, "map_d", tuple(float(v) for v in k))

    def true_diopters(self, reported_d) -> np.ndarray:
        """On-axis in-focus diopters (float64, shape of reported_d) for reported focus diopters."""
        d = (np.asarray(reported_d, np.float64) - self.bias_d) * self.scale
        if self.map_d:
            k = np.asarray(self.map_d).reshape(-1, 2)
            d = curve_d(d, k[:, 0], k[:, 1])
        return d


@dataclass(frozen=True)
class FieldPoly:
    """sum_k sum_j coefficients[k, j] x^terms[k][0] y^terms[k][1] P_j(tau): terms (K, 2) non-negative exponents,
    coefficients (K, J) with J - 1 the degree in the on-axis focus (Legendre P_j), focus_range_d [lo, hi] the
    calibrated on-axis focus (tau = -1..1 over it, held beyond). radius_max: None, or the field radius
    (`field_radius_of` with `aspect`, the frames' width / height: 1 at the corners) beyond which the terms are
    not extrapolated as polynomials (the farthest the calibration measured; a high-order polynomial extrapolated
    into corners no tile saw is not a measurement). beyond: how a point p farther out is evaluated, from q, the
    point of radius_max on p's ray from the centre: "held" at q; "linear" continued from q along the ray to first
    order, F(q) + (|p| / |q| - 1) (q . grad F(q)), which for a monomial of total degree n is its value at q times
    1 + n (|p| / |q| - 1) (between the hold, 1, and the polynomial itself, (|p| / |q|)^n); "rectangle": the terms
    are evaluated inside `rectangle` (x_lo, x_hi, y_lo, y_hi, normalised field: the tile centres' bounding box) and,
    outside it, at its nearest point (x and y clipped to it; the nearest in pixels too), whatever radius_max says."""

    terms: np.ndarray
    coefficients: np.ndarray
    focus_range_d: tuple[float, float]
    radius_max: float | None = None
    aspect: float = 1.0
    beyond: str = "held"
    rectangle: tuple[float, float, float, float] | None = None

    def __post_init__(self):
        t = np.asarray(self.terms)
        c = np.asarray(self.coefficients, np.float64)
        if c.ndim == 1:
            c = c[:, None]
        if t.ndim != 2 or t.shape[1:] != (2,) or not 1 <= len(t) <= MAX_TERMS:
            raise ValueError(f"terms must be a list of 1..{MAX_TERMS} [x_exponent, y_exponent] pairs")
        if not np.all(np.equal(np.mod(t, 1), 0)) or t.min() < 0 or t.sum(1).max() > MAX_DEGREE:
            raise ValueError(f"term exponents must be integers >= 0 of total degree <= {MAX_DEGREE}")
        if c.ndim != 2 or c.shape[0] != len(t) or not 1 <= c.shape[1] <= MAX_DEGREE + 1 or \
                not np.all(np.abs(c) <= MAX_VALUE):
            raise ValueError(f"coefficients {c.shape} do not fit {len(t)} terms (finite, (K, J) with J <= "
                             f"{MAX_DEGREE + 1}, |c| <= {MAX_VALUE:g})")
        lo, hi = (float(v) for v in self.focus_range_d)
        if not (abs(lo) <= MAX_VALUE and abs(hi) <= MAX_VALUE and hi >= lo):
            raise ValueError(f"focus_range_d {self.focus_range_d!r} must be [lo, hi] with lo <= hi")
        object.__setattr__(self, "terms", t.astype(np.int64))
        object.__setattr__(self, "coefficients", c)
        object.__setattr__(self, "focus_range_d", (lo, hi))
        a = float(self.aspect)
        if not (math.isfinite(a) and 1e-3 <= a <= 1e3):
            raise ValueError(f"aspect {self.aspect!r} must be a frame's width / height (0.001..1000)")
        object.__setattr__(self, "aspect", a)
        if self.radius_max is not None:
            r = float(self.radius_max)
            if not (math.isfinite(r) and 0 < r <= 2):
                raise ValueError(f"radius_max {self.radius_max!r} must be a field radius in (0, 2]")
            object.__setattr__(self, "radius_max", r)
        if self.beyond not in BEYOND:
            raise ValueError(f"beyond {self.beyond!r} must be one of {', '.join(BEYOND)}")
        if self.beyond == "linear" and self.radius_max is None:  # else it would be the polynomial, silently
            raise ValueError("beyond 'linear' continues from radius_max, which is missing")
        if (self.rectangle is not None) != (self.beyond == "rectangle"):
            raise ValueError(f"rectangle [x_lo, x_hi, y_lo, y_hi] goes with beyond 'rectangle' (and only with it), "
                             f"got beyond {self.beyond!r}, rectangle {self.rectangle!r}"[:200])
        if self.rectangle is not None:
            v = np.asarray(self.rectangle, np.float64).ravel()
            if v.shape != (4,) or not np.all(np.abs(v) <= 1) or v[0] > v[1] or v[2] > v[3]:
                raise ValueError(f"rectangle {self.rectangle!r} must be [x_lo, x_hi, y_lo, y_hi] within -1..1, "
                                 f"lo <= hi"[:200])
            object.__setattr__(self, "rectangle", tuple(float(c) for c in v))

    def tau(self, t_d) -> np.ndarray:
        lo, hi = self.focus_range_d
        if hi - lo < 1e-12:
            return np.zeros_like(np.asarray(t_d, np.float64))
        return np.clip(2 * (np.asarray(t_d, np.float64) - lo) / (hi - lo) - 1, -1, 1)

    def focus_weights(self, t_d) -> np.ndarray:
        """(S, K) coefficients summed over the focus polynomials at on-axis focus t_d (S,)."""
        j = self.coefficients.shape[1]
        leg = np.polynomial.legendre.legvander(self.tau(np.ravel(t_d)), j - 1)  # (S, J)
        return leg @ self.coefficients.T

    def basis(self, x, y) -> np.ndarray:
        """(K, ...) the terms at field points x, y (broadcast), held or continued beyond radius_max (`beyond`)."""
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        if self.rectangle is not None:  # the nearest point of the tile centres' rectangle, where the fit has data
            x0, x1, y0, y1 = self.rectangle
            x, y = np.clip(x, x0, x1), np.clip(y, y0, y1)
            return np.stack([x ** a * y ** b for a, b in self.terms])
        if self.radius_max is None:
            return np.stack([x ** a * y ** b for a, b in self.terms])
        r = field_radius_of(x, y, self.aspect)
        s = np.where(r > self.radius_max, self.radius_max / np.maximum(r, 1e-300), 1.0)
        b = np.stack([(x * s) ** a * (y * s) ** c for a, c in self.terms])
        if self.beyond == "linear":  # x d/dx + y d/dy of a monomial is its degree times itself (Euler)
            n = self.terms.sum(1).astype(np.float64).reshape((-1,) + (1,) * x.ndim)
            b = b * (1.0 + n * (1.0 / s - 1.0))
        return b

    def __call__(self, x, y, t_d) -> np.ndarray:
        """(S, *x.shape) float64 at field (x, y) for on-axis focus t_d (S,)."""
        w = self.focus_weights(t_d)  # (S, K)
        b = self.basis(x, y)
        return np.tensordot(w, b, 1)

    def to_dict(self) -> dict:
        d = {"terms": self.terms.tolist(), "coefficients": np.round(self.coefficients, 9).tolist(),
             "focus_range_d": [float(v) for v in self.focus_range_d]}
        if self.radius_max is not None:  # absent: never held (files made before 2026-11-26, evening)
            d["radius_max"] = round(self.radius_max, 6)
            d["aspect"] = round(self.aspect, 9)
        if self.beyond != "held":  # absent: held
            d["beyond"] = self.beyond
        if self.rectangle is not None:
            d["rectangle"] = [round(v, 9) for v in self.rectangle]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> FieldPoly:
        r = d.get("radius_max")
        if r is not None and (isinstance(r, bool) or not isinstance(r, (int, float))):
            raise ValueError(f"radius_max must be a number, got {r!r}"[:200])
        a = d.get("aspect", 1.0)
        if isinstance(a, bool) or not isinstance(a, (int, float)):
            raise ValueError(f"aspect must be a number, got {a!r}"[:200])
        beyond = d.get("beyond", "held")
        if not isinstance(beyond, str):
            raise ValueError(f"beyond must be one of {', '.join(BEYOND)}, got {beyond!r}"[:200])
        rect = d.get("rectangle")
        if rect is not None and (not isinstance(rect, list) or len(rect) != 4 or
                                 any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in rect)):
            raise ValueError(f"rectangle must be 4 numbers [x_lo, x_hi, y_lo, y_hi], got {rect!r}"[:200])
        return cls(np.array(d["terms"]), np.array(d["coefficients"], np.float64),
                   tuple(float(v) for v in d["focus_range_d"]), None if r is None else float(r), float(a), beyond,
                   None if rect is None else tuple(float(v) for v in rect))


def field_grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) normalised field x (right), y (up) of the pixel centres of frames spanning the calibrated field."""
    x = (2 * (np.arange(width) + 0.5) / width - 1)[None, :]
    y = (1 - 2 * (np.arange(height) + 0.5) / height)[:, None]
    return np.broadcast_to(x, (height, width)), np.broadcast_to(y, (height, width))


def field_radius_of(x, y, aspect: float) -> np.ndarray:
    """Field radius (0 centre, 1 corner) at normalised field x, y of frames of width / height aspect (square
    pixels): sqrt((aspect^2 x^2 + y^2) / (aspect^2 + 1)), the best-focus maps' radius (`model.FieldBasis`'s rho)."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    return np.sqrt((aspect ** 2 * x ** 2 + y ** 2) / (aspect ** 2 + 1.0))


def poly_terms(degree: int, constant: bool) -> np.ndarray:
    """(K, 2) all exponent pairs of total degree 1..degree (0..degree with the constant), by degree."""
    return np.array([(a, n - a) for n in range(0 if constant else 1, degree + 1) for a in range(n, -1, -1)],
                    np.int64).reshape(-1, 2)


# -- the calibration ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraCalibration:
    """camera: identity; size_px (W, H) of the calibrated frames; sensor_mm (W, H) or None; focus_error;
    best_focus: the field term (diopters); blur: the blur growth (px of the calibrated frames per diopter) or None;
    residuals: fit quality ({"rms_d", "p95_d", "tiles", ...}); uncertainty: bootstrap spread of the map
    ({"x": (nx,), "y": (ny,), "sd_d": (ny, nx)} at the middle of the focus range) or {}; fit: how it was made."""

    camera: CameraIdentity
    size_px: tuple[int, int]
    focus_error: FocusError
    best_focus: FieldPoly
    blur: FieldPoly | None = None
    sensor_mm: tuple[float, float] | None = None
    residuals: dict = field(default_factory=dict)
    uncertainty: dict = field(default_factory=dict)
    fit: dict = field(default_factory=dict)

    def __post_init__(self):
        w, h = (int(v) for v in self.size_px)
        if w < 1 or h < 1:
            raise ValueError(f"size_px {self.size_px!r} must be positive")
        object.__setattr__(self, "size_px", (w, h))
        if self.sensor_mm is not None:
            sw, sh = (float(v) for v in self.sensor_mm)
            if not (sw > 0 and sh > 0 and math.isfinite(sw) and math.isfinite(sh)):
                raise ValueError(f"sensor_mm {self.sensor_mm!r} must be positive")
            object.__setattr__(self, "sensor_mm", (sw, sh))
        if np.any(self.best_focus.terms.sum(1) == 0):
            raise ValueError("best_focus terms must not include the constant: the frame centre is the reported "
                             "focus's own (focus_error)")

    @property
    def focus_range_m(self) -> tuple[float, float]:
        """(near, far) on-axis focus distances (m) the calibration measured."""
        lo, hi = self.best_focus.focus_range_d
        return 1.0 / hi if hi > 0 else math.inf, 1.0 / lo if lo > 0 else math.inf

    def aspect_warning(self, height: int, width: int, where: str = "frames") -> str:
        """A one-line warning when frames of height x width px do not have the calibrated frames' aspect ("")."""
        cw, ch = self.size_px
        if abs((width / height) / (cw / ch) - 1) > 0.01:
            return (f"{where} are {width}x{height} px, the calibration's frames {cw}x{ch} px: its field positions "
                    "assume the same framing")
        return ""

    def to_dict(self) -> dict:
        c, fe = self.camera, self.focus_error
        return {
            "format": FORMAT,
            "units": UNITS,
            "camera": {"make": c.make, "model": c.model, "lens": c.lens, "focal_length_mm": c.focal_length_mm,
                       "f_number": c.f_number},
            "sensor": {"width_px": self.size_px[0], "height_px": self.size_px[1],
                       "width_mm": None if self.sensor_mm is None else self.sensor_mm[0],
                       "height_mm": None if self.sensor_mm is None else self.sensor_mm[1]},
            "focus_error": {"family": fe.family, "bias_d": fe.bias_d, "scale": fe.scale, "map_d": list(fe.map_d),
                            "intervals": fe.intervals, "support": fe.support, "quantisation": fe.quantisation},
            "best_focus": self.best_focus.to_dict(),
            "blur": None if self.blur is None else self.blur.to_dict(),
            "residuals": self.residuals,
            "uncertainty": self.uncertainty,
            "fit": self.fit,
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "calibration") -> CameraCalibration:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            got = d.get("format") if isinstance(d, dict) else type(d).__name__
            raise CalibrationError(f"{source}: not a camera calibration (format {FORMAT!r} expected, got {got!r})")
        try:
            cam, sen, fe = _obj(d, "camera"), _obj(d, "sensor"), _obj(d, "focus_error")
            identity = CameraIdentity(_str(cam, "make"), _str(cam, "model"), _str(cam, "lens"),
                                      _num(cam, "focal_length_mm"), _num(cam, "f_number"))
            sensor_mm = None
            if sen.get("width_mm") is not None or sen.get("height_mm") is not None:
                sensor_mm = (_num(sen, "width_mm", True), _num(sen, "height_mm", True))
            size = (_int(sen, "width_px"), _int(sen, "height_px"))
            focus = FocusError(str(fe.get("family", "none")), _num(fe, "bias_d") or 0.0,
                               1.0 if fe.get("scale") is None else _num(fe, "scale", True),
                               tuple(_numbers(fe.get("map_d") or [], "focus_error.map_d")),
                               _dict(fe, "intervals"), _dict(fe, "support"), _dict(fe, "quantisation") or None)
            best = FieldPoly.from_dict(_obj(d, "best_focus"))
            blur = None if d.get("blur") is None else FieldPoly.from_dict(_obj(d, "blur"))
            return cls(identity, size, focus, best, blur, sensor_mm, _dict(d, "residuals"),
                       _dict(d, "uncertainty"), _dict(d, "fit"))
        except CalibrationError as e:
            raise CalibrationError(f"{source}: {e}") from None
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            what = f"missing key {e}" if isinstance(e, KeyError) else str(e).splitlines()[0][:200]
            raise CalibrationError(f"{source}: malformed camera calibration ({what})") from None


def _obj(d: dict, key: str) -> dict:
    """A required object (KeyError when missing)."""
    return _dict(d, key) if key in d else d[key]


def _dict(d: dict, key: str) -> dict:
    """An optional object ({} when missing or null)."""
    v = d.get(key)
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise CalibrationError(f"{key} must be an object, got {type(v).__name__}")
    return v


def _str(d: dict, key: str) -> str:
    v = d.get(key)
    if v is None:
        return ""
    if not isinstance(v, str):
        raise CalibrationError(f"{key} must be text, got {type(v).__name__}")
    return v


def _num(d: dict, key: str, required: bool = False) -> float | None:
    v = d.get(key)
    if v is None:
        if required:
            raise CalibrationError(f"{key} is missing")
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise CalibrationError(f"{key} must be a finite number, got {v!r}"[:200])
    return float(v)


def _int(d: dict, key: str) -> int:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 1_000_000:
        raise CalibrationError(f"{key} must be a whole number of pixels in 1..1000000, got {v!r}"[:200])
    return v


def _numbers(v, what: str) -> list[float]:
    if not isinstance(v, list) or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v):
        raise CalibrationError(f"{what} must be a list of numbers")
    return [float(x) for x in v]


# -- storage -----------------------------------------------------------------------------------------------------
def load_calibration(path: str | Path) -> CameraCalibration:
    """A calibration file; CalibrationError (one line naming the file) for anything unreadable or malformed."""
    path = Path(path)
    kind = file_kind(path)
    if kind is not None:
        raise CalibrationError(f"{path}: {kind}, not a camera calibration file")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise CalibrationError(f"{path}: cannot read ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise CalibrationError(f"{path}: not UTF-8 text, not a camera calibration") from None
    try:
        d = json.loads(text)
    except RecursionError:
        raise CalibrationError(f"{path}: not valid JSON (nested too deeply)") from None
    except ValueError as e:
        raise CalibrationError(f"{path}: not valid JSON ({str(e).splitlines()[0][:120]})") from None
    return CameraCalibration.from_dict(d, str(path))


def save_calibration(cal: CameraCalibration, path: str | Path, force: bool = False) -> Path:
    """Write atomically; an existing file is replaced only with force (CalibrationError otherwise)."""
    path = Path(path)
    if path.exists() and not force:
        raise CalibrationError(f"{path}: exists (use --force to overwrite)")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(cal.to_dict(), indent=1, allow_nan=False) + "\n")
    return path


# -- what consumers call -----------------------------------------------------------------------------------------
def on_axis_diopters(cal: CameraCalibration, reported_focus_m) -> np.ndarray:
    """(S,) float64 on-axis in-focus diopters of frames whose metadata reports reported_focus_m (S,) metres."""
    f = np.asarray(reported_focus_m, np.float64).ravel()
    if f.size == 0 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError(f"reported focus distances must be finite and > 0 m, got {f.tolist()}")
    return cal.focus_error.true_diopters(np.maximum(1.0 / f, MIN_DIOPTERS))


def in_focus_diopters(cal: CameraCalibration, reported_focus_m, height: int, width: int) -> np.ndarray:
    """(S, H, W) float32: the object diopters (1/m from the sensor plane) in best focus at each pixel of frames
    whose metadata reports reported_focus_m (S,) metres, for frames of height x width px spanning the calibrated
    field of view. Negative values (best focus beyond infinity) are kept."""
    t = on_axis_diopters(cal, reported_focus_m)
    x, y = field_grid(int(height), int(width))
    return (t[:, None, None] + cal.best_focus(x, y, t)).astype(np.float32)


def measured_mask(cal: CameraCalibration, reported_focus_m, height: int, width: int,
                  in_focus: np.ndarray | None = None) -> np.ndarray:
    """(S, H, W) bool: where the calibration measured what is in focus, for frames reporting reported_focus_m (S,)
    metres: within the farthest counted tile's field radius (`best_focus.radius_max`; beyond it the field term is
    held), the on-axis focus inside the calibrated range (beyond it the field term is held and the focus error
    extrapolated), and the in-focus object inside the range of objects the charts' tiles showed (`fit`'s
    `object_range_d`, chart calibrations since 2026-11-27). False: the map there is extrapolated, not measured (on
    the benchmark's phone 0.47-0.49 D off beyond the farthest tile, against 0.08 D within). in_focus: the
    (S, H, W) `in_focus_diopters` when already made."""
    h, w = int(height), int(width)
    d = in_focus_diopters(cal, reported_focus_m, h, w) if in_focus is None else np.asarray(in_focus)
    lo, hi = cal.best_focus.focus_range_d
    t = on_axis_diopters(cal, reported_focus_m)
    ok = np.broadcast_to(((t >= lo - 1e-9) & (t <= hi + 1e-9))[:, None, None], d.shape).copy()
    if cal.best_focus.radius_max is not None:
        x, y = field_grid(h, w)
        ok &= (field_radius_of(x, y, cal.best_focus.aspect) <= cal.best_focus.radius_max + 1e-9)[None]
    rng = cal.fit.get("object_range_d")
    if rng is not None:
        ok &= (d >= float(rng[0]) - 1e-9) & (d <= float(rng[1]) + 1e-9)
    return ok


def defocus_scale_px_per_d(cal: CameraCalibration, height: int, width: int, focus_m: float | None = None
                           ) -> np.ndarray:
    """(H, W) float32: blur-disk diameter in pixels of a height x width frame per diopter of defocus at each pixel,
    at reported focus focus_m (None: the middle of the calibrated focus range). From the measured blur growth,
    scaled from the calibrated frames' width; without one, the thin-lens value from the camera's focal length,
    f-number and sensor width (CalibrationError when those are unknown)."""
    h, w = int(height), int(width)
    lo, hi = cal.best_focus.focus_range_d
    t = np.array([0.5 * (lo + hi)]) if focus_m is None else on_axis_diopters(cal, [focus_m])
    if cal.blur is not None:
        x, y = field_grid(h, w)
        k = cal.blur(x, y, t)[0] * (w / cal.size_px[0])
        return np.maximum(k, 0).astype(np.float32)
    c = cal.camera
    if not (c.focal_length_mm and c.f_number and cal.sensor_mm):
        raise CalibrationError("the calibration has no measured blur growth, and no focal length, f-number and "
                               "sensor size for the thin-lens one")
    k = thin_lens_defocus_scale_px_per_d(c.focal_length_mm, c.f_number, cal.sensor_mm[0] / w * 1000,
                                         1.0 / max(float(t[0]), MIN_DIOPTERS))
    return np.full((h, w), k, np.float32)


def thin_lens_defocus_scale_px_per_d(focal_length_mm: float, f_number: float, pixel_um: float,
                                     focus_m: float) -> float:
    """Blur-disk diameter (px) per diopter of defocus of a thin lens (`aat_deploy.optics.thin_lens`) focused at
    focus_m (m from the sensor), for objects near focus: the blur of an object 0.02 D nearer, over 0.02 D."""
    step = 0.02
    near_m = 1.0 / (1.0 / focus_m + step)
    b = blur_diameter_px(np.array([near_m]), np.array([focus_m], np.float64), focal_length_mm,
                         focal_length_mm / f_number, pixel_um / 1000.0)[0]
    return float(b / step)
