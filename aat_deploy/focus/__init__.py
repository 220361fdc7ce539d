"""Depth from focus without a trained model (classical focus measures), optionally aberration-aware from the lens's
own optics. Torch-free. Entry point: `depth_from_focus` (method.py); the CLI is `aat-infer --method focus`."""

from .bestfocus import BestFocusError, BestFocusMap
from .method import FocusConfig, FocusResult, depth_from_focus

__all__ = ["BestFocusError", "BestFocusMap", "FocusConfig", "FocusResult", "depth_from_focus"]
