"""focus_brightness: a frame focused nearer is darker. To focus, the lens moves away from the sensor and its exit
pupil with it; the working f-number grows with the exit pupil's distance from the sensor, and the image
irradiance falls with its square. At a fixed exposure (a focal stack), the RF50 focused at 0.6 m gets 0.83 of
the light it gets focused at infinity, at 6 m 0.98 (its focus table and exit pupil, as `focus_breathing` uses
them).

The training simulator and the twins render every frame as bright as at infinity focus unless this effect is on.
Settings: `coefficient` (1 = the lens's geometry; 0 = none): a lens that focuses by moving inner groups changes
its working f-number differently, which the coefficient scales (in log irradiance). The diagnosis fits it from
the frames' brightness (`aat_deploy.diagnose.fitters.fit_focus_brightness`); its focus fit corrects every frame's
brightness whatever the cause (`aat_deploy.diagnose.focusrobust`)."""

from __future__ import annotations

import numpy as np

from aat_deploy.render.effects import Effect, SimContext, register
from aat_deploy.render.effects.focus_breathing import breathing_scale


def irradiance_gains(focus_m, ctx: SimContext, coefficient: float = 1.0) -> np.ndarray:
    """(S,) image irradiance of frames focused at focus_m (m from the sensor) relative to focus at infinity:
    (exit pupil to sensor at infinity focus / at this focus)^(2 coefficient)."""
    s = np.asarray(breathing_scale(ctx.lens, np.ravel(focus_m), ctx.focus_table(), ctx.exit_pupil_z_mm), np.float64)
    return s ** (-2.0 * float(coefficient))


@register
class FocusBrightness(Effect):
    name = "focus_brightness"
    description = ("frames focused nearer are darker: the working f-number grows as the lens moves out to focus "
                   "(exit pupil to sensor distance squared); coefficient scales it (1 = the lens's geometry)")
    order = 65  # after the geometry, before the sensor (noise follows the light), with exposure
    defaults = {"coefficient": 1.0}
    candidates = [{"coefficient": c} for c in (0.5, 1.0, 2.0)]

    def stack(self, frames: np.ndarray, focus_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        g = irradiance_gains(focus_m, ctx, self.params["coefficient"]).astype(frames.dtype)
        return frames * g[:, None, None, None]
