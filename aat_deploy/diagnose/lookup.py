"""Find what a twin needs for a model: the lens it was trained for (with the model's sensor) and that lens's
exported PSF surrogate. Torch-free."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from aat_deploy.diagnose.twin import TwinError
from aat_deploy.infer.model import DfFModel
from aat_deploy.lens.io import load_lens
from aat_deploy.lens.schema import Lens
from aat_deploy.render.sources import OnnxSource
from aat_deploy.shipped import shipped_dir


def find_lens(model: DfFModel, lens_path: str | Path | None) -> tuple[Lens, Path]:
    """The lens the model was trained for, with the model's sensor, and its file: `lens_path` or the file in
    lenses/ with the model's aat.lens_name."""
    if lens_path is None:
        name = model.meta.get("aat.lens_name")
        lenses = shipped_dir("lenses")
        for p in sorted(lenses.glob("*.json")) if lenses else []:
            try:
                cand = load_lens(p)
            except Exception:  # a broken file in lenses/ must not stop the search
                continue
            if cand.name == name:
                lens_path = p
                break
        else:
            raise TwinError(f"{model.path}: lens {name!r} not found in the shipped lenses ({lenses}); pass --lens")
    lens = load_lens(lens_path)
    (w_mm, h_mm), (w_px, h_px) = model.meta["aat.sensor_mm"], model.sensor_px
    sensor = dataclasses.replace(lens.sensor, width_mm=float(w_mm), height_mm=float(h_mm),
                                 width_px=int(w_px), height_px=int(h_px))
    return dataclasses.replace(lens, sensor=sensor), Path(lens_path)


def find_surrogate(lens: Lens, psf_path: str | Path | None, threads: int | None = 2) -> OnnxSource | None:
    """The lens's PSF surrogate: the given .onnx (errors if it is not this lens's), else the first
    models/psf_*.onnx fitted for this lens and sensor, else None."""
    if psf_path is not None:
        return OnnxSource(psf_path, lens, threads)
    models = shipped_dir("models")
    for p in sorted(models.glob("psf_*.onnx")) if models else []:
        try:
            return OnnxSource(p, lens, threads)
        except ValueError:  # made for another lens / pixel pitch
            continue
    return None
