"""noise: Poisson-Gaussian sensor noise in linear RAW units (photon shot noise + read noise)."""

from __future__ import annotations

import numpy as np

from aat_deploy.render.effects import Effect, SimContext, register


def poisson_gaussian(x: np.ndarray, full_well_e: float, read_noise_e: float, rng: np.random.Generator) -> np.ndarray:
    """Noisy version of linear signal x (1.0 = white level = full_well_e electrons): Poisson electrons plus
    Gaussian read noise (electrons RMS), back in white-level units. Negative values are kept (as in RAW)."""
    e = rng.poisson(np.clip(x, 0, None) * full_well_e).astype(np.float64)
    e += rng.normal(0.0, read_noise_e, size=e.shape)
    return (e / full_well_e).astype(x.dtype)


@register
class Noise(Effect):
    name = "noise"
    description = "Poisson-Gaussian sensor noise in linear RAW units (shot noise from full_well_e, read noise)"
    order = 90
    defaults = {"full_well_e": 8000.0, "read_noise_e": 3.0}
    # factor-2 steps: a poorly fitted noise level leaves a focus-curve residual that hides weaker effects
    candidates = [{"full_well_e": e} for e in (300.0, 600.0, 1200.0, 2500.0, 5000.0, 10000.0)]

    def binned(self, factor: int) -> Noise:
        """The same noise after b x b binning (the block mean): b^2 x the electrons, b x the read noise in
        quadrature, so the binned pixel's variance is the full-resolution one / b^2."""
        p = self.params
        return Noise(full_well_e=float(p["full_well_e"]) * factor ** 2, read_noise_e=float(p["read_noise_e"]) * factor)

    def sensor(self, frame: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        return poisson_gaussian(frame, self.params["full_well_e"], self.params["read_noise_e"], rng)
