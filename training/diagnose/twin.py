"""Digital twins: a capture's scene (ground-truth depth + an all-in-focus image) rendered by the simulator a
model was trained with, at the capture's reported focus distances, optionally with extra effects."""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import torch

from aat_deploy.diagnose.inputs import CaptureData
from aat_deploy.model import DfFModel
from aat_deploy.normalise import normalise_stack
from training.data.rgbd import fill_depth
from training.lens.io import load_lens
from training.lens.schema import Lens
from training.render import effects as fx
from training.render.layered import LayeredConfig
from training.render.simulator import Simulator
from training.render.sources import OnnxPSF, RayTracedPSF

ROOT = Path(__file__).resolve().parents[2]


class TwinError(ValueError):
    pass


def model_effects(model: DfFModel) -> list[fx.Effect]:
    """The effects of the simulator the model was trained with (aat -> aberrations, plus `aat.effects`)."""
    sim = model.meta.get("aat.simulator")
    if sim not in ("aat", "thin_lens"):
        raise TwinError(f"{model.path}: metadata aat.simulator is {sim!r}; cannot rebuild its simulator")
    extra = model.meta.get("aat.effects") or []
    return fx.parse((["aberrations"] if sim == "aat" else []) + list(extra))


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


class TwinRenderer:
    """Renders twins of captures for one model: `render(capture, aif_linear, extra_effects)`.

    Stacks through the optics are cached (keyed by the scene's content and the optical effects' settings), so
    effects that act only after the optics (noise, focus breathing) and their candidate settings cost no new
    rendering."""

    def __init__(self, model: DfFModel, lens: Lens, lens_source, cell_px: int = 64, cache_items: int = 256):
        self.model, self.lens, self.lens_source = model, lens, lens_source
        self.base = model_effects(model)
        self.layered = LayeredConfig(cell_px=cell_px)
        self._cache: dict = {}
        self.cache_items = cache_items
        self.renders = 0  # optical renders done (cache misses)

    def simulator(self, effects: list[fx.Effect]) -> Simulator:
        return Simulator(self.lens, self.lens_source, effects, self.layered)

    def render(self, cap: CaptureData, aif_linear: np.ndarray, extra: list[fx.Effect], seed: int = 0) -> np.ndarray:
        """Normalised twin stack (S, 3, H, W) for a capture whose metadata says cap.focus_m. aif_linear (3, H, W)
        is scaled to the capture's raw level first (noise depends on the absolute signal)."""
        sim = self.simulator(self.base + list(extra))
        ctx, rng = sim.context(), np.random.default_rng(seed)
        focus = sim.twin_focus(cap.focus_m, ctx, rng)
        scale = np.percentile(cap.frames, 99.5) / max(float(np.percentile(aif_linear, 99.5)), 1e-6)
        optical = [e for e in sim.effects if not fx.is_post(e)]
        h = hashlib.sha1()
        for a in (cap.gt_m, aif_linear, focus, np.float64(scale)):
            h.update(np.ascontiguousarray(a).tobytes())
        key = (h.hexdigest(), tuple(fx.spec(e) for e in optical))
        frames = self._cache.get(key)
        if frames is None:
            gt = np.where(np.isfinite(cap.gt_m), cap.gt_m, 0).astype(np.float32)
            rgb = torch.from_numpy(np.ascontiguousarray(aif_linear * scale, dtype=np.float32))
            frames = self.simulator(optical).optical(rgb, torch.from_numpy(fill_depth(gt)), focus, ctx)
            self.renders += 1
            if len(self._cache) >= self.cache_items:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = frames
        frames = sim.post(frames, focus, ctx, rng)
        return normalise_stack(np.clip(frames.numpy(), 0, None))
