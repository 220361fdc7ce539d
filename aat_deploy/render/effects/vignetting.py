"""vignetting: relative illumination, from the lens's PSF energies (mechanical vignetting) and the cos^4 law.

The PSF energies come from the lens source the renderer was given: ray-traced PSFs (torch) or the exported
surrogate, which learns each kernel's energy and so keeps the fall-off (about 0.4 of the axis at 0.9 of the RF50's
field at f/1.8). The torch-free twin renderer uses the surrogate: the same relative illumination as the training
simulator with that surrogate. Without any lens source, only cos^4 remains."""

from __future__ import annotations

import numpy as np

from aat_deploy.optics.field import field_to_tan
from aat_deploy.render.effects import Effect, SimContext, register
from aat_deploy.render.sources import normalise_energy


@register
class Vignetting(Effect):
    name = "vignetting"
    description = ("relative illumination falls towards the corners: the fraction of the pupil's rays that get "
                   "through (traced, relative to the axis) times cos^4 of the field angle")
    order = 20
    uses_lens_psfs = True
    defaults = {"cos4": True}

    def wrap_source(self, source, ctx: SimContext):
        return _Vignetted(source, ctx, bool(self.params["cos4"]))


class _Vignetted:
    """Kernels normalised to unit energy, then scaled by the relative illumination (numpy or torch kernels, as the
    wrapped source returns them)."""

    def __init__(self, source, ctx: SimContext, cos4: bool):
        self.source, self.ctx, self.cos4 = source, ctx, cos4
        self.k, self.scale, self.blur_px = source.k, source.scale, source.blur_px

    def relative_illumination(self, x, y, depth_m, focus_m) -> np.ndarray:
        """E(x, y) / E(axis) of the lens's PSFs (<= 1; 1 without a lens source) times cos^4(theta); (N,) float64."""
        x, y, d, f = (np.asarray(a, dtype=np.float64).ravel() for a in np.broadcast_arrays(x, y, depth_m, focus_m))
        ri = np.ones_like(x)
        raw = self.ctx.lens_source
        if raw is not None:
            e = _energy(raw(x, y, d, f)[0], len(x))
            # The on-axis reference depends on (depth, focus) only: one query per distinct pair.
            df, inv = np.unique(np.stack([d, f], 1), axis=0, return_inverse=True)
            k0 = raw(np.zeros(len(df)), np.zeros(len(df)), df[:, 0], df[:, 1])[0]
            e0 = _energy(k0, len(df))[inv.ravel()]
            ri = np.clip(e / np.maximum(e0, 1e-12), 0.0, 1.0)
        if self.cos4:
            tx, ty = field_to_tan(self.ctx.lens, x, y)
            ri = ri / (1.0 + tx * tx + ty * ty) ** 2  # cos^4(theta) = 1 / (1 + tan^2)^2
        return ri

    def __call__(self, x, y, depth_m, focus_m):
        k, s = self.source(x, y, depth_m, focus_m)
        k = normalise_energy(k)
        ri = self.relative_illumination(x, y, depth_m, focus_m)
        ri = ri.astype(k.dtype) if isinstance(k, np.ndarray) else k.new_tensor(ri)
        return k * ri.reshape(-1, *([1] * (k.ndim - 1))), s


def _energy(kernels, n: int) -> np.ndarray:
    """(n,) float64 total energy of n kernels (numpy or torch; summed in their own precision)."""
    return np.asarray(kernels.reshape(n, -1).sum(1), dtype=np.float64)
