"""A stack through the lens: every frame of a focal stack rendered by the layered renderer with the PSFs and
per-field focus the simulator's effects make (before the effects' warps and the sensor). The torch simulator
(`training.render.simulator`) and the torch-free twins (`aat_deploy.diagnose.twin`) both render with it."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from aat_deploy.backend import namespace
from aat_deploy.optics.field import field_of
from aat_deploy.render import effects as fx
from aat_deploy.render.layered import LayeredConfig, render_layered


def optical_stack(effects: list[fx.Effect], thin_source, rgb, depth_m, focus_m, ctx: fx.SimContext,
                  cfg: LayeredConfig = LayeredConfig(), workers: int = 1):
    """Frames (S, C, H, W) through the lens, before warps and the sensor, numpy or torch as rgb and depth_m are.
    thin_source: the baseline PSFs the effects wrap (`GaussianSource`; torch: `training.render.sources`); rgb
    (C, H, W) linear and depth_m (H, W) metres from the sensor (> 0) of the crop at ctx.origin; focus_m (S,) true
    focus distances (m). workers > 1 renders frames in threads (numpy's FFTs and onnxruntime release the GIL;
    frames are independent, so the result is the same)."""
    src = fx.wrap_source(effects, thin_source, ctx)
    focus_at = fx.focus_at(effects, ctx)

    def field_fn(r, c):
        return field_of(r, c, ctx.sensor_hw, ctx.origin)

    def one(f):
        return render_layered(rgb, depth_m, float(f), src, field_fn, cfg, focus_at=focus_at)

    focus = np.ravel(focus_m)
    xp = namespace(rgb)
    if workers > 1 and len(focus) > 1:
        with ThreadPoolExecutor(min(workers, len(focus))) as ex:
            return xp.stack(list(ex.map(one, focus)))
    return xp.stack([one(f) for f in focus])
