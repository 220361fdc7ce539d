"""PSF datasets: ray-traced once, cached on disk (npz), reused by every fit and benchmark.

Sampling is in diopters: focus uniform in 1/f over [1/far, 1/near]; depth half uniform in 1/d over the same
range, half concentrated near the focus (defocus ~ N(0, 0.3 D)), where aberrations decide the sharpest frame.
Two layouts:
- "field": (x, y) uniform over the sensor (the paper's MLP learns this 4-D map);
- "axis": points on the +y image axis at normalised radius r (rotationally symmetric surrogates rotate them
  into place), traced on the half-cell grid (oversample 2).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from aat_deploy.io.atomic import atomic_file
from aat_deploy.lens.schema import Lens
from aat_deploy.psf.kernel import KernelSpec
from training.psf.geometry import focus_table_reaching
from training.psf.raytrace import DEFAULT_WAVELENGTH_NM, raytrace_psfs

DEFAULT_CACHE = Path(os.environ.get("AAT_CACHE", Path(__file__).resolve().parents[2] / "cache"))


@dataclass(frozen=True)
class PSFDataConfig:
    layout: str = "field"  # "field" or "axis"
    n: int = 100_000
    near_m: float = 0.3  # depth and focus range, metres from the sensor
    far_m: float = 20.0
    n_rays: int = 2048
    wavelength_nm: float = DEFAULT_WAVELENGTH_NM
    center_wavelength_nm: float | None = None  # kernels centred on this wavelength's chief ray (None: their own)
    kernel_size: int = 11
    margin_px: float = 4.0
    near_focus_fraction: float = 0.5
    near_focus_sigma_d: float = 0.3
    seed: int = 0

    def key(self, lens: Lens) -> str:
        # Unset options stay out of the key, so datasets cached before an option existed keep their names.
        blob = json.dumps({"lens": lens.prescription_hash(), **{k: v for k, v in asdict(self).items() if v is not None}},
                          sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]


def sample_inputs(lens: Lens, cfg: PSFDataConfig) -> dict[str, np.ndarray]:
    """Random (x, y, depth_m, focus_m) following the config (deterministic for a seed)."""
    rng = np.random.default_rng(cfg.seed)
    n = cfg.n
    lo, hi = 1.0 / cfg.far_m, 1.0 / cfg.near_m
    inv_f = rng.uniform(lo, hi, n)
    inv_d = rng.uniform(lo, hi, n)
    near = rng.random(n) < cfg.near_focus_fraction
    inv_d[near] = np.clip(inv_f[near] + rng.normal(0.0, cfg.near_focus_sigma_d, near.sum()), lo, hi)
    if cfg.layout == "field":
        x, y = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
        r = None
    elif cfg.layout == "axis":
        r = rng.uniform(0.0, 1.0, n)
        x = np.zeros(n)
        y = r * lens.sensor.half_diagonal_mm / (lens.sensor.height_mm / 2)
    else:
        raise ValueError(f"unknown layout {cfg.layout!r}")
    out = {"x": x, "y": y, "depth_m": 1.0 / inv_d, "focus_m": 1.0 / inv_f}
    if r is not None:
        out["r"] = r
    return out


def _atomic_savez(path: Path, **arrays) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)


def build_psf_dataset(lens: Lens, cfg: PSFDataConfig, cache_dir: Path | None = None, compiled: bool = True,
                      chunk: int = 2048, progress: bool = True, device: str = "cpu") -> dict[str, np.ndarray]:
    """Trace (or load from the cache) a PSF dataset, on `device` (raytrace_psfs). Resumes part-built datasets
    chunk by chunk."""
    cache_dir = Path(cache_dir or DEFAULT_CACHE) / "psf"
    path = cache_dir / f"{cfg.layout}_{cfg.key(lens)}.npz"
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    t_start = time.perf_counter()
    inp = sample_inputs(lens, cfg)
    spec = KernelSpec.for_lens(lens, cfg.kernel_size, cfg.margin_px)
    over = 2 if cfg.layout == "axis" else 1
    k = spec.size if over == 1 else 2 * spec.size + 1
    table = focus_table_reaching(lens, cfg.near_m)  # the sensor positions of the whole focus range
    parts_dir = cache_dir / f"{path.stem}.parts"
    parts_dir.mkdir(parents=True, exist_ok=True)
    kernels = np.zeros((cfg.n, k, k), np.float32)
    energy, scale = np.zeros(cfg.n, np.float32), np.zeros(cfg.n, np.float32)
    starts = range(0, cfg.n, chunk)
    for i, s0 in enumerate(tqdm(starts, desc=f"tracing {cfg.n} PSFs ({cfg.layout})", disable=not progress)):
        part = parts_dir / f"{i:05d}.npz"
        sl = slice(s0, min(s0 + chunk, cfg.n))
        if part.exists():
            with np.load(part) as z:
                kernels[sl], energy[sl], scale[sl] = z["kernels"], z["energy"], z["scale"]
            continue
        b = raytrace_psfs(lens, inp["x"][sl], inp["y"][sl], inp["depth_m"][sl], inp["focus_m"][sl], spec,
                          n_rays=cfg.n_rays, wavelength_nm=cfg.wavelength_nm, seed=cfg.seed * 100003 + i,
                          compiled=compiled, chunk=256, oversample=over, table=table,
                          center_wavelength_nm=cfg.center_wavelength_nm, device=device)
        kernels[sl], energy[sl], scale[sl] = b.kernels.numpy(), b.energy, b.scale
        _atomic_savez(part, kernels=kernels[sl], energy=energy[sl], scale=scale[sl])
    data = {**{k_: v.astype(np.float32) for k_, v in inp.items()}, "kernels": kernels, "energy": energy,
            "scale": scale, "config": np.array(json.dumps(asdict(cfg))),
            # tracing wall time (s), kept so cached reruns still report what building the data cost
            "build_seconds": np.array(time.perf_counter() - t_start)}
    _atomic_savez(path, **data)
    for p in parts_dir.glob("*.npz"):
        p.unlink()
    parts_dir.rmdir()
    return data


def eval_grid(lens: Lens, n_focus: int = 20, n_depth: int = 40, n_rows: int = 8, n_cols: int = 10,
              near_m: float = 0.3, far_m: float = 20.0) -> dict[str, np.ndarray]:
    """The paper's PSF evaluation grid: focus x depth (both even in diopters) x rows x cols field positions
    (cell centres of an n_rows x n_cols grid over the sensor). Flattened, focus-major."""
    from aat_deploy.optics.focus_table import diopter_grid

    f = diopter_grid(near_m, far_m, n_focus)
    d = diopter_grid(near_m, far_m, n_depth)
    ys = 1 - (2 * np.arange(n_rows) + 1) / n_rows
    xs = -1 + (2 * np.arange(n_cols) + 1) / n_cols
    F, D, Y, X = np.meshgrid(f, d, ys, xs, indexing="ij")
    return {"x": X.ravel(), "y": Y.ravel(), "depth_m": D.ravel(), "focus_m": F.ravel()}


def to_tensors(data: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    return {k: torch.from_numpy(np.asarray(v)) for k, v in data.items() if k not in ("config", "build_seconds")}
