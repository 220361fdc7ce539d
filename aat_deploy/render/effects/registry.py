"""Effects by name: `register` (the decorator each effect's class carries), `names`, `describe`, `make`, and
`parse`, which makes effects from their text form ('name:k=v:k2=v2', as `base.spec` writes it). Every module of
this package is imported on first use, so an effect in a new file is found without being listed anywhere."""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path
from typing import Any

from .base import Effect

_REGISTRY: dict[str, type[Effect]] = {}
_LOADED = False
_PACKAGE = __name__.rpartition(".")[0]


def register(cls: type[Effect]) -> type[Effect]:
    if not cls.name or cls.name in _REGISTRY:
        raise ValueError(f"effect name {cls.name!r} empty or already registered")
    _REGISTRY[cls.name] = cls
    return cls


def _load() -> None:
    global _LOADED
    if not _LOADED:
        for mod in pkgutil.iter_modules([str(Path(__file__).parent)]):
            importlib.import_module(f"{_PACKAGE}.{mod.name}")
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
