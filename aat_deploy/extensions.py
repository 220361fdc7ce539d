"""What the torch side adds to the runtime when it is installed, found without the runtime importing it.

The runtime (`aat_deploy`) never imports `training`. Where a capability that needs torch helps it (tracing a lens's
best-focus map when none is stored), the training package declares it as an entry point of the group
`aat_deploy.extensions` in pyproject.toml:

    [project.entry-points."aat_deploy.extensions"]
    best_focus_tracer = "training.optics.field_focus:coarse_best_focus_map"

`load(name)` returns the declared object, or raises `ExtensionUnavailable` with one line saying why (not declared
by this install, or its module cannot be imported: torch or the training package missing) and what to install.
Callers that have a torch-free fallback ask `load(name, optional=True)`, which returns None instead. The
declarations come from the installed distribution's metadata; a checkout run from its own folder (PYTHONPATH, or an
editable install made before an extension was declared) reads them from its pyproject.toml, as `shipped.py` finds
its models there.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import tomllib

from .errors import AatError
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


class ExtensionUnavailable(AatError, ImportError):
    """A capability of the training side that this install cannot provide; the message is one line."""


def _torch_missing() -> bool:
    try:
        return importlib.util.find_spec("torch") is None
    except (ImportError, ValueError):
        return True


def _why(e: ImportError) -> str:
    missing = (e.name or "").split(".")[0]
    if missing == "torch" or (missing != "training" and _torch_missing()):
        return "needs torch: pip install 'aat-dff[train]'"
    if missing == "training":
        return "needs the training package: pip install 'aat-dff[train]' from a clone"
    first = str(e).splitlines()[0] if str(e) else type(e).__name__
    return f"cannot be imported ({first[:200]}); pip install 'aat-dff[train]' installs what it needs"


def load(name: str, optional: bool = False):
    """The extension `name`. Not declared or not importable: `ExtensionUnavailable` (one line, saying why), or
    None when `optional` (for callers with a torch-free fallback)."""
    target = declared().get(name)
    if target is None:
        if optional:
            return None
        raise ExtensionUnavailable(f"extension {name!r} is not declared by this install "
                                   f"(declared: {', '.join(sorted(declared())) or 'none'})")
    module, _, attr = target.partition(":")
    try:
        obj = importlib.import_module(module)
    except ImportError as e:
        if optional:
            return None
        raise ExtensionUnavailable(f"extension {name!r} ({target}) {_why(e)}") from None
    for part in attr.split(".") if attr else ():
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise ExtensionUnavailable(f"extension {name!r}: {module} has no {attr!r} (declared as {target}); "
                                       "the install is inconsistent, reinstall aat-dff") from None
    return obj
