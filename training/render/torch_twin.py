"""The torch simulator behind the runtime's digital twins: `aat-diagnose` renders twins torch-free
(`aat_deploy.diagnose.twin.TwinRenderer`: the exported PSF surrogate and the numpy layered renderer) whenever
every effect involved allows it; this subclass renders the rest with the training simulator: `chromatic` (ray
traced at three wavelengths when no per-wavelength surrogates sit next to the lens's) and the lens's PSFs when no
surrogate was found (ray tracing).

The runtime never imports this module: it reaches `torch_twin_renderer` through the extension of that name
declared in pyproject.toml (`aat_deploy.extensions`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from aat_deploy.diagnose.twin import TwinRenderer
from aat_deploy.infer.model import DfFModel
from aat_deploy.lens.schema import Lens
from aat_deploy.render import effects as fx
from aat_deploy.render.sources import OnnxSource
from training.render.simulator import Simulator
from training.render.sources import OnnxPSF, RayTracedPSF


def torch_source(lens: Lens, surrogate: OnnxSource | None):
    """The lens's PSF source for the torch simulator: the surrogate on onnxruntime, else ray tracing (slow)."""
    return OnnxPSF.from_source(surrogate) if surrogate is not None else RayTracedPSF(lens)


class TorchTwinRenderer(TwinRenderer):
    """`aat_deploy.diagnose.twin.TwinRenderer` (same interface and cache) with the torch simulator behind it:
    optical stacks whose effects numpy cannot render (`why_torch`) are rendered by `training.render.simulator`.
    The post-optics hooks (noise, focus breathing) are numpy for both.

    lens_source: `OnnxPSF` (twins torch-free where possible) or `RayTracedPSF` (the lens's PSFs by torch).
    torch_only: render every optical stack with the torch simulator (comparisons, benchmarks)."""

    uses_torch = True

    def __init__(self, model: DfFModel, lens: Lens, lens_source, cell_px: int = 64, cache_items: int = 256,
                 torch_only: bool = False):
        super().__init__(model, lens, lens_source.numpy if isinstance(lens_source, OnnxPSF) else None,
                         cell_px, cache_items)
        self.torch_source, self.torch_only = lens_source, torch_only

    def fallback_focus_table(self) -> None:
        return None  # traced from the lens on first use (`SimContext.focus_table`)

    def simulator(self, effects: list[fx.Effect]) -> Simulator:
        return Simulator(self.lens, self.torch_source, effects, self.layered)

    def optical(self, effects, rgb: np.ndarray, depth_m: np.ndarray, focus_m: np.ndarray,
                ctx: fx.SimContext) -> np.ndarray:
        if not self.torch_only and self.why_torch(effects) is None:
            return super().optical(effects, rgb, depth_m, focus_m, ctx)
        ctx = dataclasses.replace(ctx, lens_source=self.torch_source)
        return self.simulator(effects).optical(torch.from_numpy(rgb), torch.from_numpy(depth_m), focus_m, ctx).numpy()


def torch_twin_renderer(model: DfFModel, lens: Lens, surrogate: OnnxSource | None) -> TorchTwinRenderer:
    """The extension `torch_twin_renderer`: twins of `model`'s captures with the torch simulator behind them."""
    return TorchTwinRenderer(model, lens, torch_source(lens, surrogate))
