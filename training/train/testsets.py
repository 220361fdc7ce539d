"""Held-out test sets for the DfF tables, rendered once and cached by content (the paper's Table 2 on our lenses).

A test set is whole-sensor stacks rendered through one lens with its PSFs (the `aat` simulator): procedural
scenes from their own seed, textured with the held-out photographs (training.data.textures, "test" split) and
random depth ranges, plus the real Middlebury 2014 Motorcycle scene scaled to cover the sensor (and with `nyu` the
real indoor NYU Depth V2 frame 0045); optionally with
capture effects on top (`effects`: sensor noise, vignetting, RAW development...), to test the nets on stacks that
look like a camera's rather than the simulator's. Two focus
protocols:
- "fixed": the camera-like schedule, `stack_size` distances even in diopters over [focus_near_m, focus_far_m],
  never looking at the scene;
- "paper": the paper's (Yang et al. 2023, Sec. 5.1), distances linear in depth over each image's own ground-truth
  depth range with a random perturbation (seeded). It lets ground truth choose the focus distances: results
  under it are labelled so.
Items are cached under `cache_dir` by a hash of everything that defines them (procedural items through
FocalStackDataset's own cache), so every benchmark (bench_table2, the classical focus method's) scores exactly
the same stacks.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

PROTOCOLS = ("fixed", "paper")
# The lenses the DfF tables test on, by the short name benchmarks/ use: lens file, PSF surrogate (paths from the
# repository root) and the frames of their Table 2 stacks.
LENSES = {
    "paper50": {"lens": "lenses/paper_50mm_f2.8.json", "psf": "models/psf_paper50.onnx", "stack_size": 10},
    "rf50": {"lens": "lenses/canon_rf50mm_f1.8.json", "psf": "models/psf_rf50.onnx", "stack_size": 8},
}


@dataclass(frozen=True)
class TestSetSpec:
    lens: str
    psf: str | None
    stack_size: int
    protocol: str = "fixed"
    n_procedural: int = 32
    seed: int = 777777
    focus_near_m: float = 0.5
    focus_far_m: float = 10.0
    photo_fraction: float = 0.5
    scene_range: str = "random"
    middlebury: bool = True
    simulator: str = "aat"
    cell_px: int = 64
    effects: tuple = ()  # capture effects on top of the simulator (aat_deploy.render.effects names, 'name:k=v')
    photo_split: str = "test"  # "train": validation sets (with their own seed) for choosing settings, never tests
    scene_near_m: float = 0.5  # the procedural scenes' depth range (metres from the sensor)
    scene_far_m: float = 10.0
    nyu: bool = False  # also NYU Depth V2 frame 0045 (../shared/data/rgbd_nyuv2_0045), a real indoor RGB-D scene
    jitter_d: float = 0.0  # "fixed" protocol: each distance moved at random by up to this fraction of the spacing
    registry_real: tuple = ()  # real RGB-D scenes from PyPI packages (training.data.registry_rgbd.SCENES)

    def __post_init__(self):
        if self.protocol not in PROTOCOLS:
            raise ValueError(f"protocol must be one of {PROTOCOLS}, got {self.protocol!r}")
        from training.data.textures import SPLITS

        if self.photo_split not in SPLITS:
            raise ValueError(f"photo_split must be one of {SPLITS}, got {self.photo_split!r}")
        if self.registry_real:
            from training.data.registry_rgbd import SCENES

            unknown = [n for n in self.registry_real if n not in SCENES]
            if unknown:
                raise ValueError(f"registry_real must name scenes of {SCENES}, got {unknown[0]!r}"[:200])

    def key(self) -> str:
        """Hash of what defines the Middlebury item (the procedural items are cached by their dataset's key)."""
        d = asdict(self)
        d.pop("n_procedural")
        if self.photo_split == "test":
            d.pop("photo_split")  # test sets hash (and stay cached) as before the field existed
        if not self.effects:
            d.pop("effects")  # sets without effects hash (and stay cached) as before the field existed
        else:
            from training.data.cache import renderer_marks

            d["effects"] = list(self.effects)
            d.update(renderer_marks(self.effects))
        d["registry_real"] = list(self.registry_real)
        for f, default in (("scene_near_m", 0.5), ("scene_far_m", 10.0), ("nyu", False), ("jitter_d", 0.0),
                           ("registry_real", [])):
            if d[f] == default:
                d.pop(f)  # likewise
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]


@dataclass
class TestItem:
    """One test stack: stack (S, 3, H, W) normalised as the runtime normalises, focus_m (S,) ascending, depth_m
    (H, W) metres from the sensor (0 = unknown), aif (3, H, W) the all-in-focus image in the stack's units."""

    name: str
    stack: np.ndarray
    focus_m: np.ndarray
    depth_m: np.ndarray
    aif: np.ndarray


def _dataset(spec: TestSetSpec, cache_dir: str | None):
    from training.data.stacks import FocalStackDataset, StackDataConfig
    from training.train.data import resolve_lens_path

    lens_path = resolve_lens_path(spec.lens)
    from aat_deploy.lens.io import load_lens

    sensor = load_lens(lens_path).sensor
    cfg = StackDataConfig(simulator=spec.simulator, lens=lens_path, psf=spec.psf, height=sensor.height_px,
                          width=sensor.width_px, stack_size=spec.stack_size, focus_near_m=spec.focus_near_m,
                          focus_far_m=spec.focus_far_m, scene_range=spec.scene_range,
                          scene_near_m=spec.scene_near_m, scene_far_m=spec.scene_far_m, jitter_d=spec.jitter_d,
                          photo_fraction=spec.photo_fraction, photo_split=spec.photo_split,
                          schedule="scene" if spec.protocol == "paper" else "fixed", scene_perturb=0.25,
                          n_items=max(1, spec.n_procedural), seed=spec.seed, margin_px=0, cell_px=spec.cell_px,
                          effects=tuple(spec.effects), cache_dir=cache_dir)
    return FocalStackDataset(cfg)


def _middlebury(spec: TestSetSpec, ds, cache_dir: str | None) -> TestItem:
    """Middlebury Motorcycle scaled to cover the sensor, rendered with the set's simulator and protocol."""
    from training.data.rgbd import load_middlebury_motorcycle

    return _real_rgbd(spec, ds, cache_dir, "middlebury", load_middlebury_motorcycle)


NYU_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "rgbd_nyuv2_0045"


def load_nyu_0045() -> tuple[np.ndarray, np.ndarray]:
    """NYU Depth V2 labelled frame 0045 from ../shared/data (linear RGB, depth m); FileNotFoundError if absent."""
    from training.data.rgbd import load_rgbd

    if not (NYU_DIR / "rgb.png").is_file():
        raise FileNotFoundError(f"{NYU_DIR}: not present (a user's clone has no ../shared/data)")
    return load_rgbd(NYU_DIR / "rgb.png", NYU_DIR / "depth_1e-4m.png", depth_scale_m=1e-4)


def _real_rgbd(spec: TestSetSpec, ds, cache_dir: str | None, name: str, loader) -> TestItem:
    """A real RGB-D scene (loader() -> (linear RGB, depth m)) scaled to cover the sensor, rendered with the set's
    simulator and protocol, cached as <name>_<key>.npz."""
    f = Path(cache_dir) / f"{name}_{spec.key()}.npz" if cache_dir else None
    if f is not None:
        ds.check_sources()  # the set's lens and PSF files, as its procedural items' folder recorded them
    if f is not None and f.is_file():
        with np.load(f) as z:
            return TestItem(name, z["stack"].astype(np.float32), z["focus_m"], z["depth_m"], z["aif"])
    import torch

    from aat_deploy.gt.holes import fill_holes
    from aat_deploy.infer.geometry import fit_rgbd_to_sensor
    from aat_deploy.infer.normalise import normalise_scale, scaled
    from aat_deploy.io.atomic import atomic_file
    from training.render.schedule import scene_range_distances

    rgb, gt = fit_rgbd_to_sensor(*loader(), ds.sensor_hw)
    if spec.protocol == "paper":
        focus = scene_range_distances(gt, spec.stack_size, np.random.default_rng([spec.seed, 1 << 20]), 0.25)
    else:
        focus = ds.schedule.distances()
    img = torch.from_numpy(rgb.transpose(2, 0, 1).copy()).float()
    # seeded: effects that draw (noise) render the same stack every time
    st = ds.sim.render_stack(img, torch.from_numpy(fill_holes(gt)).float(), focus,
                             rng=np.random.default_rng([spec.seed, 1 << 21]))
    frames = st.frames.numpy()
    p = normalise_scale(frames)
    item = TestItem(name, scaled(frames, p), st.focus_m.astype(np.float32), gt.astype(np.float32),
                    scaled(rgb.transpose(2, 0, 1), p))
    if f is not None:
        f.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(f) as tmp:
            np.savez(tmp, stack=item.stack.astype(np.float16), focus_m=item.focus_m, depth_m=item.depth_m,
                     aif=item.aif)
        item.stack = item.stack.astype(np.float16).astype(np.float32)  # as every later read sees it
    return item


def load_test_set(spec: TestSetSpec, cache_dir: str | None = "cache/heldout", progress: bool = True
                  ) -> dict[str, list[TestItem]]:
    """{"procedural": [...], "middlebury": [...]} of `spec`, rendered on first use and cached."""
    from tqdm import tqdm

    ds = _dataset(spec, cache_dir)
    if cache_dir:  # the real scenes' files count as the folder's items: a folder without a record is unverified
        ds.check_sources([Path(cache_dir) / f"{n}_{spec.key()}.npz"
                          for n, on in (("middlebury", spec.middlebury), ("nyu", spec.nyu),
                                        *((r, True) for r in spec.registry_real)) if on])
    out: dict[str, list[TestItem]] = {"procedural": []}
    kind = "validation" if spec.photo_split == "train" else "test"
    for i in tqdm(range(spec.n_procedural), desc=f"{kind} set {spec.protocol}", disable=not progress, unit="stack"):
        it = ds.load_or_render(i)
        out["procedural"].append(TestItem(f"procedural_{i:03d}", it["stack"].astype(np.float32), it["focus_m"],
                                          it["depth_m"], it["aif"]))
    if spec.middlebury:
        out["middlebury"] = [_middlebury(spec, ds, cache_dir)]
    if spec.nyu:
        out["nyu"] = [_real_rgbd(spec, ds, cache_dir, "nyu", load_nyu_0045)]
    if spec.registry_real:
        from training.data.registry_rgbd import LOADERS

        for name in spec.registry_real:
            out[name] = [_real_rgbd(spec, ds, cache_dir, name, LOADERS[name])]
    return out
