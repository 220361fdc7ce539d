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
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from aat_deploy import extensions
from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_data

_REGISTRY: dict[str, type[Effect]] = {}
_LOADED = False


class NeedsTorch(RuntimeError):
    """Raised for effects (or PSFs) that only the training simulator can render, when it is not installed."""


def torch_extension(name: str, what: str):
    """The training package's extension `name` (`aat_deploy.extensions`: declared in pyproject.toml, loaded
    without the runtime importing `training`), or NeedsTorch saying that `what` needs it and why it is unavailable."""
    try:
        return extensions.load(name)
    except extensions.ExtensionUnavailable as e:
        raise NeedsTorch(f"{what} needs the training package (torch): {e}") from None


def traced_focus_table(lens: Lens):
    """The lens's real-ray focus table (`FocusTable`), traced by the training package (torch)."""
    return torch_extension("real_ray_focus_table", f"tracing the focus table of lens {lens.name!r}")(lens)


@dataclass
class SimContext:
    """What effects may look at: the lens, the full sensor (rows, cols), the crop's top-left pixel, the real
    lens's PSF source, and the lens's focusing: `table` (sensor z vs diopters, `optics.focus_table.FocusTable`;
    None = real-ray traced from the lens on first use, which needs torch) and the paraxial exit pupil (mm from the
    first vertex; None = computed from the lens). The torch simulator traces; the torch-free twin renderer fills
    both from the PSF surrogate's metadata. `capture` names the capture a digital twin is rendered for."""

    lens: Lens
    sensor_hw: tuple[int, int]
    origin: tuple[int, int] = (0, 0)
    lens_source: Any = None  # the real lens's PSF source (the `aberrations` effect switches to it)
    table: Any = None
    exit_pupil_z_mm: float | None = None
    capture: str = ""  # the capture a twin is rendered for (settings fitted per capture: exposure, misalignment)

    def __post_init__(self):
        if self.exit_pupil_z_mm is None:
            self.exit_pupil_z_mm = paraxial_data(self.lens).exit_pupil_z_mm

    def focus_table(self):
        """The lens's focus table (`FocusTable`), traced once if none was given."""
        if self.table is None:
            self.table = traced_focus_table(self.lens)
        return self.table


class Effect:
    """Base class. `params` are the effect's settings (documented per effect), JSON-serialisable."""

    name: str = ""
    description: str = ""
    order: int = 50  # hooks run in ascending order (PSF wrappers: the lower, the closer to the raw source)
    defaults: dict[str, Any] = {}
    candidates: list[dict[str, Any]] = [{}]  # settings the diagnosis tries ({} = the defaults)
    needs_torch: str = ""  # why only the torch simulator can render it ("" = numpy can)
    uses_lens_psfs: bool = False  # reads ctx.lens_source (the real lens's PSFs)

    def __init__(self, **params: Any):
        unknown = set(params) - set(self.defaults)
        if unknown:
            raise ValueError(f"effect {self.name!r}: unknown parameter(s) {sorted(unknown)}; "
                             f"known: {sorted(self.defaults)}")
        self.params = {**self.defaults, **params}

    def torch_reason(self, ctx: SimContext) -> str:
        """Why rendering this effect for `ctx` needs torch ("" = numpy can); `needs_torch` unless the context
        decides (e.g. `chromatic` with per-wavelength surrogates next to the lens's)."""
        return self.needs_torch

    def wrap_source(self, source, ctx: SimContext):
        return source

    def focus_at(self, ctx: SimContext) -> Callable | None:
        return None

    def sensor_shift_mm(self, ctx: SimContext) -> Callable | None:
        """None, or fn(x, y, focus_m) -> axial sensor shift (mm, + away from the lens) at normalised field (x, y)
        for a camera focused at focus_m on axis (arrays broadcast)."""
        return None

    def warp(self, frame: np.ndarray, focus_m: float, ctx: SimContext) -> np.ndarray:
        """frame (C, H, W) linear, numpy."""
        return frame

    def stack(self, frames: np.ndarray, focus_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        """frames (S, C, H, W) linear, numpy, in the order rendered (a capture's: ascending focus); focus_m (S,)."""
        return frames

    def sensor(self, frame: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        """frame (C, H, W) linear (1.0 = white level), numpy."""
        return frame

    def report_focus(self, focus_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        return focus_m

    def twin_focus(self, focus_reported_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        return focus_reported_m

    def binned(self, factor: int) -> Effect | None:
        """This effect as seen on a sensor binned factor x factor (the diagnosis searches at reduced resolution):
        itself by default; effects in pixel units rescale, and an effect that binning removes returns None."""
        return self

    def training_spec(self) -> str:
        """The `--effects` text to train with this effect: its settings by default; effects fitted frame by
        frame on a capture (exposure, misalignment) give their random form instead."""
        return spec(self)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params})"


def is_post(effect: Effect) -> bool:
    """True when the effect only acts after the optics (warp / sensor hooks), so a rendered stack can be reused."""
    t = type(effect)
    return all(getattr(t, h) is getattr(Effect, h)
               for h in ("wrap_source", "focus_at", "sensor_shift_mm", "twin_focus", "report_focus"))


def wrap_source(effects: list[Effect], source, ctx: SimContext):
    """The PSF source seen through every effect's `wrap_source`, in the effects' order (lowest first)."""
    for e in sorted(effects, key=lambda e: e.order):
        source = e.wrap_source(source, ctx)
    return source


def focus_at(effects: list[Effect], ctx: SimContext) -> Callable | None:
    """The per-field focus function of the effects (None: focus is the same everywhere): the first effect's
    `focus_at` if one has it, else the sum of their sensor shifts (`sensor_shift_mm`) through the lens's focus
    table: focus(x, y) = 1 / diopters(z(focus_m) + sum of shifts), z clipped to the table."""
    effects = sorted(effects, key=lambda e: e.order)
    first = next((f for f in (e.focus_at(ctx) for e in effects) if f is not None), None)
    shifts = [f for f in (e.sensor_shift_mm(ctx) for e in effects) if f is not None]
    if first is not None or not shifts:
        return first
    table = ctx.focus_table()

    def fn(x, y, focus_m):
        z = float(table(focus_m)) + sum(np.asarray(f(x, y, focus_m), np.float64) for f in shifts)
        z = np.clip(z, table.sensor_z_mm[0], table.sensor_z_mm[-1])  # ascending in z with diopters
        return 1.0 / np.interp(z, table.sensor_z_mm, table.diopters)

    return fn


def twin_focus(effects: list[Effect], focus_reported_m, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
    """True focus distances (m) for a digital twin that knows only the reported ones."""
    focus = np.asarray(focus_reported_m, dtype=np.float64).ravel()
    for e in sorted(effects, key=lambda e: e.order):
        focus = e.twin_focus(focus, ctx, rng)
    return focus


def post_frame(effects: list[Effect], frame: np.ndarray, focus_m: float, ctx: SimContext,
               rng: np.random.Generator) -> np.ndarray:
    """One rendered frame (C, H, W), numpy, through the effects' geometry (`warp`) then sensor (`sensor`) hooks
    (effects with a `stack` hook need the whole stack: `post_stack`)."""
    effects = sorted(effects, key=lambda e: e.order)
    for e in effects:
        frame = e.warp(frame, focus_m, ctx)
    for e in effects:
        frame = e.sensor(frame, ctx, rng)
    return frame


def post_stack(effects: list[Effect], frames, focus_m, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
    """Rendered frames (S, C, H, W), numpy, through the warps (frame by frame), the `stack` hooks (the whole stack)
    and the sensor hooks (frame by frame, in order: the same random draws as `post_frame` frame after frame when
    no effect has a `stack` hook)."""
    effects = sorted(effects, key=lambda e: e.order)
    focus = np.asarray(focus_m, np.float64).ravel()
    out = [fr for fr in frames]
    for i, f in enumerate(focus):
        for e in effects:
            out[i] = e.warp(out[i], float(f), ctx)
    stacked = [e for e in effects if type(e).stack is not Effect.stack]
    if stacked:
        arr = np.stack(out)
        for e in stacked:
            arr = e.stack(arr, focus, ctx, rng)
        out = list(arr)
    for i in range(len(out)):
        for e in effects:
            out[i] = e.sensor(out[i], ctx, rng)
    return np.stack(out)


def _text(v) -> str:
    if isinstance(v, (list, tuple)):
        return "/".join(f"{float(x):.10g}" for x in v)
    return str(v)


def spec(effect: Effect) -> str:
    """'name' or 'name:k=v:k=v' for settings that differ from the defaults (what `parse` reads back; lists as
    numbers joined by '/')."""
    changed = [f"{k}={_text(v)}" for k, v in effect.params.items()
               if type(effect).defaults.get(k) != v and not isinstance(v, dict)]
    fitted = [k for k, v in effect.params.items() if isinstance(v, dict) and v]
    return ":".join([effect.name, *changed]) + ("" if not fitted else f"[{','.join(fitted)} fitted per capture]")


def register(cls: type[Effect]) -> type[Effect]:
    if not cls.name or cls.name in _REGISTRY:
        raise ValueError(f"effect name {cls.name!r} empty or already registered")
    _REGISTRY[cls.name] = cls
    return cls


def _load() -> None:
    global _LOADED
    if not _LOADED:
        for mod in pkgutil.iter_modules(__path__):
            importlib.import_module(f"{__name__}.{mod.name}")
        _LOADED = True


def names() -> list[str]:
    """Registered effect names, sorted."""
    _load()
    return sorted(_REGISTRY)


def describe() -> dict[str, str]:
    _load()
    return {n: _REGISTRY[n].description for n in sorted(_REGISTRY)}


def make(name: str, **params: Any) -> Effect:
    """An effect instance by name (ValueError naming the known effects if unknown)."""
    _load()
    if name not in _REGISTRY:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name](**params)


def parse(specs: str | list | None) -> list[Effect]:
    """Effects from 'a,b:k=v:k2=v2' or ['a', 'b:k=v', {'name': 'b', 'k': 1}] (None/'' -> none).
    Values that read as numbers become floats, numbers joined by '/' lists of floats."""
    if not specs:
        return []
    items = specs.split(",") if isinstance(specs, str) else specs
    out = []
    for it in items:
        if isinstance(it, str):
            name, *kvs = it.strip().split(":")
            params = {}
            for kv in kvs:
                k, sep, v = kv.partition("=")
                if not sep:
                    raise ValueError(f"effect {name!r}: setting {kv!r} is not key=value")
                try:
                    params[k] = [float(x) for x in v.split("/")] if "/" in v else float(v)
                except ValueError:
                    params[k] = v
            out.append(make(name, **params))
        else:
            it = dict(it)
            out.append(make(it.pop("name"), **it))
    return sorted(out, key=lambda e: e.order)
