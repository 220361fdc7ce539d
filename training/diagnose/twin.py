"""Digital twins: a capture's scene (ground-truth depth + an all-in-focus image) rendered by the simulator a
model was trained with, at the capture's reported focus distances, optionally with extra effects.

Twins are rendered torch-free (`aat_deploy.twin`, the exported PSF surrogate and the numpy layered renderer)
whenever every effect involved allows it; the torch simulator takes over for the rest: `chromatic` (ray-traced
at three wavelengths) and the lens's PSFs when no surrogate was found (ray tracing).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from aat_deploy.model import DfFModel
from aat_deploy.twin.renderer import TwinError, model_effects  # noqa: F401 (re-exported)
from aat_deploy.twin.renderer import TwinRenderer as NumpyTwinRenderer
from training.lens.io import load_lens
from training.lens.schema import Lens
from training.render import effects as fx
from training.render.simulator import Simulator
from training.render.sources import OnnxPSF, RayTracedPSF

ROOT = Path(__file__).resolve().parents[2]


def find_lens(model: DfFModel, lens_path: str | Path | None) -> tuple[Lens, Path]:
    """The lens the model was trained for, with the model's sensor, and its file: `lens_path` or the file in
    lenses/ with the model's aat.lens_name."""
    if lens_path is None:
        name = model.meta.get("aat.lens_name")
        for p in sorted((ROOT / "lenses").glob("*.json")):
            try:
                cand = load_lens(p)
            except Exception:  # a broken file in lenses/ must not stop the search
                continue
            if cand.name == name:
                lens_path = p
                break
        else:
            raise TwinError(f"{model.path}: lens {name!r} not found in {ROOT / 'lenses'}; pass --lens")
    lens = load_lens(lens_path)
    (w_mm, h_mm), (w_px, h_px) = model.meta["aat.sensor_mm"], model.sensor_px
    sensor = dataclasses.replace(lens.sensor, width_mm=float(w_mm), height_mm=float(h_mm),
                                 width_px=int(w_px), height_px=int(h_px))
    return dataclasses.replace(lens, sensor=sensor), Path(lens_path)


def find_psf(lens: Lens, psf_path: str | Path | None):
    """The lens's PSF source: the given surrogate (.onnx) or the first in models/ made for this lens; without
    one, ray tracing (slow)."""
    if psf_path is not None:
        return OnnxPSF(psf_path, lens, threads=2)
    for p in sorted((ROOT / "models").glob("psf_*.onnx")):
        try:
            return OnnxPSF(p, lens, threads=2)
        except ValueError:  # made for another lens / pixel pitch
            continue
    return RayTracedPSF(lens)


class TwinRenderer(NumpyTwinRenderer):
    """`aat_deploy.twin.TwinRenderer` (same interface and cache) with the torch simulator behind it: optical
    stacks whose effects numpy cannot render (`why_torch`) are rendered by `training.render.simulator`. The
    post-optics hooks (noise, focus breathing) are numpy for both.

    lens_source: `OnnxPSF` (twins torch-free where possible) or `RayTracedPSF` (the lens's PSFs by torch).
    torch_only: render every optical stack with the torch simulator (comparisons, benchmarks)."""

    def __init__(self, model: DfFModel, lens: Lens, lens_source, cell_px: int = 64, cache_items: int = 256,
                 torch_only: bool = False):
        super().__init__(model, lens, lens_source.numpy if isinstance(lens_source, OnnxPSF) else None,
                         cell_px, cache_items)
        self.torch_source, self.torch_only = lens_source, torch_only

    def fallback_focus_table(self) -> None:
        return None  # traced from the lens on first use (`SimContext.focus_table`)

    def simulator(self, effects: list[fx.Effect]) -> Simulator:
        return Simulator(self.lens, self.torch_source, effects, self.layered)

    def optical(self, effects, rgb: np.ndarray, depth_m: np.ndarray, focus_m: np.ndarray, ctx: fx.SimContext) -> np.ndarray:
        if not self.torch_only and self.why_torch(effects) is None:
            return super().optical(effects, rgb, depth_m, focus_m, ctx)
        ctx = dataclasses.replace(ctx, lens_source=self.torch_source)
        return self.simulator(effects).optical(torch.from_numpy(rgb), torch.from_numpy(depth_m), focus_m, ctx).numpy()
