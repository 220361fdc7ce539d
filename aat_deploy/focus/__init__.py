"""Depth from focus without a trained model (classical focus measures), optionally aberration-aware from the lens's
own optics. Torch-free. Entry point on arrays: `classical_depth` (method.py, stack (S, 3, H, W)); as a depth method
`runner.FocusMethod`; the CLI is `aat-infer --method focus`, the Python API `aat_deploy.api.depth_from_focus(...,
method="focus")`."""

import warnings as _warnings

from .bestfocus import BestFocusError, BestFocusMap
from .method import FocusConfig, FocusResult, classical_depth


def depth_from_focus(*args, **kwargs) -> FocusResult:
    """Deprecated name of `classical_depth` (kept for code written against it: the same function; the API's
    `aat_deploy.api.depth_from_focus` takes frames as (S, H, W, 3) and is another function)."""
    _warnings.warn("aat_deploy.focus.depth_from_focus is now aat_deploy.focus.classical_depth", DeprecationWarning,
                   stacklevel=2)
    return classical_depth(*args, **kwargs)


__all__ = ["BestFocusError", "BestFocusMap", "FocusConfig", "FocusResult", "classical_depth", "depth_from_focus"]
