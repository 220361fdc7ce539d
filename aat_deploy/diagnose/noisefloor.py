"""The sensor noise's focus measure in the binned focus sweep, by its expectation instead of a noise draw
(docs/diagnosis.md, "Focus errors"; issue 32, scene 2038).

The focus measure of a region is the region mean of the squared Laplacian (`compare.focus_curves`); noise adds its
own energy, E[lap(s + n)^2] = lap(s)^2 + E[lap(n)^2] (the cross term has mean 0). For noise independent from pixel
to pixel with variance v(p), E[lap(n)^2](p) = sum_k w_k^2 v(p + k) over the Laplacian's taps w_k (cv2's 3 x 3
aperture: -8 at the centre, 2 at the four diagonal neighbours). So the sweep's twin is rendered without noise and
each channel's curve becomes log(S + N): S its noiseless focus measure, N that expectation (`floor`), both in the
normalised stack's units. A noise draw instead puts its own random floor into every sweep step and into the binning
correction's anchors, which the capture's draw does not share.

A developed RAW's noise is not independent: demosaicking spreads one draw per photosite over its neighbours, so
binning b x b removes less of it than the binned renderer's independent noise (b^2 the full well, b the read noise:
`Noise.binned`). `developed_factor` measures how much more Laplacian energy the binned developed noise keeps, per
channel, by developing a flat field with and without a noise draw through the chain's own `raw_pipeline` (about
2.9 / 1.7 / 2.8 x for R / G / B at b = 4 with LibRaw's development); the floor is scaled by it. At b >= 2 the binned
developed noise is close to white (its Laplacian energy and its variance grow alike), which is what scaling the
independent floor assumes.

Used when the twin's chain has `noise` and, after it, nothing but `raw_pipeline` (whose binned form is left out);
any other effect after the noise (a phone's processing) keeps the noise draw.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from aat_deploy.diagnose.binned import bin_frames
from aat_deploy.diagnose.compare import region_index

# cv2.Laplacian(ksize=3)'s taps squared: the weights of a white noise's variance in E[lap(n)^2]
_LAP2 = np.array([[4.0, 0.0, 4.0], [0.0, 64.0, 0.0], [4.0, 0.0, 4.0]], np.float32)
_FLAT = 0.18  # the flat field the developed factor is measured on (linear, 1 = white)
_FACTOR_HW = (512, 768)


def noise_of(chain: list):
    """The chain's `noise` effect, or None."""
    return next((e for e in chain if e.name == "noise"), None)


def applies(chain: list) -> bool:
    """Whether the sweep can carry the chain's noise by its expectation: the chain has `noise`, and every effect
    after it is `raw_pipeline`."""
    n = noise_of(chain)
    return n is not None and all(e.name == "raw_pipeline" for e in chain if e.order > n.order)


def quiet(chain: list) -> list:
    """The chain without its noise."""
    return [e for e in chain if e.name != "noise"]


def developed_factor(chain: list, b: int) -> np.ndarray:
    """(3,) per channel: the Laplacian energy of the chain's noise after its `raw_pipeline` and b x b binning, over
    that of the same noise independent per pixel and channel binned alike (`Noise.binned`'s model). Ones without
    a `raw_pipeline`."""
    raw = next((e for e in chain if e.name == "raw_pipeline"), None)
    n = noise_of(chain)
    if raw is None or n is None:
        return np.ones(3)
    return np.asarray(_developed_factor(raw.params["demosaic"], int(b), float(n.params["full_well_e"]),
                                        float(n.params["read_noise_e"])))


@functools.lru_cache(maxsize=16)
def _developed_factor(demosaic: str, b: int, full_well_e: float, read_noise_e: float) -> tuple:
    from types import SimpleNamespace

    from aat_deploy.render.effects.noise import poisson_gaussian
    from aat_deploy.render.effects.raw_pipeline import RawPipeline

    raw = RawPipeline(demosaic=demosaic)
    h, w = _FACTOR_HW
    x = np.full((3, h, w), _FLAT, np.float32)
    ctx = SimpleNamespace(origin=(0, 0))  # all `raw_pipeline` reads of its context: the mosaic's phase
    noisy = poisson_gaussian(x, full_well_e, read_noise_e, np.random.default_rng(20261127))
    rng = np.random.default_rng(0)
    dev = raw.sensor(noisy, ctx, rng) - raw.sensor(x, ctx, rng)
    var = (_FLAT / full_well_e + (read_noise_e / full_well_e) ** 2) / b ** 2  # the binned independent pixel's
    out = []
    for c in bin_frames(dev, b):
        lap = cv2.Laplacian(np.ascontiguousarray(c, np.float32), cv2.CV_32F, ksize=3)[4:-4, 4:-4]
        out.append(float(np.mean(lap.astype(np.float64) ** 2) / (float(_LAP2.sum()) * var)))
    return tuple(out)


def floor(linear: np.ndarray, scale: float, noise, factor_c: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """(R, S, C) the noise's expected focus measure per region, frame and channel, in the units of the stack
    normalised by `scale` (`normalise_scale`), for binned frames `linear` (S, C, H, W) without noise (white = 1) and
    the binned sensor's `noise` (`Noise.binned(b)`), each channel's scaled by factor_c (`developed_factor`)."""
    fw, rd = float(noise.params["full_well_e"]), float(noise.params["read_noise_e"])
    s, c, h, w = linear.shape
    reg = region_index(h, w, grid).ravel()
    n_r = grid[0] * grid[1]
    count = np.bincount(reg, minlength=n_r)
    out = np.empty((n_r, s, c))
    for i in range(s):
        for j in range(c):
            v = (np.clip(linear[i, j], 0, None) / fw + (rd / fw) ** 2) * (factor_c[j] / scale ** 2)
            e = cv2.blur(cv2.filter2D(np.ascontiguousarray(v, np.float32), cv2.CV_32F, _LAP2), (9, 9)).ravel()
            out[:, i, j] = np.bincount(reg, weights=e, minlength=n_r) / count
    return out


def read_part(scale: float, noise, factor_c: np.ndarray) -> np.ndarray:
    """(C,) the read noise's part of `floor` (the same in every region and frame): its variance (read / full well)^2
    through the Laplacian's squared taps, scaled like `floor`. The rest of the floor is the shot noise's."""
    fw, rd = float(noise.params["full_well_e"]), float(noise.params["read_noise_e"])
    return float(_LAP2.sum()) * (rd / fw) ** 2 * np.asarray(factor_c, np.float64) / scale ** 2


def compose(signal_log_c: np.ndarray, floor_c: np.ndarray) -> np.ndarray:
    """(..., C) per-channel log noiseless focus measures and (..., C) floors -> (...) the channel mean of
    log(S + N), as `focus_curves(...).mean(-1)` of the noisy stack would be in expectation (per channel)."""
    return np.log(np.exp(signal_log_c) + floor_c).mean(-1)
