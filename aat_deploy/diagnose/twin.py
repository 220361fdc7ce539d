"""Digital twins without torch: a capture's scene (ground-truth depth + an all-in-focus image) rendered the way the
model's training simulator would, at the capture's reported focus distances, optionally with extra effects.

The simulator is rebuilt from the model's metadata (`aat.simulator`: `aat` = the lens's PSFs, i.e. the
`aberrations` effect, or `thin_lens`; plus `aat.effects`), with the effects registry shared with training
(`aat_deploy.render.effects`), the exported PSF surrogate and the layered renderer (`aat_deploy.render`). Effects
that only the torch simulator can render (`chromatic` without per-wavelength surrogates; the lens's PSFs when there
is no surrogate) raise `NeedsTorch`; `training.render.torch_twin.TorchTwinRenderer` (the declared extension
`torch_twin_renderer`) renders those with torch; `aat_deploy.diagnose.session.make_renderer` picks one.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import warnings
from pathlib import Path

import numpy as np

from aat_deploy.diagnose.inputs import CaptureData
from aat_deploy.errors import AatError
from aat_deploy.gt.holes import fill_holes
from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.normalise import normalise_stack
from aat_deploy.lens.schema import Lens
from aat_deploy.optics.focus_table import FocusTable, paraxial_focus_table
from aat_deploy.render import effects as fx
from aat_deploy.render.layered import LayeredConfig
from aat_deploy.render.optical import optical_stack
from aat_deploy.render.sources import GaussianSource, OnnxSource


class TwinError(AatError):
    pass


def model_effects(model: DfFModel) -> list[fx.Effect]:
    """The effects of the simulator the model was trained with (aat -> aberrations, plus `aat.effects`)."""
    sim = model.meta.get("aat.simulator")
    if sim not in ("aat", "thin_lens"):
        raise TwinError(f"{model.path}: metadata aat.simulator is {sim!r}; cannot rebuild its simulator")
    extra = model.meta.get("aat.effects") or []
    return fx.parse((["aberrations"] if sim == "aat" else []) + list(extra))


class TwinRenderer:
    """Renders twins of captures for one model: `render(capture, aif_linear, extra_effects)`.

    lens: the lens the model was trained for, with the model's sensor (`aat_deploy.lens`). psf: the lens's exported
    surrogate (.onnx path or an `OnnxSource`), or None (then only effects that do not need the lens's PSFs render).
    Stacks through the optics are cached (keyed by the scene's content and the optical effects' settings), so
    effects that act only after the optics (noise, focus breathing) and their candidate settings cost no new
    rendering. `renders` counts optical renders (cache misses)."""

    factor = 1  # binning of the sensor (`binned`)
    uses_torch = False  # renders effects that need torch (the training simulator behind it)

    def __init__(self, model: DfFModel, lens: Lens, psf: str | Path | OnnxSource | None = None, cell_px: int = 64,
                 cache_items: int = 256, threads: int | None = 2):
        self.model, self.lens = model, lens
        self.workers = max(1, int(threads or 1))
        self.lens_source = psf if isinstance(psf, OnnxSource) or psf is None else OnnxSource(psf, lens, threads)
        self.thin_source = GaussianSource(lens)
        self.base = model_effects(model)
        self.layered = LayeredConfig(cell_px=cell_px)
        # The lens's focusing for sensor tilt and focus breathing: from the surrogate's metadata.
        table = self.lens_source.focus_table() if self.lens_source is not None else None
        self._table = table if table is not None else self.fallback_focus_table()
        self._exit_pupil = self.lens_source.exit_pupil_z_mm() if self.lens_source is not None else None
        self._cache: dict = {}
        self.cache_items = cache_items
        self.renders = 0

    def binned(self, b: int) -> TwinRenderer:
        """This renderer for the sensor binned b x b (`aat_deploy.diagnose.binned`): the lens's sensor at 1/b of the
        pixels, PSF cells b times smaller, anchors as dense on the sensor, every effect through `Effect.binned`.
        Always the numpy renderer (effects only torch can render are not searched at reduced resolution); its
        own cache. Renders `binned_capture(cap, b)`."""
        from aat_deploy.diagnose.binned import BinnedSource

        if b == 1:
            return self
        r = copy.copy(self)
        r.__class__ = TwinRenderer
        s = self.lens.sensor
        r.lens = dataclasses.replace(self.lens, sensor=s.with_resolution(s.width_px // b, s.height_px // b))
        r.lens_source = BinnedSource(self.lens_source, b) if self.lens_source is not None else None
        r.thin_source = GaussianSource(r.lens)
        r.layered = dataclasses.replace(self.layered, cell_px=max(8, self.layered.cell_px // b))
        r.factor = self.factor * b
        r.base = [x for x in (e.binned(b) for e in self.base) if x is not None]
        r._cache, r.renders = {}, 0
        return r

    def fallback_focus_table(self) -> FocusTable | None:
        """The focus table when the surrogate has none (older export, or no surrogate): the paraxial one, which
        misses the lens's spherical aberration, with a warning."""
        warnings.warn(f"{getattr(self.lens_source, 'path', 'no PSF surrogate')}: no real-ray focus table; sensor "
                      "tilt and focus breathing use the paraxial one (stamp the surrogate with "
                      "aat-lens focus-map LENS --stamp PSF.onnx)", stacklevel=3)
        return paraxial_focus_table(self.lens)

    def context(self, capture: str = "") -> fx.SimContext:
        s = self.lens.sensor
        return fx.SimContext(self.lens, (s.height_px, s.width_px), (0, 0), self.lens_source, self._table,
                             self._exit_pupil, capture)

    def why_torch(self, effects: list[fx.Effect]) -> str | None:
        """Why these effects need the torch simulator, or None when numpy renders them."""
        ctx = self.context()
        for e in effects:
            why = e.torch_reason(ctx)
            if why:
                return f"effect {e.name!r} needs the training package (torch): {why}"
            if e.uses_lens_psfs and self.lens_source is None:
                return (f"effect {e.name!r} needs the lens's PSFs and there is no PSF surrogate: ray tracing needs "
                        "the training package (torch)")
        return None

    def optical(self, effects: list[fx.Effect], rgb: np.ndarray, depth_m: np.ndarray, focus_m: np.ndarray,
                ctx: fx.SimContext) -> np.ndarray:
        """Frames (S, C, H, W) float32 through the lens (PSFs, per-field focus) for rgb (C, H, W) linear, depth_m
        (H, W) metres from the sensor (> 0) and true focus distances focus_m (S,) in metres."""
        why = self.why_torch(effects)
        if why:
            raise fx.NeedsTorch(why)
        return optical_stack(effects, self.thin_source, rgb, depth_m, focus_m, ctx, self.layered, self.workers)

    def render(self, cap: CaptureData, aif_linear: np.ndarray, extra: list[fx.Effect], seed: int = 0) -> np.ndarray:
        """Normalised twin stack (S, 3, H, W) for a capture whose metadata says cap.focus_m. aif_linear (3, H, W)
        is scaled to the capture's raw level first (noise depends on the absolute signal)."""
        return normalise_stack(np.clip(self.linear(cap, aif_linear, extra, seed), 0, None))

    def linear(self, cap: CaptureData, aif_linear: np.ndarray, extra: list[fx.Effect], seed: int = 0,
               focus_true_m: np.ndarray | None = None) -> np.ndarray:
        """The twin's frames (S, 3, H, W) in linear RAW units, before the stack normalisation: at the focus the
        effects' `twin_focus` makes of cap.focus_m, or at focus_true_m (m, any number of frames: focus sweeps;
        then effects with per-frame settings (`stack` hooks) are the caller's business)."""
        if self.factor > 1:
            extra = [x for x in (e.binned(self.factor) for e in extra) if x is not None]
        effects = sorted(self.base + list(extra), key=lambda e: e.order)
        ctx, rng = self.context(cap.name), np.random.default_rng(seed)
        focus = fx.twin_focus(effects, cap.focus_m, ctx, rng) if focus_true_m is None else \
            np.asarray(focus_true_m, np.float64).ravel()
        scale = np.percentile(cap.frames, 99.5) / max(float(np.percentile(aif_linear, 99.5)), 1e-6)
        optical = [e for e in effects if not fx.is_post(e)]
        h = hashlib.sha1()
        for a in (cap.gt_m, aif_linear, focus, np.float64(scale)):
            h.update(np.ascontiguousarray(a).tobytes())
        key = (h.hexdigest(), tuple(fx.spec(e) for e in optical))
        frames = self._cache.get(key)
        if frames is None:
            gt = np.where(np.isfinite(cap.gt_m), cap.gt_m, 0).astype(np.float32)
            rgb = np.ascontiguousarray(aif_linear * scale, dtype=np.float32)
            frames = self.optical(optical, rgb, fill_holes(gt), focus, ctx)
            self.renders += 1
            if len(self._cache) >= self.cache_items:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = frames
        return fx.post_stack(effects, frames, focus, ctx, rng)

    def true_focus(self, cap: CaptureData, extra: list[fx.Effect], seed: int = 0) -> np.ndarray:
        """The focus distances (m) a twin of `cap` with these extra effects assumes (their `twin_focus`)."""
        effects = sorted(self.base + list(extra), key=lambda e: e.order)
        return fx.twin_focus(effects, cap.focus_m, self.context(cap.name), np.random.default_rng(seed))

    @staticmethod
    def has_stack_hook(effect: fx.Effect) -> bool:
        """Whether the effect acts on the whole stack at once (settings per frame)."""
        return type(effect).stack is not fx.Effect.stack

    @staticmethod
    def spec(effect: fx.Effect) -> str:
        return fx.spec(effect)

    def focus_range_m(self) -> tuple[float, float]:
        """The focus distances (m) the lens's PSFs are known for (the surrogate's range; else 0.05-100 m)."""
        src = getattr(self.lens_source, "source", self.lens_source)
        model = getattr(src, "model", None)
        return tuple(float(v) for v in model.focus_range_m) if model is not None else (0.05, 100.0)

    def focus_table(self) -> FocusTable:
        """The lens's focus table the effects use (sensor z vs diopters)."""
        return self.context().focus_table()
