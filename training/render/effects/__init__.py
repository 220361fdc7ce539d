"""The simulator's effects: each a switch, each one file in this package.

An effect is a class derived from `Effect` with a unique `name`, registered by the `@register` decorator when
its module is imported; every module in this package is imported on first use of the registry, so adding an
effect is adding one file. An effect changes the simulation through any of these hooks (all optional):

- `wrap_source(source, ctx)`: the PSFs (aberrations, vignetting, colour);
- `focus_at(ctx)`: a per-field focus distance (sensor tilt);
- `warp(frame, focus_m, ctx)`: the geometry of a rendered frame (focus breathing);
- `sensor(frame, ctx, rng)`: linear RAW values (noise);
- `report_focus(focus_m, ctx, rng)`: the focus distances written to metadata (EXIF errors);
- `twin_focus(focus_reported_m, ctx, rng)`: the inverse, for a digital twin that knows only what the metadata says.

The sim-to-real diagnosis switches these on and off one at a time (`names()` lists them); it does not know an
effect's settings, so it tries each of the effect's `candidates` (parameter sets) and keeps the best fit.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from training.lens.schema import Lens

_REGISTRY: dict[str, type[Effect]] = {}
_LOADED = False


@dataclass
class SimContext:
    """What effects may look at: the lens, the full sensor (rows, cols) and the crop's top-left pixel."""

    lens: Lens
    sensor_hw: tuple[int, int]
    origin: tuple[int, int] = (0, 0)
    lens_source: Any = None  # the real lens's PSF source (the `aberrations` effect switches to it)


class Effect:
    """Base class. `params` are the effect's settings (documented per effect), JSON-serialisable."""

    name: str = ""
    description: str = ""
    order: int = 50  # hooks run in ascending order (PSF wrappers: the lower, the closer to the raw source)
    defaults: dict[str, Any] = {}
    candidates: list[dict[str, Any]] = [{}]  # settings the diagnosis tries ({} = the defaults)

    def __init__(self, **params: Any):
        unknown = set(params) - set(self.defaults)
        if unknown:
            raise ValueError(f"effect {self.name!r}: unknown parameter(s) {sorted(unknown)}; "
                             f"known: {sorted(self.defaults)}")
        self.params = {**self.defaults, **params}

    def wrap_source(self, source, ctx: SimContext):
        return source

    def focus_at(self, ctx: SimContext) -> Callable | None:
        return None

    def warp(self, frame: torch.Tensor, focus_m: float, ctx: SimContext) -> torch.Tensor:
        return frame

    def sensor(self, frame: torch.Tensor, ctx: SimContext, rng: np.random.Generator) -> torch.Tensor:
        return frame

    def report_focus(self, focus_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        return focus_m

    def twin_focus(self, focus_reported_m: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        return focus_reported_m

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params})"


def is_post(effect: Effect) -> bool:
    """True when the effect only acts after the optics (warp / sensor hooks), so a rendered stack can be reused."""
    t = type(effect)
    return all(getattr(t, h) is getattr(Effect, h) for h in ("wrap_source", "focus_at", "twin_focus", "report_focus"))


def spec(effect: Effect) -> str:
    """'name' or 'name:k=v:k=v' for settings that differ from the defaults (what `parse` reads back)."""
    changed = [f"{k}={v}" for k, v in effect.params.items() if type(effect).defaults.get(k) != v]
    return ":".join([effect.name, *changed])


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
    Values that read as numbers become floats."""
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
                    params[k] = float(v)
                except ValueError:
                    params[k] = v
            out.append(make(name, **params))
        else:
            it = dict(it)
            out.append(make(it.pop("name"), **it))
    return sorted(out, key=lambda e: e.order)
