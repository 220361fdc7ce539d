"""misalignment: the frames do not line up (camera shake between frames, a tripod settling, a lens that shifts or
rescales the image as it focuses in a way its breathing model does not say): frame i is moved by (dx, dy) pixels
(right, down) and magnified by s about the sensor centre.

Settings: `sigma_px` (and `sigma_scale`) draw independent shifts (and magnifications) per frame; `by_capture`
fixes them per capture ({name: [dx0, dy0, s0, dx1, dy1, s1, ...]} in the stack's order), which is what the
diagnosis fits from the capture-vs-twin shifts of every region (`aat_deploy.diagnose.fitters.fit_misalignment`)."""

from __future__ import annotations

import numpy as np

from aat_deploy.render.effects import Effect, SimContext, register
from aat_deploy.render.effects.focus_breathing import warp_about_axis


@register
class Misalignment(Effect):
    name = "misalignment"
    description = ("frames shifted and magnified against each other (shake, settling, image shifts while focusing): "
                   "random shifts of sigma_px pixels (and magnifications of sigma_scale), or fixed per capture "
                   "(by_capture: {name: [dx, dy, scale] per frame})")
    order = 65  # after focus breathing's warp, before exposure and the sensor
    defaults = {"sigma_px": 1.0, "sigma_scale": 0.0, "by_capture": {}}
    candidates = [{"sigma_px": s} for s in (0.5, 1.0, 2.0)]

    def frame_warps(self, n: int, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        """(n, 3) per-frame dx, dy (px), scale for a stack of n frames rendered for ctx.capture."""
        fixed = self.params["by_capture"].get(ctx.capture) if self.params["by_capture"] else None
        if fixed is not None:
            w = np.asarray(fixed, np.float64).reshape(-1, 3)
            if len(w) != n:
                raise ValueError(f"effect 'misalignment': {len(w)} frame warps for a stack of {n} frames")
            return w
        p = self.params
        return np.column_stack([rng.normal(0, float(p["sigma_px"]), (n, 2)),
                                1.0 + rng.normal(0, float(p["sigma_scale"]), n)])

    def stack(self, frames: np.ndarray, focus_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        w = self.frame_warps(len(frames), ctx, rng)
        return np.stack([fr if (dx == 0 and dy == 0 and s == 1) else warp_about_axis(fr, s, (dx, dy), ctx)
                         for fr, (dx, dy, s) in zip(frames, w)])

    def binned(self, factor: int) -> "Misalignment":
        """Shifts in pixels of the binned sensor."""
        p = self.params
        by = {k: (np.asarray(v, np.float64).reshape(-1, 3) / [factor, factor, 1]).ravel().tolist()
              for k, v in p["by_capture"].items()}
        return Misalignment(sigma_px=float(p["sigma_px"]) / factor, sigma_scale=float(p["sigma_scale"]), by_capture=by)

    def training_spec(self) -> str:
        """Random warps with the spread of the fitted ones (training cannot know a capture's)."""
        fitted = [np.asarray(v, np.float64).reshape(-1, 3) for v in self.params["by_capture"].values()]
        if not fitted:
            return f"misalignment:sigma_px={float(self.params['sigma_px']):.4g}:sigma_scale={float(self.params['sigma_scale']):.4g}"
        w = np.concatenate(fitted)
        return (f"misalignment:sigma_px={max(float(np.std(w[:, :2])), 1e-3):.4g}"
                f":sigma_scale={float(np.std(w[:, 2])):.4g}")
