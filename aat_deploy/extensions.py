"""What the torch side adds to the runtime when it is installed, found without the runtime importing it.

The runtime (`aat_deploy`) never imports `training`. Where a capability that needs torch helps it (tracing a lens's
best-focus map when none is stored), the training package declares it as an entry point of the group
`aat_deploy.extensions` in pyproject.toml:

    [project.entry-points."aat_deploy.extensions"]
    best_focus_tracer = "training.optics.field_focus:coarse_best_focus_map"

`load(name)` returns the declared object, or None when nothing is declared under that name or it cannot be
imported (torch or the training package missing): the caller then says in one line what to install. The
declarations come from the installed distribution's metadata; a checkout run from its own folder (PYTHONPATH, or an
editable install made before an extension was declared) reads them from its pyproject.toml, as `shipped.py` finds
its models there.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import tomllib

from .shipped import _checkout

GROUP = "aat_deploy.extensions"


def declared() -> dict[str, str]:
    """{name: "module:attribute"} of the extensions this install declares."""
    root = _checkout()
    if root is not None:
        with open(root / "pyproject.toml", "rb") as f:
            project = tomllib.load(f).get("project", {})
        return dict(project.get("entry-points", {}).get(GROUP, {}))
    return {ep.name: ep.value for ep in importlib.metadata.entry_points(group=GROUP)}


def load(name: str):
    """The extension `name`, or None if it is not declared or its module cannot be imported."""
    target = declared().get(name)
    if target is None:
        return None
    module, _, attr = target.partition(":")
    try:
        obj = importlib.import_module(module)
    except ImportError:
        return None
    for part in attr.split(".") if attr else ():
        obj = getattr(obj, part)
    return obj
