"""A PSF surrogate experiment as data: which lens, ranges, datasets and fits (configs/psf_*.json), and the
functions that build its datasets and run its fits. Used by `aat-psf fit` and benchmarks/bench_psf.py."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from aat_deploy.lens.io import load_lens
from aat_deploy.lens.schema import Lens
from aat_deploy.psf.kernel import KernelSpec
from training.psf.dataset import DEFAULT_CACHE, PSFDataConfig, build_psf_dataset, to_tensors
from training.psf.fit import FitConfig, fit, make_model
from training.psf.surrogates import PSFModel

ROOT = Path(__file__).resolve().parents[2]


@dataclass
class PSFExperiment:
    lens: str
    near_m: float = 0.3
    far_m: float = 20.0
    kernel_size: int = 11
    margin_px: float = 4.0
    wavelength_nm: float = 589.0
    center_wavelength_nm: float | None = None  # see PSFDataConfig: for per-wavelength surrogates of one camera
    train_axis: dict = field(default_factory=dict)
    train_field: dict = field(default_factory=dict)
    val: dict = field(default_factory=dict)
    eval: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    fits: dict = field(default_factory=dict)
    source: str = ""

    @staticmethod
    def load(path) -> "PSFExperiment":
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: cannot read experiment config ({e})") from None
        known = set(PSFExperiment.__dataclass_fields__)
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"{path}: unknown keys {sorted(unknown)}")
        return PSFExperiment(**d, source=str(path))

    def lens_obj(self) -> Lens:
        p = Path(self.lens)
        return load_lens(p if p.is_absolute() else ROOT / p)

    def spec(self, lens: Lens) -> KernelSpec:
        return KernelSpec.for_lens(lens, self.kernel_size, self.margin_px)

    def data_config(self, layout: str, part: dict) -> PSFDataConfig:
        return PSFDataConfig(layout=layout, near_m=self.near_m, far_m=self.far_m, kernel_size=self.kernel_size,
                             margin_px=self.margin_px, wavelength_nm=self.wavelength_nm,
                             center_wavelength_nm=self.center_wavelength_nm, **part)

    def datasets(self, lens: Lens, cache_dir=None, compiled=True, device: str = "cpu") -> dict[str, dict]:
        """Train (axis, field) and validation sets as tensors, traced once (on `device`) and cached; with build
        times."""
        out = {}
        for name, layout, part in (("axis", "axis", self.train_axis), ("field", "field", self.train_field),
                                   ("val", "field", self.val)):
            data = build_psf_dataset(lens, self.data_config(layout, part), cache_dir, compiled=compiled,
                                     device=device)
            out[name] = to_tensors(data)
            out[name]["_seconds"] = float(data["build_seconds"])  # tracing time when it was built
        return out

    def run_fit(self, name: str, lens: Lens, data: dict, cache_dir=None, progress: bool = True,
                device: str = "cpu") -> tuple[PSFModel, FitConfig]:
        """Fit surrogate `name` (a key of `fits`; "rot*" = RotPSF on axis data, "paper_mlp*" = PaperMLP on
        field data) on `device`, resuming from its checkpoint."""
        f = dict(self.fits[name])
        kind = "rot" if name.startswith("rot") else "paper_mlp"
        model = make_model(kind, lens, self.spec(lens), self.near_m, self.far_m)
        train = data["axis"] if kind == "rot" else data["field"]
        v = data["val"]
        val = (torch.stack([v["x"], v["y"], v["depth_m"], v["focus_m"]], -1), v["kernels"])
        cfg = fit(model, train, FitConfig(**f), ckpt=self.checkpoint(name, cache_dir, lens), val=val, progress=progress,
                  device=device)
        model.eval()
        return model, cfg

    def checkpoint(self, name: str, cache_dir=None, lens: Lens | None = None) -> Path:
        """Where fit `name` is checkpointed: named after the config file and keyed by what the fit depends on
        (the lens's optics and sensor, the data and the fit settings), so that two configs of the same file
        name, or an edited config, never resume each other's fit."""
        lens = lens or self.lens_obj()
        d = {k: v for k, v in asdict(self).items()
             if k not in ("lens", "source", "eval", "grid", "fits") and v is not None}  # unset: keys unchanged
        blob = json.dumps({"lens": lens.prescription_hash(), "fit": self.fits.get(name), **d}, sort_keys=True)
        key = hashlib.sha256(blob.encode()).hexdigest()[:10]
        return Path(cache_dir or DEFAULT_CACHE) / "psf_fit" / f"{Path(self.source).stem}_{name}_{key}.pt"
