"""The simulator's effects: each a switch, each one file in this package.

An effect is a class derived from `Effect` with a unique `name`, registered by the `@register` decorator when
its module is imported; every module in this package is imported on first use of the registry, so adding an
effect is adding one file. An effect changes the simulation through any of these hooks (all optional):

- `wrap_source(source, ctx)`: the PSFs (aberrations, vignetting, colour);
- `focus_at(ctx)`: a per-field focus distance;
- `sensor_shift_mm(ctx)`: a per-field axial shift (mm, +z away from the lens) of the sensor against the lens's
  best focus (sensor tilt, a lens's manufacturing tolerance); the shifts of all effects add up, and the focus
  they make is looked up in the lens's focus table;
- `warp(frame, focus_m, ctx)`: the geometry of a rendered frame (focus breathing);
- `stack(frames, focus_m, ctx, rng)`: every frame of the stack at once, after the warps and before the sensor
  (effects that differ from frame to frame: exposure changes, misalignment);
- `sensor(frame, ctx, rng)`: linear RAW values (noise);
- `report_focus(focus_m, ctx, rng)`: the focus distances written to metadata (EXIF errors);
- `twin_focus(focus_reported_m, ctx, rng)`: the inverse, for a digital twin that knows only what the metadata says.

One implementation serves both renderers: the torch simulator (`training.render.simulator`) and the torch-free
twin renderer (`aat_deploy.diagnose.twin`). The registry and the effects are torch-free: frames given to
`warp`/`sensor` are numpy (C, H, W) arrays; PSF wrappers take numpy or torch kernels, whichever their source
returns. What only torch can compute (ray-traced PSFs at three wavelengths, the real-ray focus table, a perturbed
lens's focal surface) comes from the training package through its declared extensions (`torch_extension`,
`aat_deploy.extensions`), never by importing it; an effect that can only be rendered with torch says why in
`needs_torch`.

The sim-to-real diagnosis switches these on and off one at a time (`names()` lists them); it does not know an
effect's settings, so it fits them on the images (`aat_deploy.diagnose.fitters`) or, for effects without a
fitter, tries each of the effect's `candidates` (parameter sets) and keeps the best.

Settings are numbers, strings or lists of numbers; in text (`spec`, `parse`: 'name:k=v:k2=v2') a list is written
with '/' between its numbers ('gains=1/1.02/0.98').

The machinery is three modules: `base.py` (`Effect`, `SimContext`, `NeedsTorch`), `registry.py` (by name, and the
text form), `compose.py` (a list of effects applied hook by hook); this package re-exports them, so callers write
`from aat_deploy.render import effects as fx; fx.parse(...)`. Every other module here is one effect.
"""

from __future__ import annotations

from .base import Effect, NeedsTorch, SimContext, is_post, spec, torch_extension, traced_focus_table
from .compose import focus_at, post_frame, post_stack, twin_focus, varies_focus, wrap_source
from .registry import describe, make, names, parse, register

__all__ = ["Effect", "NeedsTorch", "SimContext", "is_post", "torch_extension", "traced_focus_table", "focus_at", "varies_focus",
           "post_frame", "post_stack", "twin_focus", "wrap_source", "describe", "make", "names", "parse", "register",
           "spec"]
