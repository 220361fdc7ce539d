"""chromatic: colour from PSFs at three wavelengths (longitudinal and lateral colour, per-channel aberrations).

The sensor stays where the camera focuses it at the design wavelength, so each channel's focus shift shows up as
defocus; each channel's kernel is centred on the design wavelength's chief ray, so lateral colour shows up as a
shift. The per-channel PSFs come from per-wavelength surrogates (`psf_<w>nm.onnx`, made by
`aat-train --lens ... --effects chromatic`, stage psf_colour) when there are any, else from the ray tracer
(torch, about 30 s a stack at training sizes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aat_deploy.backend import as_tensor
from aat_deploy.optics.thin_lens import thin_lens_blur_px
from aat_deploy.render.effects import Effect, SimContext, register, torch_extension
from aat_deploy.render.sources import UnitEnergy


def _three_wavelengths(ctx: SimContext, wavelengths_nm: list[float], n_rays: int, compiled: bool, k: int):
    """The ray-traced per-wavelength source (`training.render.chromatic_trace`, a declared extension: torch)."""
    tracer = torch_extension("chromatic_tracer", "effect 'chromatic' without per-wavelength surrogates (ray tracing)")
    return tracer(ctx, wavelengths_nm, n_rays, compiled, k)

REFERENCE_WAVELENGTH_NM = 589.0  # the kernels' centre: the design-wavelength surrogate's chief ray


def surrogate_name(wavelength_nm: float) -> str:
    """File name of the per-wavelength surrogate for `wavelength_nm` (e.g. psf_610nm.onnx)."""
    return f"psf_{float(wavelength_nm):g}nm.onnx"


@register
class Chromatic(Effect):
    name = "chromatic"
    description = ("per-channel PSFs at three wavelengths with the sensor focused at the design wavelength: "
                   "longitudinal colour as defocus, lateral colour as a shift of each channel's kernel (implies "
                   "the lens's aberrations). psfs: 'auto' = per-wavelength surrogates psf_<w>nm.onnx next to "
                   "the lens's surrogate if there, else ray tracing; 'trace'; or a folder holding them")
    order = 10
    defaults = {"wavelengths_nm": [610.0, 540.0, 465.0], "n_rays": 1024, "compiled": False, "psfs": "auto"}

    def __init__(self, **params):
        super().__init__(**params)
        mode = str(self.params["psfs"])
        if mode not in ("auto", "trace"):  # a folder: checked now, so a bad path fails before any rendering
            missing = [surrogate_name(w) for w in self.wavelengths() if not (Path(mode) / surrogate_name(w)).is_file()]
            if missing:
                raise ValueError(f"effect 'chromatic': {mode}: no per-wavelength surrogate {', '.join(missing)} "
                                 "(psfs=auto|trace|FOLDER)")

    @property
    def needs_torch(self) -> str:  # without a context: only a given folder is known to hold surrogates
        return "" if self._folder(None) else "it ray-traces the PSFs at three wavelengths (no per-wavelength surrogates)"

    def torch_reason(self, ctx: SimContext) -> str:
        return "" if self._folder(ctx) else self.needs_torch

    def wavelengths(self) -> list[float]:
        return [float(w) for w in self.params["wavelengths_nm"]]

    def _folder(self, ctx: SimContext | None) -> Path | None:
        """The folder of per-wavelength surrogates to use, or None (trace)."""
        mode = str(self.params["psfs"])
        if mode == "trace":
            return None
        if mode != "auto":
            return Path(mode)  # checked in __init__
        path = getattr(ctx.lens_source, "path", None) if ctx is not None else None
        if path is None:
            return None
        folder = Path(path).parent
        return folder if all((folder / surrogate_name(w)).is_file() for w in self.wavelengths()) else None

    def wrap_source(self, source, ctx: SimContext):
        folder = self._folder(ctx)
        if folder is None:
            return UnitEnergy(_three_wavelengths(ctx, self.wavelengths(), int(self.params["n_rays"]),
                                                 bool(self.params["compiled"]), k=source.k))
        return UnitEnergy(_Surrogates([folder / surrogate_name(w) for w in self.wavelengths()], ctx, source))


class _Surrogates:
    """Source of (N, 3, k, k) kernels from one surrogate per wavelength (numpy or torch, as the wrapped source
    returns: the torch simulator and the torch-free twin renderer share it)."""

    _cache: dict = {}  # (path, mtime, lens hash) -> OnnxSource: each file's session is loaded once per process

    def __init__(self, paths: list[Path], ctx: SimContext, wrapped):
        from aat_deploy.render.sources import OnnxSource

        self.lens = ctx.lens
        self.sources = []
        for p in paths:
            key = (str(Path(p).resolve()), Path(p).stat().st_mtime_ns, ctx.lens.prescription_hash())
            if key not in self._cache:
                src = OnnxSource(p, ctx.lens)
                meta = src.model.meta
                centre = meta.get("aat.center_wavelength_nm")
                if centre is None or abs(float(centre) - REFERENCE_WAVELENGTH_NM) > 1e-6:
                    raise ValueError(f"{p}: not centred on the {REFERENCE_WAVELENGTH_NM:g} nm chief ray "
                                     f"(aat.center_wavelength_nm = {centre}); refit it with stage psf_colour")
                self._cache[key] = src
            self.sources.append(self._cache[key])
        self.spec = self.sources[0].spec
        if any(s.spec != self.spec for s in self.sources) or self.spec.size != wrapped.k:
            raise ValueError(f"{paths[0].parent}: per-wavelength surrogates with different kernel windows")
        self.k = self.spec.size
        k0, _ = wrapped(np.zeros(1), np.zeros(1), np.ones(1), np.ones(1))
        self.torch = not isinstance(k0, np.ndarray)

    def scale(self, depth_m, focus_m):
        return self.spec.scale(self.lens, depth_m, focus_m)

    def blur_px(self, depth_m, focus_m):
        return thin_lens_blur_px(self.lens, depth_m, focus_m)

    def __call__(self, x, y, depth_m, focus_m):
        outs = [s(x, y, depth_m, focus_m) for s in self.sources]
        kernels, scale = np.stack([k for k, _ in outs], 1), outs[0][1]
        if self.torch:
            return as_tensor(kernels), as_tensor(scale)
        return kernels, scale
