"""focus_metadata: the focus distance the camera writes to its metadata is not the one it focused at.

The errors, all in the reported value, applied from the true focus in this order:
- a monotone curve (`map_d`: knots [reported_d0, true_d0, reported_d1, true_d1, ...] in diopters, linear between
  them and parallel to reported = true beyond them): any calibration error of the focus encoder, and the form
  the diagnosis reports per-frame fits in;
- a scale of the distance (`scale`: reported distance = scale x true distance; a distance-encoder scale error);
- a bias (`bias_d`: reported minus true, diopters; a mis-calibrated focus encoder);
- quantisation (cameras store focus distance coarsely: Nikon's LensData in steps of 10^(1/40), about 6 % of the
  distance; others in fixed diopter steps)."""

from __future__ import annotations

import numpy as np

from aat_deploy.render.effects import Effect, SimContext, register

QUANTISERS = ("none", "nikon", "diopter")
# Reports and twin foci stop at 100 m (the far end of focus tables): a bias can push a far focus past infinity,
# where a camera reports its largest distance, not a negative or infinite one.
FAR_D = 1e-2


def _check(params: dict) -> None:
    if params["quantise"] not in QUANTISERS:
        raise ValueError(f"effect 'focus_metadata': quantise must be one of {QUANTISERS}, got {params['quantise']!r}")


def quantise_focus_m(focus_m: np.ndarray, mode: str, step_d: float) -> np.ndarray:
    """Focus distances (m) as a camera would store them: 'nikon' = 0.01 * 10^(round(40 log10(100 d)) / 40) m,
    'diopter' = 1/d rounded to multiples of step_d, 'none' = unchanged."""
    f = np.asarray(focus_m, np.float64)
    if mode == "nikon":
        return 0.01 * 10.0 ** (np.round(40 * np.log10(100 * f)) / 40)
    if mode == "diopter":
        return 1.0 / np.maximum(np.round(1.0 / f / step_d), 1) / step_d
    return f


def quantisation_bin_d(focus_m: np.ndarray, mode: str, step_d: float) -> np.ndarray:
    """Width (diopters) of the quantisation bin around each reported value."""
    f = np.asarray(focus_m, np.float64)
    if mode == "nikon":
        return (1 / f) * (10 ** (1 / 80) - 10 ** (-1 / 80))
    if mode == "diopter":
        return np.full_like(f, step_d)
    return np.zeros_like(f)


@register
class FocusMetadata(Effect):
    name = "focus_metadata"
    description = ("reported focus distance differs from the true one: bias_d (diopters, reported minus true), "
                   "scale (reported distance / true distance), map_d (a monotone curve: knots reported_d/true_d/...) "
                   "and quantisation ('none' | 'nikon' | 'diopter' with step_d)")
    order = 95
    defaults = {"bias_d": 0.05, "quantise": "none", "step_d": 0.05, "scale": 1.0, "map_d": []}
    candidates = [{"bias_d": b} for b in (-0.2, -0.1, -0.05, 0.05, 0.1, 0.2)] + [{"bias_d": 0.0, "quantise": "nikon"}]

    def __init__(self, **params):
        super().__init__(**params)
        _check(self.params)
        knots = self.params["map_d"]
        if isinstance(knots, (int, float)) or len(knots) % 2:
            raise ValueError(f"effect 'focus_metadata': map_d needs pairs reported_d/true_d, got {knots!r}")
        k = np.asarray(knots, np.float64).reshape(-1, 2)
        if len(k) and (np.any(np.diff(k[:, 0]) <= 0) or np.any(np.diff(k[:, 1]) < 0)):
            raise ValueError("effect 'focus_metadata': map_d must rise in reported diopters and not fall in true ones")
        if not float(self.params["scale"]) > 0:
            raise ValueError(f"effect 'focus_metadata': scale must be > 0, got {self.params['scale']!r}")
        self.knots = k

    def report_focus(self, focus_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        p = self.params
        d = 1.0 / np.asarray(focus_m, np.float64)
        if len(self.knots):
            d = curve_d(d, self.knots[:, 1], self.knots[:, 0])  # true -> reported
        d = d / float(p["scale"])
        biased = 1.0 / np.maximum(d + p["bias_d"], FAR_D)
        return quantise_focus_m(biased, p["quantise"], p["step_d"])

    def twin_focus(self, focus_reported_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        """A true focus consistent with the report: the bias, scale and curve undone, and a uniform draw (in
        diopters) inside the quantisation bin, since the twin cannot know where in the bin the camera really was."""
        p = self.params
        d = 1.0 / np.asarray(focus_reported_m, np.float64)
        w = quantisation_bin_d(focus_reported_m, p["quantise"], p["step_d"])
        d = d + rng.uniform(-0.5, 0.5, size=d.shape) * w  # drawn even for w = 0: later effects' draws stay put
        d = (d - p["bias_d"]) * float(p["scale"])
        if len(self.knots):
            d = curve_d(d, self.knots[:, 0], self.knots[:, 1])
        return 1.0 / np.maximum(d, FAR_D)


def curve_d(d: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """A monotone curve through the knots (xs ascending -> ys), linear between them and with slope 1 beyond the
    first and the last (an error that stays constant past the measured range)."""
    d = np.asarray(d, np.float64)
    out = np.interp(d, xs, ys)
    out = np.where(d < xs[0], ys[0] + (d - xs[0]), out)
    return np.where(d > xs[-1], ys[-1] + (d - xs[-1]), out)
