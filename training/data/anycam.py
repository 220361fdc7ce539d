"""Training data for one DfF net on every camera (`dfv_aat`): focal stacks of random cameras with the per-pixel
in-focus diopters and the defocus scale a user of that camera would give the net.

Each item (deterministic in (seed, index), rendered once and cached as float16 linear frames) is:
- a camera: with probability `traced_fraction` the Canon RF50 through its PSF surrogate (real traced PSFs, the
  lens's own best-focus map), else a random camera of `training.data.cameras` (phone to full frame) with cheap
  parametric aberrated PSFs driven by a random best-focus map (`training.render.parametric`) (with probability
  `wide_sweep_fraction` a wide sweep: a large sensor wide open over its scene's depth range, `Sweep`);
- a scene: a room (`training.data.rooms`: floor, walls, furniture in the camera's perspective, textureless and dark
  surfaces) with probability `room_fraction`, else planes and shapes (`training.data.scenes`), depths around the
  camera's sweep;
- a dense sweep of `cameras.RENDER_FRAMES` frames (even in diopters, random, or linear in depth) rendered through
  the camera at the item's place on its sensor.

When read, a training item is cropped (and mirrored: the image and its maps together, which is the mirrored
camera's render; with `crop_sizes` each batch is cropped to one side drawn for it, `batch_crop`); `collate` then
picks, per batch, how many frames and which (any S from 3 to 16, strided, random or phone-like) and applies a
camera's processing to every item with random settings (exposure, misalignment, sensor noise, RAW development, a
phone's JPEG pipeline when the `phone_jpeg` effect exists), then normalises as the runtime does. So the cached
renders serve endless stack sizes, schedules and camera effects.

A batch: "stack" (B, S, 3, H, W) normalised (docs/contracts.md), "focus_diopters" (B, S, H, W) object diopters in
best focus per frame and pixel (1/m from the sensor plane), "defocus_px_per_d" (B, 1, H, W) blur-diameter growth
per diopter of defocus (px), "focus_m" (B, S) the nominal focus distances (m), "depth_m" (B, H, W) ground truth
(m), "aif" (B, 3, H, W) in the stack's units. Validation items (`fixed_subsets`) come whole, their frames and
effects fixed by (seed, index).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from aat_deploy.infer.normalise import normalise_scale, scaled
from training.data import cameras as cams
from training.data.cache import check_sources, item_path, save_item, sources_state
from training.data.rooms import RoomConfig, room_scene
from training.data.scenes import SceneConfig, procedural_scene
from training.render.parametric import Camera, ParametricSource

ROOT = Path(__file__).resolve().parents[2]
TRACED = {"rf50": ("lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx")}
MAX_BLUR_PX = 1000.0  # largest thin-lens blur diameter an item may have (kernels and memory grow with it)
NEAREST_SCENE = 0.85  # scene depths are at least this fraction of the sweep's nearest focus distance
HELD_OUT_LENSES = ("paper_50mm_f2.8", "canon_ef50mm_f1.8", "nikon_z35")  # never in training (TEAM.md)
# 2: parametric PSFs blur about a best focus beyond infinity as the map says (training.render.parametric.FAR_D);
# renders without this number whose map passes FAR_D somewhere (about one in ten) are rendered again
RENDER_VERSION = 2
# the largest S of a small-stack batch (`AnyCamConfig.small_stack_fraction`)
SMALL_STACK_MAX = 5


@dataclass(frozen=True)
class AnyCamConfig:
    """n_items renders of height x width px (+ margin_px rendered and dropped on every side); crop: side of the
    random square crops read for training (0 = the whole render); crop_sizes: sides (px) to draw each batch's
    crops from instead (one side per batch, `collate`; sides over the render's are capped to it); camera_effects:
    apply a camera's processing when reading; fixed_subsets: validation mode (frames and effects fixed per index,
    no crop)."""

    n_items: int = 3000
    seed: int = 0
    height: int = 160
    width: int = 160
    margin_px: int = 16
    crop: int = 128
    flips: bool = True
    room_fraction: float = 0.5
    traced_fraction: float = 0.15
    photo_fraction: float = 0.5
    photo_split: str = "train"
    cell_px: int = 64
    layer_blur_px: float = 1.5
    max_layers: int = 128
    camera_effects: bool = True
    fixed_subsets: bool = False
    cache_dir: str | None = None
    only_cached: bool = False  # read only the items already in the cache (a run started before its data is rendered)
    mosaic: float = 0.0  # chance that a batch's items are laid out 2 x 2 into one image (`collate`)
    # chance that a parametric item is a wide sweep (`cameras.wide_sweep_camera`: APS-C / full frame wide open over
    # the scene's depth range, 16-140 px of blur change); decided apart from the other draws, so every other item
    # is the item of the same index with 0 here (`base_config`) and is read from that config's cache when there
    wide_sweep_fraction: float = 0.0
    wide_max_width_px: int = cams.MAX_WIDTH_PX  # the wide sweeps' finest working resolution (px across)
    # parametric best-focus maps stay within 1 / far_map_floor x the sweep's far focus (`cameras.limit_far_map`;
    # 0: as drawn, maps may pass infinity)
    far_map_floor: float = 0.0
    crop_sizes: tuple[int, ...] = ()
    # renders no larger than the camera's sensor (height x width capped to its rows and columns): at larger render
    # sizes a window on a small working resolution (320 x 240 px phones) would reach past the sensor's corners,
    # where its maps are extrapolated (12 % of the draws are under 256 px tall, a third under 384)
    fit_sensor: bool = False
    # chance that an item gets a camera's processing (with camera_effects): the judged test stacks are clean renders,
    # and the ninth run's late checkpoints, trained on 85 % noisy items, scored worse on clean stacks than on the same
    # stacks processed (docs/training.md, "The ninth run along its steps"); 1 draws nothing (earlier runs' draws)
    processed_fraction: float = 1.0
    # chance that a training batch's S is drawn from 3-5 frames (capped as usual) instead of 3 to the sweep's cap:
    # with S uniform over 3-16 a 3-frame batch is 1 in 14, and the tenth run's nets were worse than the classical
    # method on 3-frame RF50 validation stacks while good on 8-frame ones (docs/training.md); 0 draws nothing
    small_stack_fraction: float = 0.0

    def processes(self, rng: np.random.Generator) -> bool:
        """Whether the item whose draws `rng` makes gets a camera's processing."""
        if not self.camera_effects:
            return False
        return self.processed_fraction >= 1.0 or bool(rng.random() < self.processed_fraction)

    def __post_init__(self):
        object.__setattr__(self, "crop_sizes", tuple(int(v) for v in self.crop_sizes))  # JSON gives a list
        if any(v < 16 for v in self.crop_sizes):
            raise ValueError(f"crop_sizes {list(self.crop_sizes)}: sides of at least 16 px")
        if not 0.0 <= self.processed_fraction <= 1.0:
            raise ValueError(f"processed_fraction {self.processed_fraction}: a chance in [0, 1]")
        if not 0.0 <= self.small_stack_fraction <= 1.0:
            raise ValueError(f"small_stack_fraction {self.small_stack_fraction}: a chance in [0, 1]")

    def key(self) -> str:
        """Hash of what defines the renders (not how they are read)."""
        d = asdict(self)
        for k in ("n_items", "crop", "flips", "camera_effects", "fixed_subsets", "cache_dir", "only_cached", "mosaic",
                  "crop_sizes", "processed_fraction", "small_stack_fraction"):
            d.pop(k)
        if d["max_layers"] == 128:
            d.pop("max_layers")  # the layered renderer's default (renders made before the field hash as before)
        if not d["wide_sweep_fraction"]:
            d.pop("wide_sweep_fraction")  # renders made before it hash as before
        if d["wide_max_width_px"] == cams.MAX_WIDTH_PX:
            d.pop("wide_max_width_px")  # likewise
        if not d["far_map_floor"]:
            d.pop("far_map_floor")
        if not d["fit_sensor"]:
            d.pop("fit_sensor")
        d["version"] = 1
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]

    def base_config(self) -> AnyCamConfig | None:
        """The config whose items this one shares (all but the wide sweeps), or None."""
        return replace(self, wide_sweep_fraction=0.0) if self.wide_sweep_fraction else None

    def donor_configs(self) -> list[AnyCamConfig]:
        """Configs whose cached renders may hold this one's items: the base config, and the same configs without
        the later draw limits (wide_max_width_px, far_map_floor at their defaults). A limit only changes the items
        it touches, so every other item is drawn (and rendered) the same: `AnyCamDataset.is_cached` adopts an
        item from a donor's cache when its draw there is the same (`same_draw`)."""
        legacy = replace(self, wide_max_width_px=cams.MAX_WIDTH_PX, far_map_floor=0.0)
        out = [self.base_config(), None if legacy == self else legacy, None if legacy == self else legacy.base_config()]
        return [c for c in out if c is not None]


@dataclass(frozen=True)
class Sweep:
    """What an item's camera and focus sweep are (`AnyCamDataset.draw_sweep`): the camera (aberrations included
    for parametric ones), the full sensor (H, W) px, the sweep's near and far ends (m), its dense focus distances
    (m, near -> far), the schedule's kind, the camera's description, traced (the RF50) and wide
    (`cameras.wide_sweep_camera`)."""

    cam: Camera
    sensor_hw: tuple[int, int]
    near: float
    far: float
    focus: np.ndarray
    kind: str
    info: dict
    traced: bool
    wide: bool

    def span_px(self) -> float:
        """Total blur change over the sweep (px): the defocus scale the net is told x the sweep's diopters."""
        k = self.cam.defocus_px_per_diopter(float(np.sqrt(self.focus[0] * self.focus[-1])))
        return float(k * (1.0 / self.focus[0] - 1.0 / self.focus[-1]))


def _resolve(p: str) -> Path:
    q = Path(p)
    return q if q.is_absolute() else ROOT / q


class AnyCamDataset(Dataset):
    config_class = AnyCamConfig

    def __init__(self, cfg: AnyCamConfig):
        self.cfg = cfg
        self.cache = Path(cfg.cache_dir) / f"anycam_{cfg.key()}" if cfg.cache_dir else None
        base = cfg.base_config()
        self.base_cache = Path(cfg.cache_dir) / f"anycam_{base.key()}" if base and cfg.cache_dir else None
        self._donors = [AnyCamDataset._bare(d) for d in cfg.donor_configs()] if cfg.cache_dir else []
        self._traced: dict = {}
        self.sources, self._sources_checked, self._donor_state = render_sources(cfg), None, {}
        # with only_cached, position j reads item self.items[j]: the cached ones, as found now
        self.items = [i for i in range(cfg.n_items) if not cfg.only_cached or self.is_cached(i)]
        if not self.items:
            raise ValueError(f"{self.cache}: no cached items (only_cached): render them first")

    @classmethod
    def _bare(cls, cfg: AnyCamConfig) -> AnyCamDataset:
        """A dataset of `cfg` that only draws and names its cache (no item list, no donors of its own)."""
        d = cls.__new__(cls)
        d.cfg, d._traced, d._donors, d.items = cfg, {}, [], []
        d.sources, d._sources_checked, d._donor_state = render_sources(cfg), None, {}
        d.cache = Path(cfg.cache_dir) / f"anycam_{cfg.key()}" if cfg.cache_dir else None
        d.base_cache = None
        return d

    def __len__(self) -> int:
        return len(self.items)

    # -- rendering --------------------------------------------------------------------------------------------
    def _traced_lens(self, name: str):
        if name not in self._traced:
            from aat_deploy.focus.bestfocus import for_lens
            from aat_deploy.lens.io import load_lens
            from aat_deploy.render import effects as fx
            from training.render.layered import LayeredConfig
            from training.render.simulator import Simulator
            from training.render.sources import OnnxPSF

            lens_path, psf_path = TRACED[name]
            lens = load_lens(_resolve(lens_path))
            sim = Simulator(lens, OnnxPSF(_resolve(psf_path), lens, threads=1), fx.parse(["aberrations"]),
                            LayeredConfig(cell_px=self.cfg.cell_px, layer_blur_px=self.cfg.layer_blur_px,
                                          max_layers=self.cfg.max_layers))
            fmap, _ = for_lens(_resolve(lens_path), compute=False)
            self._traced[name] = (lens, sim, fmap)
        return self._traced[name]

    def _scene(self, rng, h, w, f_px, centre_rc, near, far):
        c = self.cfg
        if rng.random() < c.room_fraction:
            return room_scene(rng, h, w, f_px, centre_rc, (near, far),
                              RoomConfig(photo_fraction=0.4 * c.photo_fraction / 0.5, photo_split=c.photo_split))
        return procedural_scene(SceneConfig(height=h, width=w, near_m=near, far_m=far,
                                            photo_fraction=c.photo_fraction, photo_split=c.photo_split), rng)

    def is_wide(self, index: int) -> bool:
        """Whether item `index` is a wide sweep: a parametric item (not the RF50) picked with chance
        wide_sweep_fraction from a stream of its own, so that every other draw stays as with 0."""
        c = self.cfg
        if not c.wide_sweep_fraction or np.random.default_rng([c.seed, index, 35]).random() < c.traced_fraction:
            return False
        return bool(np.random.default_rng([c.seed, index, 36]).random() < c.wide_sweep_fraction)

    def render_priority(self, index: int) -> int:
        """Order in which a renderer makes the missing items (lower first): the wide sweeps, then the others."""
        return 0 if self.is_wide(index) else 1

    def draw_sweep(self, rng: np.random.Generator, index: int) -> Sweep:
        """The camera and focus sweep of item `index`, drawn from its render stream `rng` (which `render` goes on
        reading): the RF50 (traced_fraction), a wide sweep (`is_wide`) or a `cameras.random_camera`."""
        c = self.cfg
        traced = rng.random() < c.traced_fraction
        wide = not traced and self.is_wide(index)
        if traced:
            cam = _traced_camera("rf50")
            sensor_hw = cam.sensor_hw
            info = {"class": "traced", "lens": "rf50"}
            near, far = cams.random_focus_range(rng, 0.35, "full_frame")
            near, far = max(near, 0.3), min(far, 20.0)  # the surrogate's range
        elif wide:
            cam, info, near, far = cams.wide_sweep_camera(rng, c.wide_max_width_px)
            sensor_hw = cam.sensor_hw
        else:
            cam, info = cams.random_camera(rng)
            sensor_hw = cam.sensor_hw
            near, far = cams.random_focus_range(rng, info["min_focus_m"], info["class"],
                                                cam.defocus_px_per_diopter(2.0))
        kind = str(rng.choice(cams.WIDE_SCHEDULES[0], p=cams.WIDE_SCHEDULES[1])) if wide else None
        focus, kind = cams.dense_schedule(rng, near, far, kind=kind)
        spacing = (1 / focus[0] - 1 / focus[-1]) / (len(focus) - 1)
        if not traced:
            ab = cams.random_aberrations(rng, spacing, 0.5 * (1 / near + 1 / far))
            cam = cams.limit_far_map(Camera(cam.focal_mm, cam.f_number, cam.sensor_hw, cam.pixel_mm, ab), focus,
                                     c.far_map_floor)
        return Sweep(cam, tuple(sensor_hw), near, far, focus, kind, info, traced, wide)

    def render_hw(self, sensor_hw) -> tuple[int, int]:
        """(rows, cols) of an item's render: the config's, capped to the camera's sensor with `fit_sensor`."""
        c = self.cfg
        if c.fit_sensor:
            return min(c.height, int(sensor_hw[0])), min(c.width, int(sensor_hw[1]))
        return c.height, c.width

    def render(self, index: int) -> dict:
        """Item `index` (numpy): frames (F, 3, h, w) linear float32, focus_m (F,) near -> far, depth_m (h, w),
        aif (3, h, w) linear, origin (row, col) on the sensor, sensor_hw, and what defines its focus map."""
        import torch as _torch

        from aat_deploy.optics.field import field_of
        from aat_deploy.render.layered import LayeredConfig, render_layered

        c = self.cfg
        rng = np.random.default_rng([c.seed, index, 35])
        m = c.margin_px
        sw = self.draw_sweep(rng, index)
        h, w = self.render_hw(sw.sensor_hw)
        hh, ww = h + 2 * m, w + 2 * m
        cam, sensor_hw, near, far, focus, kind, info, traced = (sw.cam, sw.sensor_hw, sw.near, sw.far, sw.focus,
                                                                sw.kind, sw.info, sw.traced)
        if traced:
            lens, sim, fmap = self._traced_lens("rf50")
        hs, ws = sensor_hw
        origin = (int(rng.integers(0, max(1, hs - h + 1))), int(rng.integers(0, max(1, ws - w + 1))))
        if sw.wide:  # the sweep spans the scene's depth range (the paper's protocol), give or take a little
            s_near = near * float(np.exp(rng.uniform(-0.1, 0.05)))
            s_far = max(far * float(np.exp(rng.uniform(-0.15, 0.1))), s_near * 1.3)
        else:  # scene depths mostly inside the sweep (a user sweeps over the scene), sometimes a little beyond
            s_near = near * float(np.exp(rng.uniform(-0.15, 0.35)))
            s_far = max(far * float(np.exp(rng.uniform(-0.7, 0.15))), s_near * 1.3)
        f_px = cam.focal_mm / cam.pixel_mm
        centre = (hs / 2 - (origin[0] - m), ws / 2 - (origin[1] - m))  # optical axis in the rendered window
        rgb, depth = self._scene(rng, hh, ww, f_px, centre, s_near, s_far)
        img = np.ascontiguousarray(rgb.transpose(2, 0, 1)).astype(np.float32)
        # nothing much nearer than the nearest focus (a room's floor at the camera's feet): blur there is no cue and
        # near a lens's close-focus limit the thin-lens blur explodes (kernels of thousands of px)
        depth = np.ascontiguousarray(np.maximum(depth, NEAREST_SCENE * near)).astype(np.float32)
        worst = float(np.max(cam.blur_px(np.array([depth.min(), depth.max()])[:, None], focus[None, :])))
        if worst > MAX_BLUR_PX:  # a guard: the sweep's limits above keep every item below it
            raise RuntimeError(f"anycam item {index}: a blur of {worst:.0f} px (> {MAX_BLUR_PX:g}); not rendered")
        o = (origin[0] - m, origin[1] - m)
        if traced:
            frames = sim.optical(_torch.from_numpy(img), _torch.from_numpy(depth), focus,
                                 sim.context(o)).numpy()
        else:
            src = ParametricSource(cam, focus)
            cfg = LayeredConfig(cell_px=c.cell_px, layer_blur_px=c.layer_blur_px, max_layers=c.max_layers)
            frames = np.stack([render_layered(img, depth, float(f), src,
                                              lambda r, q: field_of(r, q, sensor_hw, o), cfg) for f in focus])
        sl = (slice(m, m + h), slice(m, m + w))
        info.update({"schedule": kind, "focus_range_m": [near, far]})
        return {"frames": frames[:, :, sl[0], sl[1]].astype(np.float32), "focus_m": focus.astype(np.float64),
                "depth_m": depth[sl].astype(np.float32), "aif": img[:, sl[0], sl[1]],
                "origin": np.array(origin, np.int64), "sensor_hw": np.array(sensor_hw, np.int64),
                "render_version": np.int64(RENDER_VERSION),
                "camera": json.dumps({"focal_mm": cam.focal_mm, "f_number": cam.f_number,
                                      "pixel_mm": cam.pixel_mm, "aberrations": cam.aberrations.to_dict(),
                                      "traced": info.get("lens"), "info": info})}

    def same_draw(self, other: AnyCamDataset, index: int) -> bool:
        """Whether item `index` is drawn the same in `other` (a config of the same renders but for its draw
        limits or wide-sweep share): the same camera, aberrations, sweep and schedule, and the render stream left
        in the same state, so the rest of `render` (origin, scene, frames) is the same, byte for byte."""
        states, sweeps = [], []
        for d in (self, other):
            rng = np.random.default_rng([d.cfg.seed, index, 35])
            sweeps.append(d.draw_sweep(rng, index))
            states.append(rng.bit_generator.state)
        a, b = sweeps
        return (states[0] == states[1] and a.cam == b.cam and a.sensor_hw == b.sensor_hw and a.near == b.near
                and a.far == b.far and np.array_equal(a.focus, b.focus) and a.kind == b.kind and a.info == b.info
                and a.traced == b.traced and a.wide == b.wide)

    def check_sources(self) -> str | None:
        """ValueError (one line, nothing written) when the cache folder's sources.json names other lens/PSF files
        than `render_sources`; else "verified", "recorded" (a new folder) or "unverified" (renders made before the
        record: `training.data.cache.check_sources`); None without a cache. Once per dataset object."""
        if self.cache is not None and self._sources_checked is None:
            self._sources_checked = check_sources(self.cache, self.sources)
        return self._sources_checked

    def _may_adopt(self, donor: AnyCamDataset) -> bool:
        """Whether a donor's renders may be adopted: its record names this config's files, or neither folder has a
        record (unverified renders stay among unverified ones: never into a folder whose record vouches for them)."""
        if donor.cache not in self._donor_state:
            self._donor_state[donor.cache] = sources_state(donor.cache, self.sources)[0]
        state = self._donor_state[donor.cache]
        return state == "verified" or (state == "unverified" and self.check_sources() == "unverified")

    def is_cached(self, index: int) -> bool:
        """The item's render is in the cache and still valid (`stale`). An item this config shares with a donor
        config (`AnyCamConfig.donor_configs`: its `base_config`, whose items are all but the wide sweeps, and the
        same configs without the later draw limits; the same draws, so the same bytes: `same_draw`) found valid in
        that config's cache is adopted first: hard-linked (else copied) into this cache, when the donor's record of
        its sources allows (`_may_adopt`). A cache whose record names other files raises (`check_sources`)."""
        if self.cache is None:
            return False
        self.check_sources()
        f = item_path(self.cache, index)
        for donor in self._donors if not f.is_file() else ():
            b = item_path(donor.cache, index)
            if _valid(b, self.stale) and self._may_adopt(donor) and self.same_draw(donor, index):
                f.parent.mkdir(parents=True, exist_ok=True)
                tmp = f.with_suffix(f".adopt{os.getpid()}.tmp")  # each process its own
                tmp.unlink(missing_ok=True)
                try:
                    os.link(b, tmp)
                except OSError:
                    shutil.copyfile(b, tmp)
                os.replace(tmp, f)
                break
        return f.is_file() and _valid(f, self.stale)

    def stale(self, z) -> bool:
        """A cached render (an open .npz) made before RENDER_VERSION that the current renderer draws otherwise:
        a parametric camera whose best focus (tangential or sagittal) passes parametric.FAR_D in the rendered
        window (margin included), where the old renderer focused at 10 km instead of beyond infinity."""
        if "render_version" in z.files and int(z["render_version"]) >= RENDER_VERSION:
            return False
        from training.render.parametric import FAR_D, Aberrations

        cam_d = json.loads(str(z["camera"]))
        if cam_d.get("traced"):
            return False
        m = self.cfg.margin_px
        h, w = z["depth_m"].shape
        cam = Camera(cam_d["focal_mm"], cam_d["f_number"], tuple(int(v) for v in z["sensor_hw"]),
                     cam_d["pixel_mm"], Aberrations(**cam_d["aberrations"]))
        origin = (int(z["origin"][0]) - m, int(z["origin"][1]) - m)
        from aat_deploy.optics.field import pixel_fields

        fd = cam.frame_diopters(z["focus_m"], h + 2 * m, w + 2 * m, origin)
        x, y = pixel_fields(h + 2 * m, w + 2 * m, cam.sensor_hw, origin)
        half = np.abs(0.5 * cam.aberrations.a2 * cam.radius(x, y) ** 2)
        return bool((fd - half[None]).min() < FAR_D)

    def load_or_render(self, index: int) -> dict:
        """Item `index` whole (numpy): from the cache (or adopted from the base config's: `is_cached`), else
        rendered and cached (frames as float16; the cache's layout and byte-deterministic files of
        `training.data.cache`, so sharded rendering fills it)."""
        f = item_path(self.cache, index) if self.cache is not None else None
        if f is not None:
            self.check_sources()
        if f is not None and (f.is_file() or self.is_cached(index)):
            try:
                with np.load(f) as z:
                    item = None if self.stale(z) else {k: z[k] for k in z.files}
                if item is not None:
                    item["frames"] = item["frames"].astype(np.float32)
                    item["camera"] = str(item["camera"])
                    return item
            except Exception:  # noqa: BLE001 (a torn write: render again)
                pass
        item = self.render(index)
        if f is not None:
            self.cache.mkdir(parents=True, exist_ok=True)
            save_item(f, {**item, "frames": item["frames"].astype(np.float16), "camera": np.asarray(item["camera"])})
            item["frames"] = item["frames"].astype(np.float16).astype(np.float32)  # as every later read sees it
        return item

    # -- the maps a user would give ------------------------------------------------------------------------------
    def focus_maps(self, item: dict, r0: int, c0: int, h: int, w: int) -> tuple[np.ndarray, float]:
        """(F, h, w) float32 in-focus diopters of the window (r0, c0, h, w) of the item, and its defocus scale
        (px per diopter): the camera's own map (parametric) or the lens's best-focus map (traced)."""
        cam_d = json.loads(item["camera"])
        sensor_hw = tuple(int(v) for v in item["sensor_hw"])
        origin = (int(item["origin"][0]) + r0, int(item["origin"][1]) + c0)
        focus = np.asarray(item["focus_m"], np.float64)
        from training.render.parametric import Aberrations

        cam = Camera(cam_d["focal_mm"], cam_d["f_number"], sensor_hw, cam_d["pixel_mm"],
                     Aberrations(**cam_d["aberrations"]))
        k = cam.defocus_px_per_diopter(float(np.sqrt(focus[0] * focus[-1])))
        if cam_d.get("traced"):
            from aat_deploy.optics.field import pixel_fields

            _, _, fmap = self._traced_lens(cam_d["traced"])
            x, y = pixel_fields(h, w, sensor_hw, origin)
            a = sensor_hw[1] / sensor_hw[0]
            r = np.hypot(x * a, y) / np.hypot(a, 1.0)
            return fmap.frame_diopters(focus, r.ravel()).reshape(len(focus), h, w).astype(np.float32), k
        return cam.frame_diopters(focus, h, w, origin), k

    # -- reading ---------------------------------------------------------------------------------------------
    def __getitem__(self, position: int) -> dict:
        if not 0 <= position < len(self):
            raise IndexError(position)
        index = self.items[position]
        item = self.load_or_render(index)
        c = self.cfg
        h, w = item["depth_m"].shape
        if c.fixed_subsets:
            rng = np.random.default_rng([c.seed, index, 77])
            maps, k = self.focus_maps(item, 0, 0, h, w)
            dense = {"frames": item["frames"], "maps": maps, "k": k, "focus_m": item["focus_m"],
                     "depth_m": item["depth_m"], "aif": item["aif"]}
            s = int(rng.integers(cams.S_RANGE[0], cams.max_frames(_span_px(dense)) + 1))
            idx = cams.subset(rng, len(item["focus_m"]), s=s)[0]
            return _to_torch(finish(dense, rng, c.processes(rng), idx))
        r0 = c0 = 0
        crop = min(max(c.crop_sizes), h, w) if c.crop_sizes else c.crop  # variable: `collate` crops further
        if crop:
            r0 = int(torch.randint(0, h - crop + 1, ()))
            c0 = int(torch.randint(0, w - crop + 1, ()))
            h = w = crop
        maps, k = self.focus_maps(item, r0, c0, h, w)
        sl = (slice(r0, r0 + h), slice(c0, c0 + w))
        out = {"frames": item["frames"][:, :, sl[0], sl[1]], "maps": maps, "k": k, "focus_m": item["focus_m"],
               "depth_m": item["depth_m"][sl], "aif": item["aif"][:, sl[0], sl[1]]}
        if c.flips:
            flip = torch.randint(0, 2, (2,)).tolist()
            for do, ax in zip(flip, (-1, -2)):
                if do:
                    for key in ("frames", "maps", "depth_m", "aif"):
                        out[key] = np.flip(out[key], ax)
        out = {k_: (np.ascontiguousarray(v) if isinstance(v, np.ndarray) else v) for k_, v in out.items()}
        out["seed"] = int(torch.randint(0, 2**31 - 1, ()))
        return out

    def collate(self, items: list[dict]) -> dict:
        """One training batch: the same S for every item (drawn here), each item's frames a subset of its sweep,
        its camera's processing applied, normalised; see the module docstring for the keys. With chance
        cfg.mosaic (and a multiple of 4 items of one size) each 4 items become one image of twice the side
        (`mosaic`). With cfg.crop_sizes every item is first cropped to one side drawn for the batch
        (`batch_crop`)."""
        rng = np.random.default_rng(items[0]["seed"])
        cap = cams.max_frames(float(np.median([_span_px(it) for it in items])))  # sweeps of little blur: few frames
        if self.cfg.small_stack_fraction and rng.random() < self.cfg.small_stack_fraction:
            cap = min(cap, SMALL_STACK_MAX)
        s = int(rng.integers(cams.S_RANGE[0], cap + 1))
        if self.cfg.crop_sizes:
            items = batch_crop(items, self.cfg.crop_sizes, np.random.default_rng([items[0]["seed"], 1]))
        out = []
        for it in items:
            r = np.random.default_rng(it["seed"])
            kind = str(r.choice(["stride", "random", "near"], p=[0.5, 0.3, 0.2]))
            idx, _ = cams.subset(r, len(it["focus_m"]), kind, s)
            out.append(finish(it, r, self.cfg.processes(r), idx))
        if (self.cfg.mosaic > 0 and len(out) % 4 == 0 and len({o["depth_m"].shape for o in out}) == 1
                and rng.random() < self.cfg.mosaic):
            out = [mosaic(out[i:i + 4]) for i in range(0, len(out), 4)]
        return {k: torch.stack([torch.from_numpy(np.ascontiguousarray(o[k])) for o in out]) for k in out[0]}


def batch_crop(items: list[dict], sizes, rng: np.random.Generator) -> list[dict]:
    """Items as `AnyCamDataset.__getitem__` reads them (frames (F, 3, h, w), maps (F, h, w), depth_m, aif) cropped to
    one square side drawn from `sizes` for the whole batch (capped to the smallest item), each at a random place:
    a net that runs on large tiles trains on large single scenes, and the batch still stacks."""
    side = min(int(rng.choice(list(sizes))), *(min(it["depth_m"].shape) for it in items))
    out = []
    for it in items:
        h, w = it["depth_m"].shape
        r0, c0 = int(rng.integers(0, h - side + 1)), int(rng.integers(0, w - side + 1))
        sl = (slice(r0, r0 + side), slice(c0, c0 + side))
        out.append({**it, "frames": it["frames"][:, :, sl[0], sl[1]], "maps": it["maps"][:, sl[0], sl[1]],
                    "depth_m": it["depth_m"][sl], "aif": it["aif"][:, sl[0], sl[1]]})
    return out


def mosaic(parts: list[dict]) -> dict:
    """Four finished stacks of one size and S (`finish`) laid out 2 x 2 as one stack of twice the side: every map is
    per pixel, so each quadrant keeps its own camera. The net trains on small renders; laid out like this its
    pixels also lie far from the image's border, as in a whole frame (the first run's net, trained on 128 px images
    only, was 2.4x worse on whole 640 x 480 frames than on 128 px tiles of them). "focus_m" has no single value
    for a mosaic: NaN (the training loss does not read it)."""
    a, b, c, d = parts
    out = {}
    for k in ("stack", "focus_diopters", "defocus_px_per_d", "depth_m", "aif"):
        out[k] = np.concatenate([np.concatenate([a[k], b[k]], -1), np.concatenate([c[k], d[k]], -1)], -2)
    out["focus_m"] = np.full_like(np.asarray(a["focus_m"]), np.nan)
    return out


def render_sources(cfg: AnyCamConfig) -> dict[str, Path]:
    """The lens and PSF files a config's renders read ({"<lens>_lens": path, "<lens>_psf": path} per traced lens;
    none when traced_fraction is 0), recorded in its cache folder (`check_sources`). The parametric cameras read no
    file; a traced lens's best-focus map is read with the items (`focus_maps`), not rendered into them."""
    if not cfg.traced_fraction:
        return {}
    return {f"{name}_{role}": _resolve(p) for name, paths in TRACED.items() for role, p in zip(("lens", "psf"), paths)}


@functools.lru_cache(maxsize=None)
def _traced_camera(name: str) -> Camera:
    """A traced lens's paraxial camera (focal length, f-number, its sensor and pixel pitch)."""
    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.paraxial import paraxial_data

    lens = load_lens(_resolve(TRACED[name][0]))
    p = paraxial_data(lens)
    return Camera(p.efl_mm, p.fno, (lens.sensor.height_px, lens.sensor.width_px), lens.sensor.pixel_mm)


def _valid(path: Path, stale) -> bool:
    """A cached render file that opens and is not `stale`."""
    if not path.is_file():
        return False
    try:
        with np.load(path) as z:
            return not stale(z)
    except Exception:  # noqa: BLE001 (a torn write: render again)
        return False


def _span_px(it: dict) -> float:
    """How much the blur changes over an item's whole sweep (px): defocus scale x its diopter range."""
    f = np.asarray(it["focus_m"], np.float64)
    return float(it["k"]) * (1.0 / f[0] - 1.0 / f[-1])


def _to_torch(d: dict) -> dict:
    return {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in d.items()}


def camera_processing(frames: np.ndarray, rng: np.random.Generator, origin=(0, 0)) -> np.ndarray:
    """A random camera's processing of linear frames (S, 3, H, W) rendered with white = 1: exposure level and
    per-frame changes, misalignment, Poisson-Gaussian noise, RAW development (bilinear demosaicking) and, when the
    `phone_jpeg` effect is registered, a phone's JPEG pipeline. Returns linear frames as the runtime decodes them."""
    from aat_deploy.render import effects as fx

    hs, ws = frames.shape[-2:]
    ctx = fx.SimContext(None, (hs, ws), (0, 0), exit_pupil_z_mm=0.0)
    level = float(np.percentile(frames, 99.5))
    x = frames * np.float32(rng.uniform(0.25, 1.0) / max(level, 1e-6))
    effects = []
    if rng.random() < 0.5:
        effects.append(fx.make("exposure", sigma_log=float(rng.uniform(0.0, 0.05))))
    if rng.random() < 0.4:
        effects.append(fx.make("misalignment", sigma_px=float(rng.uniform(0.0, 0.8)),
                               sigma_scale=float(rng.uniform(0.0, 0.002))))
    if rng.random() < 0.85:  # at working sizes a pixel bins several photosites: 2,000-50,000 electrons
        effects.append(fx.make("noise", full_well_e=float(np.exp(rng.uniform(np.log(2000), np.log(50000)))),
                               read_noise_e=float(rng.uniform(1.0, 4.0))))
    if rng.random() < 0.25:
        effects.append(fx.make("raw_pipeline", demosaic="bilinear"))
    if "phone_jpeg" in fx.names() and rng.random() < 0.35:
        from aat_deploy.render.effects import phone_jpeg

        effects.append(fx.make("phone_jpeg", **phone_jpeg.random_settings(rng)))
    if not effects:
        return x
    return np.clip(fx.post_stack(sorted(effects, key=lambda e: e.order), x, np.ones(len(x)), ctx, rng), 0, None)


def finish(it: dict, rng: np.random.Generator, effects: bool, idx: np.ndarray) -> dict:
    """A stack from a (cropped) dense item: frames `idx`, the camera's processing, the runtime's normalisation,
    the maps a user gives (with the small errors of a real calibration: an offset and a scale error)."""
    frames = np.asarray(it["frames"], np.float32)[idx]
    if effects:
        frames = camera_processing(frames, rng)
    p = normalise_scale(frames)
    maps = np.asarray(it["maps"], np.float32)[idx]
    spacing = max(float(maps.mean((1, 2))[0] - maps.mean((1, 2))[-1]) / max(len(idx) - 1, 1), 1e-3)
    maps = maps + np.float32(rng.normal(0, 0.03) * spacing)  # calibration offset, a few hundredths of a frame
    k = float(it["k"]) * float(np.exp(rng.normal(0, 0.05)))  # f-number / pixel pitch rounding
    h, w = frames.shape[-2:]
    return {"stack": scaled(frames, p), "focus_diopters": maps.astype(np.float32),
            "defocus_px_per_d": np.full((1, h, w), k, np.float32),
            "focus_m": np.asarray(it["focus_m"], np.float32)[idx], "depth_m": np.asarray(it["depth_m"], np.float32),
            "aif": scaled(np.asarray(it["aif"], np.float32), p)}
