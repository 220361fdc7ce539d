"""Focal-stack training data rendered on the fly: (stack, focus distances, depth, all-in-focus).

Each item is a random crop placed anywhere on the full sensor; the crop is rendered with the PSFs of its true
field position (the simulator gets the crop's origin). A margin around the crop is rendered and dropped so that
light from outside the crop comes in as it would on the sensor. Items are deterministic in (seed, index), so the
AAT and thin-lens datasets of one config show the same scenes, crops and focus distances: only the simulator
differs. Rendered items can be cached on disk (`cache_dir`), as rendering costs more than a small net's step.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from aat_deploy.gt.holes import fill_holes
from aat_deploy.infer.normalise import normalise_scale, scaled
from aat_deploy.lens.io import load_lens
from aat_deploy.optics.field import pixel_fields
from aat_deploy.render import effects as fx
from training.data.cache import check_sources, item_path, renderer_marks, save_item
from training.data.rgbd import load_middlebury_motorcycle
from training.data.scenes import SceneConfig, procedural_scene
from training.render.layered import LayeredConfig
from training.render.schedule import FocusSchedule, scene_range_distances
from training.render.simulator import Simulator
from training.render.sources import OnnxPSF, RayTracedPSF

ROOT = Path(__file__).resolve().parents[2]
SIMULATORS = ("aat", "thin_lens")


@dataclass(frozen=True)
class StackDataConfig:
    """simulator: "aat" (the lens's PSFs) or "thin_lens" (Gaussian baseline); effects: extra effect names.
    psf: the lens's surrogate (.onnx; null = ray-trace, slow). height, width: crop (px). Focus schedule:
    stack_size distances even in diopters over [focus_near_m, focus_far_m], jittered by up to jitter_d.
    scene: "procedural" (depths in [scene_near_m, scene_far_m]) or "middlebury".

    Richer data (all off by default, so older configs render and hash as before):
    scene_range: "fixed" (every scene spans [scene_near_m, scene_far_m]) or "random" (a random sub-range in
    diopters per item, the whole range with probability 0.3). photo_fraction: chance that a surface is textured
    with a real photograph of `photo_split` (training.data.textures). schedule: "fixed" (the camera-like schedule
    above), "scene" (the paper's protocol: linear in depth over the item's own depth range, perturbed by up to
    scene_perturb of the spacing; it reads the ground truth) or "mixed" (scene with probability
    scene_schedule_fraction). crop_height, crop_width: when set, __getitem__ returns a random crop of that size
    from the rendered (cached) item, mirrored at random when `flips` (its field coordinates mirrored with it, as
    a rotationally symmetric lens's PSFs are). Every item carries "field_xy" (2, H, W): the normalised sensor
    position of each pixel (x right, y up, +-1 at the sensor edges; aat_deploy.optics.field)."""

    simulator: str = "aat"
    lens: str = "lenses/canon_rf50mm_f1.8.json"
    psf: str | None = "models/psf_rf50.onnx"
    effects: tuple = ()
    height: int = 128
    width: int = 128
    stack_size: int = 8
    focus_near_m: float = 0.5
    focus_far_m: float = 10.0
    jitter_d: float = 0.0
    scene: str = "procedural"
    scene_near_m: float = 0.5
    scene_far_m: float = 10.0
    n_items: int = 1000
    seed: int = 0
    margin_px: int = 16
    cell_px: int = 32
    cache_dir: str | None = None
    scene_range: str = "fixed"
    photo_fraction: float = 0.0
    photo_split: str = "train"
    schedule: str = "fixed"
    scene_schedule_fraction: float = 0.5
    scene_perturb: float = 0.25
    crop_height: int = 0
    crop_width: int = 0
    flips: bool = False

    def __post_init__(self):
        if self.simulator not in SIMULATORS:
            raise ValueError(f"simulator must be one of {SIMULATORS}, got {self.simulator!r}")
        if self.scene not in ("procedural", "middlebury"):
            raise ValueError(f"scene must be 'procedural' or 'middlebury', got {self.scene!r}")
        if self.stack_size < 2 or self.height < 8 or self.width < 8:
            raise ValueError("need stack_size >= 2 and a crop of at least 8 x 8 px")
        if self.scene_range not in ("fixed", "random"):
            raise ValueError(f"scene_range must be 'fixed' or 'random', got {self.scene_range!r}")
        if self.schedule not in ("fixed", "scene", "mixed"):
            raise ValueError(f"schedule must be 'fixed', 'scene' or 'mixed', got {self.schedule!r}")
        if not 0.0 <= self.photo_fraction <= 1.0 or not 0.0 <= self.scene_schedule_fraction <= 1.0:
            raise ValueError("photo_fraction and scene_schedule_fraction must be in [0, 1]")
        if (self.crop_height > 0) != (self.crop_width > 0) or self.crop_height > self.height \
                or self.crop_width > self.width:
            raise ValueError(f"crop_height/crop_width must both be set and fit in {self.width}x{self.height}")

    def effect_list(self) -> list:
        return (["aberrations"] if self.simulator == "aat" else []) + list(self.effects)

    def key(self) -> str:
        d = asdict(self)
        d.pop("cache_dir")
        d["n_items"] = None  # item i is the same whatever the dataset length
        for f in ("crop_height", "crop_width", "flips"):
            d.pop(f)  # crops are cut from the cached item when it is read: they do not change what is rendered
        for f in ("scene_range", "photo_fraction", "photo_split", "schedule", "scene_schedule_fraction",
                  "scene_perturb"):
            if d[f] == StackDataConfig.__dataclass_fields__[f].default:
                d.pop(f)  # configs that do not use a field hash as they did before it existed
        d.update(renderer_marks(self.effects))
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]


def _resolve(p: str | None) -> Path | None:
    if p is None:
        return None
    q = Path(p)
    return q if q.is_absolute() or q.exists() else ROOT / q


class FocalStackDataset(Dataset):
    config_class = StackDataConfig

    def __init__(self, cfg: StackDataConfig, device: str = "cpu"):
        """device: where the simulator renders (training.render.simulator; the items come back on the CPU). Not
        part of the data's identity: a cache filled on a GPU differs from a CPU one by float rounding only."""
        self.cfg = cfg
        self.lens = load_lens(_resolve(cfg.lens))
        lens_src = None
        names = {str(e).split(":")[0] for e in cfg.effects}  # 'name:k=v' too
        # chromatic looks for its per-wavelength surrogates next to the lens's (else it ray-traces by itself)
        uses_psf = cfg.simulator == "aat" or "vignetting" in names or ("chromatic" in names and cfg.psf)
        if uses_psf:
            lens_src = (OnnxPSF(_resolve(cfg.psf), self.lens, threads=1) if cfg.psf
                        else RayTracedPSF(self.lens, device=device))
        # the files the items are rendered from, recorded in (and checked against) the cache folder
        self.sources = {"lens": _resolve(cfg.lens), "psf": _resolve(cfg.psf) if uses_psf and cfg.psf else None}
        self._sources_checked = None  # check_sources' answer, once known
        self.sim = Simulator(self.lens, lens_src, fx.parse(cfg.effect_list()), LayeredConfig(cell_px=cfg.cell_px),
                             device=device)
        self.schedule = FocusSchedule(cfg.focus_near_m, cfg.focus_far_m, cfg.stack_size, cfg.jitter_d)
        s = self.lens.sensor
        self.sensor_hw = (s.height_px, s.width_px)
        if cfg.height > s.height_px or cfg.width > s.width_px:
            raise ValueError(f"crop {cfg.width}x{cfg.height} is larger than the sensor {s.width_px}x{s.height_px}")
        self._middlebury = None
        self.cache = Path(cfg.cache_dir) / cfg.key() if cfg.cache_dir else None

    def __len__(self) -> int:
        return self.cfg.n_items

    def _scene_range(self, rng: np.random.Generator) -> tuple[float, float]:
        """Depth range (m) of one procedural scene: the configured one, or with scene_range "random" a random
        sub-range at least 1.5x deep in distance (the whole range with probability 0.3)."""
        c = self.cfg
        if c.scene_range == "fixed":
            return c.scene_near_m, c.scene_far_m
        if rng.random() < 0.3:
            return c.scene_near_m, c.scene_far_m
        lo, hi = np.log(c.scene_near_m), np.log(c.scene_far_m)
        span = rng.uniform(min(np.log(1.5), hi - lo), hi - lo)
        near = float(np.exp(rng.uniform(lo, hi - span)))
        return near, float(near * np.exp(span))

    def _scene(self, rng: np.random.Generator, h: int, w: int):
        c = self.cfg
        if c.scene == "procedural":
            near, far = self._scene_range(rng)
            rgb, depth = procedural_scene(SceneConfig(height=h, width=w, near_m=near, far_m=far,
                                                      photo_fraction=c.photo_fraction,
                                                      photo_split=c.photo_split), rng)
            return rgb, depth, depth
        if self._middlebury is None:
            self._middlebury = load_middlebury_motorcycle()
        rgb, gt = self._middlebury
        if h > rgb.shape[0] or w > rgb.shape[1]:
            raise ValueError(f"middlebury scene is {rgb.shape[1]}x{rgb.shape[0]}, smaller than {w}x{h}")
        r = int(rng.integers(0, rgb.shape[0] - h + 1))
        q = int(rng.integers(0, rgb.shape[1] - w + 1))
        g = gt[r:r + h, q:q + w]
        return rgb[r:r + h, q:q + w], fill_holes(g), g

    def _focus(self, rng: np.random.Generator, gt: np.ndarray) -> np.ndarray:
        """Focus distances (m) of one item: the camera-like schedule or the paper's scene-range protocol."""
        c = self.cfg
        use_scene = c.schedule == "scene" or (c.schedule == "mixed" and rng.random() < c.scene_schedule_fraction)
        if use_scene:
            return scene_range_distances(gt, c.stack_size, rng, c.scene_perturb)
        return self.schedule.distances(rng if c.jitter_d > 0 else None)

    def render(self, index: int) -> dict:
        c = self.cfg
        rng = np.random.default_rng([c.seed, index])
        m = c.margin_px
        h, w = c.height + 2 * m, c.width + 2 * m
        rgb, depth_fill, gt = self._scene(rng, h, w)
        hs, ws = self.sensor_hw
        origin = (int(rng.integers(0, hs - c.height + 1)), int(rng.integers(0, ws - c.width + 1)))
        focus = self._focus(rng, gt[m:m + c.height, m:m + c.width])
        img = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))).float()
        st = self.sim.render_stack(img, torch.from_numpy(depth_fill).float(), focus,
                                   origin=(origin[0] - m, origin[1] - m), rng=rng)
        sl = (slice(m, m + c.height), slice(m, m + c.width))
        frames = st.frames[:, :, sl[0], sl[1]].numpy()
        aif = img[:, sl[0], sl[1]].numpy()
        p = normalise_scale(frames)
        return {"stack": scaled(frames, p),
                "focus_m": st.focus_reported_m.astype(np.float32),
                "depth_m": np.ascontiguousarray(gt[sl]).astype(np.float32),
                "aif": scaled(aif, p),
                "origin": np.array(origin, dtype=np.int64)}

    def __getitem__(self, index: int) -> dict:
        if not 0 <= index < len(self):
            raise IndexError(index)
        item = self._crop(self.load_or_render(index))
        return {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in item.items()}

    def is_cached(self, index: int) -> bool:
        return self.cache is not None and item_path(self.cache, index).is_file()

    def check_sources(self, also_held=()) -> str | None:
        """ValueError when the cache folder was rendered from other lens/PSF files than this config's (the key
        holds their paths only); else how it stands (`training.data.cache.check_sources`: "verified", "recorded"
        or "unverified"; None without a cache). Once per dataset object. also_held: files rendered with the
        folder's items but kept outside it (a test set's real scenes)."""
        if self.cache is not None and self._sources_checked is None:
            self._sources_checked = check_sources(self.cache, self.sources, also_held)
        return self._sources_checked

    def load_or_render(self, index: int) -> dict:
        """Item `index` as numpy arrays, whole (not cropped): from the cache, else rendered (and cached)."""
        item = None
        if self.cache is not None:
            self.check_sources()
            f = item_path(self.cache, index)
            if f.is_file():
                try:
                    with np.load(f) as z:
                        item = {k: z[k] for k in z.files}
                    item["stack"] = item["stack"].astype(np.float32)
                except Exception:
                    item = None  # a torn write: render again
            if item is None:
                item = self.render(index)
                self.cache.mkdir(parents=True, exist_ok=True)
                # atomic: DDP ranks and loader workers may write the same item at once; byte-deterministic, so
                # shards rendered anywhere make the same files (training.data.cache)
                save_item(f, {**item, "stack": item["stack"].astype(np.float16)})
                item["stack"] = item["stack"].astype(np.float16).astype(np.float32)  # as every later read sees it
        else:
            item = self.render(index)
        return item

    def _crop(self, item: dict) -> dict:
        """Add "field_xy"; with crop_height/crop_width cut a random crop (torch's RNG, so a resumed run draws
        the same crops), mirrored at random when `flips`. A mirrored crop is the render of the mirrored scene
        at the mirrored sensor position (the lens is rotationally symmetric), so its field coordinates flip sign."""
        c = self.cfg
        h, w = item["depth_m"].shape
        origin = tuple(int(v) for v in item["origin"])
        out = dict(item)
        if c.crop_height:
            r = int(torch.randint(0, h - c.crop_height + 1, ()))
            q = int(torch.randint(0, w - c.crop_width + 1, ()))
            h, w = c.crop_height, c.crop_width
            origin = (origin[0] + r, origin[1] + q)
            out["stack"] = item["stack"][..., r:r + h, q:q + w]
            out["aif"] = item["aif"][..., r:r + h, q:q + w]
            out["depth_m"] = item["depth_m"][r:r + h, q:q + w]
            out["origin"] = np.array(origin, dtype=np.int64)
        fx_, fy_ = pixel_fields(h, w, self.sensor_hw, origin)
        field = np.stack([fx_, fy_]).astype(np.float32)
        if c.flips:
            flip = torch.randint(0, 2, (2,)).tolist()  # (left-right, up-down)
            for axis, (do, sign_row) in enumerate(zip(flip, (0, 1))):
                if do:
                    ax = -1 if axis == 0 else -2
                    out["stack"] = np.flip(out["stack"], ax)
                    out["aif"] = np.flip(out["aif"], ax)
                    out["depth_m"] = np.flip(out["depth_m"], ax)
                    field = np.flip(field, ax)
                    field[sign_row] = -field[sign_row]
        out["field_xy"] = np.ascontiguousarray(field)
        return out
