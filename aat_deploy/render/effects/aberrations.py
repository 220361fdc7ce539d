"""aberrations: the real lens's PSFs instead of the thin-lens Gaussian (same EFL, F-number and pixels)."""

from __future__ import annotations

from aat_deploy.render.effects import Effect, SimContext, register
from aat_deploy.render.sources import UnitEnergy


@register
class Aberrations(Effect):
    name = "aberrations"
    description = ("real-lens PSFs (ray-traced or surrogate: field curvature, astigmatism, coma, spherical) "
                   "instead of the thin-lens Gaussian")
    order = 0
    uses_lens_psfs = True

    def wrap_source(self, source, ctx: SimContext):
        if ctx.lens_source is None:
            raise ValueError("effect 'aberrations' needs the lens's PSFs (a surrogate .onnx or ray tracing)")
        return UnitEnergy(ctx.lens_source)  # light fall-off is the `vignetting` effect's business
