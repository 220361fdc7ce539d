"""What an effect is: the `Effect` base class with its hooks, the `SimContext` effects look at, an effect's text
form (`spec`; `registry.parse` reads it back), and how an effect reaches what only torch computes
(`torch_extension`, `NeedsTorch`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from aat_deploy import extensions
from aat_deploy.errors import AatError
from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_data


class NeedsTorch(AatError, RuntimeError):
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
