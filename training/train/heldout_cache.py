"""Held-out test stacks rendered once and kept on disk, so every benchmark scores exactly the same stacks.

    from training.train.heldout_cache import HeldoutSpec, heldout_sets
    sets = heldout_sets(HeldoutSpec(lens="lenses/paper_50mm_f2.8.json", psf="models/psf_paper50.onnx"))
    for it in sets["procedural"]: it.stack, it.focus_m, it.depth_m, it.aif

A set is `n_procedural` procedural scenes (items 0..n-1 of a `FocalStackDataset` at the lens's full sensor,
margin 0, seed `seed`, as `benchmarks/bench_dff.py` renders them) plus, optionally, Middlebury 2014 Motorcycle
scaled to cover the sensor (`heldout.rgbd_item`), all with the fixed schedule (`stack_size` distances even in
diopters over `focus_near_m`..`focus_far_m`) and the given simulator. Rendering is deterministic in the spec.

Cache: `<cache_root>/heldout/<key>/<item>.npz` (default cache_root: the repository's `cache/`, or the environment
variable AAT_CACHE). The key hashes the spec (without the item count), the lens's prescription hash, the PSF
surrogate's file hash and `VERSION` (bump it when the rendering code changes what it draws). Items are written
atomically; an unreadable item is rendered again. Stacks are stored as float16 (in [0, 1], 2^-11 relative steps).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
VERSION = 1


@dataclass(frozen=True)
class HeldoutSpec:
    """What a held-out set is: lens file, its PSF surrogate (None = ray-traced), simulator ("aat" = the lens's PSFs,
    "thin_lens" = the Gaussian baseline), scene count and seed, schedule, whether Middlebury Motorcycle is in."""

    lens: str = "lenses/canon_rf50mm_f1.8.json"
    psf: str | None = "models/psf_rf50.onnx"
    simulator: str = "aat"
    n_procedural: int = 24
    seed: int = 777777
    stack_size: int = 8
    focus_near_m: float = 0.5
    focus_far_m: float = 10.0
    middlebury: bool = True
    cell_px: int = 64


@dataclass
class HeldoutItem:
    """One test stack: stack (S, 3, H, W) float32 normalised as the runtime normalises (contract), frames near to
    far; focus_m (S,) metres from the sensor; depth_m (H, W) float32 metres, 0 = unknown; aif (3, H, W) float32
    all-in-focus in the stack's normalised units."""

    name: str
    stack: np.ndarray
    focus_m: np.ndarray
    depth_m: np.ndarray
    aif: np.ndarray

    def as_tuple(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(stack, focus_m, depth_m): `training.train.heldout.Item`, for `evaluate_model`."""
        return self.stack, self.focus_m, self.depth_m


def _resolve(p: str | None) -> Path | None:
    if p is None:
        return None
    q = Path(p)
    return q if q.is_absolute() or q.exists() else ROOT / q


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def spec_key(spec: HeldoutSpec) -> str:
    """Content hash of a set (12 hex): spec without the item count, lens prescription, PSF file, VERSION."""
    from training.lens.io import load_lens

    d = asdict(spec)
    d.pop("n_procedural")
    d.pop("middlebury")
    d["lens"] = load_lens(_resolve(spec.lens)).prescription_hash()
    d["psf"] = _file_sha256(_resolve(spec.psf)) if spec.psf else None
    d["version"] = VERSION
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]


def cache_dir(spec: HeldoutSpec, cache_root: str | Path | None = None) -> Path:
    root = Path(cache_root or os.environ.get("AAT_CACHE") or ROOT / "cache")
    return root / "heldout" / spec_key(spec)


def _dataset(spec: HeldoutSpec):
    from training.data.stacks import FocalStackDataset, StackDataConfig
    from training.lens.io import load_lens

    s = load_lens(_resolve(spec.lens)).sensor
    cfg = StackDataConfig(simulator=spec.simulator, lens=str(_resolve(spec.lens)),
                          psf=str(_resolve(spec.psf)) if spec.psf else None, height=s.height_px, width=s.width_px,
                          stack_size=spec.stack_size, focus_near_m=spec.focus_near_m, focus_far_m=spec.focus_far_m,
                          n_items=max(spec.n_procedural, 1), seed=spec.seed, margin_px=0, cell_px=spec.cell_px)
    return FocalStackDataset(cfg)


def _render(spec: HeldoutSpec, name: str, ds) -> HeldoutItem:
    from training.train.heldout import render_rgbd

    if name == "middlebury":
        from training.data.rgbd import load_middlebury_motorcycle

        r = render_rgbd(ds, *load_middlebury_motorcycle())
    else:
        r = ds.render(int(name.split("_")[1]))
    return HeldoutItem(name, r["stack"].astype(np.float32), np.asarray(r["focus_m"], np.float32),
                       np.asarray(r["depth_m"], np.float32), np.asarray(r["aif"], np.float32))


def _load(f: Path, name: str) -> HeldoutItem | None:
    try:
        with np.load(f) as z:
            return HeldoutItem(name, z["stack"].astype(np.float32), z["focus_m"].astype(np.float32),
                               z["depth_m"].astype(np.float32), z["aif"].astype(np.float32))
    except Exception:  # noqa: BLE001 (a torn or foreign file: render it again)
        return None


def _save(f: Path, it: HeldoutItem) -> None:
    f.parent.mkdir(parents=True, exist_ok=True)
    tmp = f.with_name(f".{f.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, stack=it.stack.astype(np.float16), focus_m=it.focus_m, depth_m=it.depth_m,
             aif=it.aif.astype(np.float16))
    tmp.replace(f)


def item_names(spec: HeldoutSpec) -> dict[str, list[str]]:
    names = {"procedural": [f"procedural_{i:04d}" for i in range(spec.n_procedural)]}
    if spec.middlebury:
        names["middlebury"] = ["middlebury"]
    return names


def iter_items(spec: HeldoutSpec, set_name: str, cache_root: str | Path | None = None,
               progress: bool = True) -> Iterator[HeldoutItem]:
    """The items of one set ("procedural" or "middlebury"), from the cache or rendered (and cached) one by one,
    so a caller never holds more than one stack it does not keep."""
    folder = cache_dir(spec, cache_root)
    ds = None
    names = item_names(spec)[set_name]
    for k, name in enumerate(names):
        f = folder / f"{name}.npz"
        it = _load(f, name) if f.is_file() else None
        if it is None:
            ds = ds or _dataset(spec)
            it = _render(spec, name, ds)
            _save(f, it)
            if progress:
                print(f"  rendered {set_name} {k + 1}/{len(names)} -> {f}", flush=True)
        yield it


def heldout_sets(spec: HeldoutSpec, cache_root: str | Path | None = None,
                 progress: bool = True) -> dict[str, list[HeldoutItem]]:
    """{"procedural": [...], "middlebury": [...]} (Middlebury only if `spec.middlebury`), all in memory."""
    return {s: list(iter_items(spec, s, cache_root, progress)) for s in item_names(spec)}
