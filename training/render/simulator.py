"""The focal-stack simulator: a PSF source, a registry of effects and the fast renderer, composed.

Without effects it is the thin-lens baseline (Gaussian PSFs of the same EFL, F-number and pixels); the
`aberrations` effect swaps in the real lens's PSFs (aberration-aware training); the other effects add what a
real camera adds. Frames come out in linear units where 1.0 is the sensor's white level.

`device` (training.devices.select): the layered renderer (the FFT convolutions, the bulk of the work) runs
there, under torch's default-device context, so every tensor the shared algorithm creates lands on it; PSF
sources answer on the CPU and their kernels are copied over; the effects' numpy hooks and the returned frames
are on the CPU.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from aat_deploy.lens.io import load_lens
from aat_deploy.lens.schema import Lens
from aat_deploy.optics.focus_table import FocusTable
from aat_deploy.render import effects as fx
from aat_deploy.render.optical import optical_stack
from training.devices.select import resolve_device
from training.psf.geometry import DEFAULT_NEAR_M
from training.render.layered import LayeredConfig
from training.render.sources import OnnxPSF, RayTracedPSF, thin_lens_source


@dataclass
class SimulatorConfig:
    """lens: lens file. psf: exported surrogate (.onnx) for the lens's PSFs, or null to ray-trace them.
    effects: names or {"name": ..., params} (see `aat-render --list-effects`)."""

    lens: str
    psf: str | None = None
    effects: list = field(default_factory=list)
    layered: LayeredConfig = field(default_factory=LayeredConfig)
    n_rays: int = 1024

    @classmethod
    def from_dict(cls, d: dict) -> SimulatorConfig:
        d = dict(d)
        if "layered" in d:
            d["layered"] = LayeredConfig(**d["layered"])
        return cls(**d)


@dataclass
class Stack:
    frames: torch.Tensor  # (S, C, H, W) linear, 1.0 = white level
    focus_m: np.ndarray  # (S,) true focus distances, m from the sensor
    focus_reported_m: np.ndarray  # (S,) what the metadata says (differs only with metadata effects)


def near_focus_table(lens_source) -> FocusTable | None:
    """The surrogate's stamped focus table when it reaches nearer than the traced default's DEFAULT_NEAR_M (a phone
    lens's working range: the default table would refuse its focus distances); else None, so the context traces the
    default table on first use, as it always has (the renders of every 0.2 m+ lens, and their cache keys, stay)."""
    source = getattr(lens_source, "numpy", None)  # an OnnxPSF's torch-free OnnxSource
    table = source.focus_table() if source is not None else None
    if table is None or 1.0 / table.diopters[-1] >= DEFAULT_NEAR_M:
        return None
    return table


class Simulator:
    def __init__(self, lens: Lens, lens_source=None, effects: list | None = None,
                 layered: LayeredConfig = LayeredConfig(), thin_source=None, device: str | torch.device = "cpu"):
        self.lens = lens
        self.device = resolve_device(device)
        self.lens_source = lens_source
        self.thin_source = thin_source or thin_lens_source(lens)
        self.effects = sorted(effects or [], key=lambda e: e.order)
        self.layered = layered

    @classmethod
    def from_config(cls, cfg: SimulatorConfig, root: Path | None = None) -> Simulator:
        root = root or Path(".")
        lens = load_lens(root / cfg.lens)
        src = OnnxPSF(root / cfg.psf, lens) if cfg.psf else RayTracedPSF(lens, n_rays=cfg.n_rays)
        return cls(lens, src, fx.parse(cfg.effects), cfg.layered)

    @property
    def effect_names(self) -> list[str]:
        return [e.name for e in self.effects]

    def context(self, origin=(0, 0), crop_hw=None) -> fx.SimContext:
        s = self.lens.sensor
        return fx.SimContext(self.lens, (s.height_px, s.width_px), tuple(origin), self.lens_source,
                             near_focus_table(self.lens_source))

    def source(self, ctx: fx.SimContext):
        return fx.wrap_source(self.effects, self.thin_source, ctx)

    def render_stack(self, rgb: torch.Tensor, depth_m: torch.Tensor, focus_m, origin=(0, 0),
                     rng: np.random.Generator | None = None) -> Stack:
        """rgb (3, H, W) linear all-in-focus, depth_m (H, W) metres from the sensor (> 0), for the crop whose
        top-left pixel is `origin` = (row, col) on the lens's sensor; focus_m (S,) metres from the sensor."""
        rng = rng or np.random.default_rng()
        focus = np.asarray(focus_m, dtype=np.float64).ravel()
        ctx = self.context(origin)
        frames = self._frames(rgb, depth_m, focus, ctx, rng)
        reported = focus.copy()
        for e in self.effects:
            reported = e.report_focus(reported, ctx, rng)
        return Stack(frames, focus, reported)

    def twin_focus(self, focus_reported_m, ctx: fx.SimContext, rng: np.random.Generator) -> np.ndarray:
        """True focus distances for a digital twin that knows only the reported ones (effects' `twin_focus`)."""
        return fx.twin_focus(self.effects, focus_reported_m, ctx, rng)

    def _frames(self, rgb, depth_m, focus: np.ndarray, ctx: fx.SimContext, rng: np.random.Generator) -> torch.Tensor:
        return self.post(self.optical(rgb, depth_m, focus, ctx), focus, ctx, rng)

    def optical(self, rgb, depth_m, focus: np.ndarray, ctx: fx.SimContext) -> torch.Tensor:
        """Frames (S, C, H, W) through the lens: PSFs and per-field focus, before warps and the sensor (on the CPU,
        rendered on the simulator's device)."""
        if self.device.type == "cpu":
            return optical_stack(self.effects, self.thin_source, rgb, depth_m, focus, ctx, self.layered)
        with self.device:  # tensors the renderer creates land on the device
            frames = optical_stack(self.effects, self.thin_source, rgb.to(self.device), depth_m.to(self.device),
                                   focus, ctx, self.layered)
        return frames.cpu()

    def post(self, frames: torch.Tensor, focus: np.ndarray, ctx: fx.SimContext, rng: np.random.Generator) -> torch.Tensor:
        """The effects' geometry (`warp`), whole-stack (`stack`) then sensor (`sensor`) hooks (`effects.post_stack`).
        The hooks work on numpy (shared with the torch-free twin renderer): one conversion each way per frame."""
        out = fx.post_stack(self.effects, [fr.numpy() for fr in frames], focus, ctx, rng)
        return torch.stack([torch.from_numpy(np.ascontiguousarray(fr)) for fr in out])
