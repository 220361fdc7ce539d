"""exposure: the light of each frame differs (auto exposure between frames, a flickering light source): frame i is
gains[i] times as bright as the simulator would make it, before the sensor's noise.

Settings: `sigma_log` draws independent log-normal gains per frame (training, and the benchmark's captures);
`gains` fixes them (one per frame, in the stack's order: a capture's is ascending focus); `by_capture` fixes them
per capture ({name: gains}), which is what the diagnosis fits (`aat_deploy.diagnose.fitters.fit_exposure`). A
rolling shutter's flicker bands within a frame are not modelled."""

from __future__ import annotations

import numpy as np

from aat_deploy.render.effects import Effect, SimContext, register


@register
class Exposure(Effect):
    name = "exposure"
    description = ("each frame's light differs (auto exposure, flicker): random log-normal gains of sigma_log, or "
                   "fixed per-frame gains (list in the stack's order; by_capture: per capture)")
    order = 70  # after the geometry, before the sensor (noise follows the light)
    defaults = {"sigma_log": 0.05, "gains": [], "by_capture": {}}
    candidates = [{"sigma_log": s} for s in (0.02, 0.05, 0.1)]

    def __init__(self, **params):
        super().__init__(**params)
        g = self.params["gains"]
        if isinstance(g, (int, float)) or any(not float(x) > 0 for x in g):
            raise ValueError(f"effect 'exposure': gains must be a list of positive numbers, got {g!r}")

    def frame_gains(self, n: int, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        """(n,) gains for a stack of n frames rendered for ctx.capture."""
        g = self.params["by_capture"].get(ctx.capture) if self.params["by_capture"] else None
        g = g if g is not None else self.params["gains"]
        if len(g):
            if len(g) != n:
                raise ValueError(f"effect 'exposure': {len(g)} gains for a stack of {n} frames")
            return np.asarray(g, np.float64)
        return np.exp(rng.normal(0.0, float(self.params["sigma_log"]), n))

    def stack(self, frames: np.ndarray, focus_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        g = self.frame_gains(len(frames), ctx, rng).astype(frames.dtype)
        return frames * g[:, None, None, None]

    def training_spec(self) -> str:
        """Random gains with the spread of the fitted ones (training cannot know a capture's)."""
        fitted = [np.log(np.asarray(g, np.float64)) for g in self.params["by_capture"].values()]
        if len(self.params["gains"]):
            fitted.append(np.log(np.asarray(self.params["gains"], np.float64)))
        s = float(np.std(np.concatenate(fitted))) if fitted else float(self.params["sigma_log"])
        return f"exposure:sigma_log={max(s, 1e-3):.4g}"
