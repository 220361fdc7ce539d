"""The any-camera training data (training.data.anycam, cameras): items are deterministic, batches share one stack
size, subsets keep the sweep's order, the maps a net is told match its frames (also mirrored), and no held-out
lens enters."""

import json

import numpy as np
import pytest
import torch

from training.data import cameras as cams
from training.data.anycam import HELD_OUT_LENSES, TRACED, AnyCamConfig, AnyCamDataset


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    cfg = AnyCamConfig(n_items=6, seed=3, height=48, width=48, margin_px=8, crop=32, max_layers=24,
                       cache_dir=str(tmp_path_factory.mktemp("anycam")))
    return AnyCamDataset(cfg)


def test_items_are_deterministic_and_cached_bytes_equal(ds, tmp_path):
    a = ds.load_or_render(0)
    other = AnyCamDataset(AnyCamConfig(**{**ds.cfg.__dict__, "cache_dir": str(tmp_path)}))
    b = other.load_or_render(0)
    assert (ds.cache / "000000.npz").read_bytes() == (other.cache / "000000.npz").read_bytes()
    assert np.array_equal(a["frames"], b["frames"]) and a["camera"] == b["camera"]
    assert a["frames"].shape == (cams.RENDER_FRAMES, 3, 48, 48)
    assert np.all(np.diff(a["focus_m"]) > 0)  # near -> far


def test_batches_share_one_stack_size_and_carry_the_maps(ds):
    torch.manual_seed(0)
    sizes = set()
    for _ in range(3):
        batch = ds.collate([ds[i] for i in range(4)])
        b, s = batch["focus_m"].shape
        sizes.add(s)
        assert batch["stack"].shape == (b, s, 3, 32, 32)
        assert batch["focus_diopters"].shape == (b, s, 32, 32)
        assert batch["defocus_px_per_d"].shape == (b, 1, 32, 32)
        assert cams.S_RANGE[0] <= s <= cams.S_RANGE[1]
        assert float(batch["stack"].min()) >= 0 and float(batch["stack"].max()) <= 1
        md = batch["focus_diopters"].mean((2, 3))
        assert bool((md[:, :-1] > md[:, 1:]).all())  # near -> far
    assert len(sizes) > 1


def test_maps_follow_the_frames_when_mirrored(ds):
    item = ds.load_or_render(1)
    h, w = item["depth_m"].shape
    maps, _ = ds.focus_maps(item, 0, 0, h, w)
    torch.manual_seed(5)
    seen = set()
    for _ in range(12):
        it = ds[1]
        r0c0 = None
        for r0 in range(h - 32 + 1):
            for c0 in range(w - 32 + 1):
                for fl in ((False, False), (True, False), (False, True), (True, True)):
                    d = item["depth_m"][r0:r0 + 32, c0:c0 + 32]
                    m = maps[:, r0:r0 + 32, c0:c0 + 32]
                    if fl[0]:
                        d, m = d[:, ::-1], m[:, :, ::-1]
                    if fl[1]:
                        d, m = d[::-1], m[:, ::-1]
                    if np.array_equal(d, it["depth_m"]):
                        r0c0 = fl
                        assert np.allclose(m, it["maps"], atol=1e-6)
        assert r0c0 is not None
        seen.add(r0c0)
    assert len(seen) > 1


def test_subsets_keep_order_and_size():
    rng = np.random.default_rng(0)
    for kind in ("stride", "random", "near"):
        for s in range(3, 17):
            idx, _ = cams.subset(rng, 16, kind, s)
            assert len(idx) == s and np.all(np.diff(idx) > 0) and idx.min() >= 0 and idx.max() < 16
    idx, _ = cams.subset(rng, 16, "random", 5)
    assert idx[0] == 0 and idx[-1] == 15  # a random schedule still spans the sweep


def test_random_cameras_span_phones_to_full_frame_within_the_blur_limit():
    rng = np.random.default_rng(1)
    classes, ks = set(), []
    for _ in range(300):
        cam, info = cams.random_camera(rng)
        classes.add(info["class"])
        ks.append(cam.defocus_px_per_diopter(2.0))
    assert classes == {c.name for c in cams.SENSOR_CLASSES}
    assert max(ks) <= cams.K_MAX_PX_PER_D * 1.05 and min(ks) < 1.0


def test_no_held_out_lens_is_rendered(ds):
    used = {p for pair in TRACED.values() for p in pair}
    assert not any(h in p for p in used for h in HELD_OUT_LENSES)
    for i in range(len(ds)):
        cam = json.loads(ds.load_or_render(i)["camera"])
        assert cam["traced"] in (None, *TRACED)


def test_sweeps_change_the_blur_by_a_bounded_amount():
    """Sweeps whose blur would span thousands of pixels (a 1-inch camera focused at 5 cm at full resolution) are
    drawn again or shortened: such renders need huge kernels (the first training run's data worker ran out of
    memory on one) and teach nothing."""
    rng = np.random.default_rng(2)
    for _ in range(400):
        cam, info = cams.random_camera(rng)
        k = cam.defocus_px_per_diopter(2.0)
        near, far = cams.random_focus_range(rng, info["min_focus_m"], info["class"], k)
        assert 0 < near < far
        assert k * (1 / near - 1 / far) <= cams.MAX_SPAN_PX * 1.0001


def test_no_camera_focuses_nearer_than_its_close_focus_limit():
    """Focus distances below ~4 focal lengths have no thin-lens solution (the blur formula explodes: the second
    out-of-memory render); cameras focus no nearer than 8 focal lengths."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        cam, info = cams.random_camera(rng)
        assert info["min_focus_m"] >= cams.MIN_FOCUS_FOCAL_LENGTHS * cam.focal_mm / 1000 - 1e-12
        near, _ = cams.random_focus_range(rng, info["min_focus_m"], info["class"], cam.defocus_px_per_diopter(2.0))
        assert near >= 4 * cam.focal_mm / 1000


def test_only_cached_reads_the_cached_items(ds):
    from dataclasses import replace

    ds.load_or_render(2)
    ds.load_or_render(5)
    part = AnyCamDataset(replace(ds.cfg, only_cached=True, n_items=6))
    cached = [i for i in range(6) if ds.is_cached(i)]
    assert part.items == cached and len(part) == len(cached) and 5 in cached
    assert part.cfg.key() == ds.cfg.key()  # the same renders


def test_even_sweeps_are_the_one_diopter_grid_bit_for_bit():
    # dense_schedule's "even" kind draws on optics.focus_table.even_diopters; the same random draws give the same
    # sweep as the inline np.linspace(1 / near, 1 / far, n) it replaced.
    for seed, (near, far, n) in enumerate(((0.3, 4.0, 16), (0.5, 10.0, 8), (1.2, 30.0, 5))):
        got, kind = cams.dense_schedule(np.random.default_rng(seed), near, far, n, kind="even")
        rng = np.random.default_rng(seed)
        dn, df = 1.0 / near, 1.0 / far
        d = np.linspace(dn, df, n) + rng.uniform(-0.2, 0.2, n) * (dn - df) / (n - 1)
        d = np.sort(np.clip(d, df * 0.5, None))[::-1]
        gap = (d[0] - d[-1]) / (n - 1) * 0.01
        for i in range(1, n):
            d[i] = min(d[i], d[i - 1] - gap)
        assert kind == "even" and np.array_equal(got, 1.0 / np.maximum(d, 1e-3))


def test_renders_older_than_the_beyond_infinity_fix_are_rendered_again_only_where_it_matters(ds, tmp_path):
    """A cached render without RENDER_VERSION whose camera's best focus passes infinity (parametric.FAR_D) in its
    window is stale (is_cached False, load_or_render renders it again); one whose map stays this side is kept."""
    from dataclasses import replace

    from training.data.anycam import RENDER_VERSION
    from training.data.cache import item_path, save_item

    d = AnyCamDataset(replace(ds.cfg, cache_dir=str(tmp_path)))
    index = next(i for i in range(6) if not json.loads(d.render(i)["camera"])["traced"])
    item = d.load_or_render(index)
    assert int(item["render_version"]) == RENDER_VERSION and d.is_cached(index)
    path = item_path(d.cache, index)
    old = {k: v for k, v in item.items() if k != "render_version"}
    cam = json.loads(old["camera"])
    far = 1.0 / float(item["focus_m"][-1])
    from aat_deploy.optics.field import pixel_fields
    from training.render.parametric import Camera

    h, w = item["depth_m"].shape
    sensor = tuple(int(v) for v in item["sensor_hw"])
    x, y = pixel_fields(h, w, sensor, tuple(int(v) for v in item["origin"]))
    r2 = float((Camera(1.0, 1.0, sensor, 1.0).radius(x, y) ** 2).max())  # the window's outermost field (r^2)
    for c2, stale in ((-(far + 0.05) / r2, True), (0.5 * far, False)):  # best focus past infinity there / nowhere
        cam["aberrations"].update(c2=c2, c4=0.0, tx=0.0, ty=0.0, a2=0.0, g=0.0)
        save_item(path, {**old, "frames": old["frames"].astype(np.float16), "camera": np.asarray(json.dumps(cam))})
        assert d.is_cached(index) is (not stale)
        again = d.load_or_render(index)
        assert ("render_version" in again) is stale  # rendered again (and cached) only when stale
        if stale:
            assert d.is_cached(index)


def test_mosaic_batches_lay_four_stacks_out_2x2_each_quadrant_its_own_camera(ds):
    """cfg.mosaic = 1: a batch of 4 items is one image of twice the side whose quadrants are those items' stacks,
    maps, defocus scales and depths (as the same batch without mosaic); the training loss runs on it."""
    from dataclasses import replace

    from training.nets.dfvaat import build, train_levels
    from training.train.config import LossConfig
    from training.train.loss import focus_map_loss

    torch.manual_seed(1)
    items = [ds[i] for i in range(4)]
    plain = ds.collate(items)
    mos = AnyCamDataset(replace(ds.cfg, mosaic=1.0)).collate(items)
    assert mos["stack"].shape[0] == 1 and mos["stack"].shape[-2:] == (64, 64)
    assert torch.isnan(mos["focus_m"]).all()
    for q, (r, c) in enumerate(((0, 0), (0, 32), (32, 0), (32, 32))):
        for k in ("stack", "focus_diopters", "defocus_px_per_d", "depth_m", "aif"):
            assert torch.equal(mos[k][0, ..., r:r + 32, c:c + 32], plain[k][q]), k
    loss, parts = focus_map_loss(train_levels(build(), mos), mos, LossConfig(level_weights=(8.0, 4.0)))
    assert torch.isfinite(loss) and np.isfinite(parts["frames_l1"])


def test_variable_crops_one_side_per_batch_the_maps_cropped_with_the_frames(ds):
    """cfg.crop_sizes: each batch draws one side for all its items (so it stacks), sides vary across batches, the
    renders (same key) are reused, and every array of an item is cut at the same place: a focus map cut from the
    item's own read equals the map computed for that window."""
    from dataclasses import replace

    from training.data.anycam import batch_crop
    from training.train.export import largest_training_image_px

    var = AnyCamDataset(replace(ds.cfg, crop_sizes=[16, 40, 64]))  # 64 > the 48 px renders: capped
    assert var.cfg.crop_sizes == (16, 40, 64) and var.cache == ds.cache
    torch.manual_seed(2)
    sides = set()
    for _ in range(8):
        items = [var[i] for i in range(4)]
        assert {it["depth_m"].shape for it in items} == {(48, 48)}  # read whole (at most the largest side)
        batch = var.collate(items)
        side = batch["stack"].shape[-1]
        assert batch["stack"].shape[-2:] == batch["focus_diopters"].shape[-2:] == batch["depth_m"].shape[-2:] == (
            side, side)
        sides.add(side)
    assert sides == {16, 40, 48}
    # where it cuts: arrays that encode their own coordinates, cut alike
    rc = np.arange(48 * 48, dtype=np.float32).reshape(48, 48)
    item = {"frames": np.broadcast_to(rc, (5, 3, 48, 48)), "maps": np.broadcast_to(rc, (5, 48, 48)),
            "depth_m": rc, "aif": np.broadcast_to(rc, (3, 48, 48)), "k": 1.0, "seed": 0}
    for it in batch_crop([item, item], (24,), np.random.default_rng(0)):
        corner = it["depth_m"][0, 0]
        assert it["depth_m"].shape == (24, 24) and corner != 0
        assert it["frames"][:, :, 0, 0].min() == it["maps"][:, 0, 0].max() == it["aif"][:, 0, 0].min() == corner
    # the maps of a window of the real item are those focus_maps computes for that window
    whole = var.load_or_render(1)
    maps, _ = var.focus_maps(whole, 0, 0, 48, 48)
    cut = batch_crop([{"frames": whole["frames"], "maps": maps, "depth_m": whole["depth_m"], "aif": whole["aif"],
                       "k": 1.0, "seed": 0}], (20,), np.random.default_rng(5))[0]
    r0, c0 = _where(whole["frames"], cut)
    assert np.allclose(cut["maps"], var.focus_maps(whole, r0, c0, 20, 20)[0])
    assert largest_training_image_px({"crop": 0, "crop_sizes": [128, 384], "height": 256, "width": 256}) == 256
    assert largest_training_image_px({"crop": 0, "crop_sizes": [128, 192], "height": 256, "width": 256}) == 192


def test_fit_sensor_caps_a_render_to_its_cameras_sensor_and_leaves_old_keys_alone(ds, tmp_path):
    """fit_sensor: a render larger than its camera's sensor (a 320 x 240 px phone) is cut to the sensor's rows and
    columns, so no pixel lies past the sensor's corners; off, the keys of earlier renders are unchanged."""
    from dataclasses import replace

    cfg = AnyCamConfig(n_items=400, seed=3, height=200, width=200, margin_px=4, crop=0, max_layers=8,
                       wide_sweep_fraction=0.5, wide_max_width_px=1280, fit_sensor=True, cache_dir=str(tmp_path))
    d = AnyCamDataset(cfg)
    small = next(i for i in range(400) if d.draw_sweep(np.random.default_rng([3, i, 35]), i).sensor_hw[0] < 200)
    sensor_hw = d.draw_sweep(np.random.default_rng([3, small, 35]), small).sensor_hw
    item = d.load_or_render(small)
    capped = tuple(min(v, 200) for v in sensor_hw)
    assert item["depth_m"].shape == item["frames"].shape[-2:] == capped == d.render_hw(sensor_hw)
    assert item["origin"][0] == 0 and tuple(item["sensor_hw"]) == tuple(sensor_hw)
    assert d.render_hw((480, 640)) == (200, 200)
    assert replace(cfg, fit_sensor=False).key() != cfg.key()
    assert replace(ds.cfg, fit_sensor=False).key() == ds.cfg.key()  # the default adds nothing to a key


def _where(frames: np.ndarray, cut: dict) -> tuple[int, int]:
    """(row, col) of the window `cut` in the whole frames (found by matching every pixel)."""
    s = cut["frames"].shape[-1]
    hits = [(r, c) for r in range(frames.shape[-2] - s + 1) for c in range(frames.shape[-1] - s + 1)
            if np.array_equal(frames[..., r:r + s, c:c + s], cut["frames"])]
    assert len(hits) == 1
    return hits[0]


def test_wide_sweeps_are_large_sensors_wide_open_changing_the_blur_by_tens_of_pixels():
    """The third run's sweeps that look like the test stacks (benchmarks/probes/anycam_sweeps.py: the first runs'
    sweeps changed the blur by under 9 px in half the items, the held-out stacks by 50-80 px)."""
    rng = np.random.default_rng(4)
    spans = []
    for _ in range(400):
        cam, info, near, far = cams.wide_sweep_camera(rng)
        assert info["class"] in ("aps_c", "full_frame") and info["sweep"] == "wide"
        assert cams.WIDE_F_NUMBER[0] <= cam.f_number <= cams.WIDE_F_NUMBER[1]
        assert near >= cams.MIN_FOCUS_FOCAL_LENGTHS * cam.focal_mm / 1000 - 1e-12 and far > near
        k = cam.defocus_px_per_diopter(float(np.sqrt(near * far)))
        assert k <= cams.K_MAX_PX_PER_D * 1.1  # (k is set at 2 m; a little more at a near focus)
        assert cam.sensor_hw[1] <= cams.MAX_WIDTH_PX
        spans.append(k * (1 / near - 1 / far))
    spans = np.array(spans)
    assert np.mean((spans >= 20) & (spans <= 120)) >= 0.7
    assert np.median(spans) >= 25 and np.percentile(spans, 90) >= 60
    assert spans.min() >= 10


def _sweeps_config(**kw) -> AnyCamConfig:
    return AnyCamConfig(n_items=400, seed=0, height=48, width=48, margin_px=8, max_layers=24, **kw)


def test_a_wide_sweep_config_keeps_every_other_item_of_its_base_config_draw_for_draw():
    """Items not drawn as wide sweeps are the base config's items (so its cached renders serve): same camera,
    aberrations and focus; the wide ones are new, and the config's cache key is its own."""
    cfg = _sweeps_config(wide_sweep_fraction=0.5)
    base = cfg.base_config()
    assert base == _sweeps_config() and base.key() == _sweeps_config().key() != cfg.key()
    assert _sweeps_config().base_config() is None
    new, old = AnyCamDataset(cfg), AnyCamDataset(base)
    wide = 0
    for i in range(120):
        a = new.draw_sweep(np.random.default_rng([0, i, 35]), i)
        b = old.draw_sweep(np.random.default_rng([0, i, 35]), i)
        assert a.wide == new.is_wide(i) and not (a.wide and a.traced) and not b.wide
        if a.wide:
            wide += 1
            assert not np.array_equal(a.focus, b.focus)
        else:
            assert np.array_equal(a.focus, b.focus) and a.cam == b.cam and a.kind == b.kind
    assert 0.3 <= wide / 120 <= 0.55  # 0.5 of the 85 % parametric items
    assert new.render_priority(next(i for i in range(120) if new.is_wide(i))) == 0


def test_the_wide_sweep_config_covers_the_test_stacks_blur_change():
    """Regression guard of the third run's data (configs/anycam/dfv_aat_v3.json) against the first runs':
    at least 45 % of its sweeps change the blur by 20-120 px (the first runs': about a quarter)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]

    def share(name):
        data = json.loads((root / "configs" / "anycam" / name).read_text())["data"]
        d = AnyCamDataset(AnyCamConfig(**{**data, "n_items": 500, "cache_dir": None, "only_cached": False}))
        s = np.array([d.draw_sweep(np.random.default_rng([d.cfg.seed, i, 35]), i).span_px() for i in range(500)])
        return np.mean((s >= 20) & (s <= 120))

    assert share("dfv_aat_v3.json") >= 0.45 > 0.35 >= share("dfv_aat.json")


def test_shared_items_are_adopted_from_the_base_cache_wide_ones_never(tmp_path):
    from training.data.cache import check_sources, item_path, save_item

    cfg = _sweeps_config(wide_sweep_fraction=0.5, cache_dir=str(tmp_path))
    new = AnyCamDataset(cfg)
    shared = next(i for i in range(50) if not new.is_wide(i))
    wide = next(i for i in range(50) if new.is_wide(i))
    fake = {"frames": np.zeros((2, 3, 4, 4), np.float16), "render_version": np.int64(2), "camera": np.asarray("{}")}
    check_sources(new.base_cache, new.sources)  # rendered with today's code: it records its sources first
    for i in (shared, wide):
        save_item(item_path(new.base_cache, i), fake)
    assert not item_path(new.cache, shared).exists()
    assert new.is_cached(shared) and not new.is_cached(wide)
    assert item_path(new.cache, shared).read_bytes() == item_path(new.base_cache, shared).read_bytes()
    assert not item_path(new.cache, wide).exists()
    assert new.is_cached(shared)  # again: idempotent


ROOT = __import__("pathlib").Path(__file__).resolve().parents[3]
ANYCAM_CONFIGS = sorted((ROOT / "configs" / "anycam").glob("*.json"))


def test_every_anycam_config_keeps_the_held_out_lenses_out():
    """No any-camera config (the fourth run's included) names a held-out lens anywhere (lens, init, data), and
    every traced camera its items draw is one of TRACED (none held out)."""
    assert "dfv_aat_v4.json" in {p.name for p in ANYCAM_CONFIGS}
    for path in ANYCAM_CONFIGS:
        text = path.read_text()
        assert not any(h in text for h in HELD_OUT_LENSES), path
        data = json.loads(text)["data"]
        d = AnyCamDataset(AnyCamConfig(**{**data, "n_items": 300, "cache_dir": None, "only_cached": False}))
        for i in range(300):
            sw = d.draw_sweep(np.random.default_rng([d.cfg.seed, i, 35]), i)
            assert not sw.traced or sw.info["lens"] in TRACED


def test_far_map_limit_keeps_every_frames_map_within_twice_the_far_focus():
    """limit_far_map: after it no frame's best focus (either astigmatic focus, anywhere on the sensor) lies past
    floor x the far frame's diopters; a camera within the limit comes back unchanged (the same draw)."""
    from training.render.parametric import Aberrations, Camera

    focus = np.geomspace(0.31, 43.0, 16)
    g = np.linspace(-1, 1, 101)  # finer than the function's own grid: the map between its nodes too
    x, y = np.meshgrid(g, g)
    touched = 0
    rng = np.random.default_rng(7)
    for _ in range(200):
        spacing = (1 / focus[0] - 1 / focus[-1]) / 15
        ab = cams.random_aberrations(rng, spacing, 0.5 * (1 / focus[0] + 1 / focus[-1]))
        cam = Camera(50.0, 1.8, (800, 1200), 0.03, ab)
        out = cams.limit_far_map(cam, focus, 0.5)
        lo = (1 / focus[:, None, None] + out.shift_diopters(x[None], y[None], focus[:, None, None])
              - np.abs(0.5 * out.aberrations.a2 * out.radius(x, y) ** 2)).min()
        assert lo >= 0.5 / focus[-1] * 0.99
        before = (1 / focus[:, None, None] + cam.shift_diopters(x[None], y[None], focus[:, None, None])
                  - np.abs(0.5 * ab.a2 * cam.radius(x, y) ** 2)).min()
        if before >= 0.5 / focus[-1] + 1e-6:
            assert out == cam
        else:
            touched += 1
            assert out.aberrations.g == ab.g and abs(out.aberrations.c2) <= abs(ab.c2)
    assert touched > 20  # a long sweep's far end: frame-spacing-sized aberrations often pass it
    assert cams.limit_far_map(Camera(50.0, 1.8, (8, 12), 0.03, Aberrations(c2=-9.0)), focus, 0.0).aberrations.c2 == -9


def test_the_wide_sweeps_width_cap_redraws_only_the_draws_over_it():
    """wide_sweep_camera(max_width_px): every camera within the cap, and a draw within it is the uncapped draw."""
    same = 0
    for i in range(200):
        cam, info, near, far = cams.wide_sweep_camera(np.random.default_rng([i, 1]), 1280)
        cam0, info0, near0, far0 = cams.wide_sweep_camera(np.random.default_rng([i, 1]))
        assert cam.sensor_hw[1] <= 1280
        if cam0.sensor_hw[1] <= 1280:
            same += 1
            assert (cam, info, near, far) == (cam0, info0, near0, far0)
    assert 60 <= same < 200


def test_items_the_draw_limits_leave_alone_are_adopted_from_the_unlimited_cache(tmp_path):
    """A config with draw limits (far_map_floor, wide_max_width_px) shares every item they do not touch with the
    same config without them: its render is the same, byte for byte, and is adopted from that config's cache; an
    item a limit touches is drawn anew and never adopted."""
    from training.data.cache import item_path

    old_cfg = replace_cfg(_sweeps_config(wide_sweep_fraction=0.5, cache_dir=str(tmp_path / "old")), n_items=40)
    new_cfg = replace_cfg(old_cfg, far_map_floor=0.5, wide_max_width_px=1280, cache_dir=str(tmp_path / "old"))
    old, new = AnyCamDataset(old_cfg), AnyCamDataset(new_cfg)
    assert new_cfg.key() != old_cfg.key() and old_cfg.key() in {c.key() for c in new_cfg.donor_configs()}
    same = [i for i in range(40) if new.same_draw(AnyCamDataset._bare(old_cfg), i)]
    diff = [i for i in range(40) if i not in same]
    assert same and diff
    for i in (same[0], diff[0]):
        old.load_or_render(i)
    assert new.is_cached(same[0]) and not new.is_cached(diff[0])
    assert item_path(new.cache, same[0]).read_bytes() == item_path(old.cache, same[0]).read_bytes()
    fresh = AnyCamDataset(replace_cfg(new_cfg, cache_dir=str(tmp_path / "fresh")))
    assert np.array_equal(fresh.render(same[0])["frames"], old.render(same[0])["frames"])
    assert not np.array_equal(fresh.render(diff[0])["frames"], old.render(diff[0])["frames"])


def replace_cfg(cfg: AnyCamConfig, **kw) -> AnyCamConfig:
    from dataclasses import replace

    return replace(cfg, **kw)


def test_processed_fraction_leaves_items_clean_and_keeps_the_earlier_draws(ds):
    from dataclasses import replace

    val = lambda **kw: AnyCamDataset(replace(ds.cfg, fixed_subsets=True, **kw))  # noqa: E731
    old, one, clean, off = val(), val(processed_fraction=1.0), val(processed_fraction=0.0), val(camera_effects=False)
    for i in range(3):
        assert torch.equal(old[i]["stack"], one[i]["stack"])  # 1 draws nothing: the earlier runs' items
        assert torch.equal(clean[i]["stack"], off[i]["stack"])  # 0: the frames as rendered, normalised
    assert any(not torch.equal(old[i]["stack"], clean[i]["stack"]) for i in range(3))
    cfg = replace(ds.cfg, processed_fraction=0.3)
    assert cfg.key() == ds.cfg.key()  # how renders are read, not what they are: the same cache
    share = np.mean([cfg.processes(np.random.default_rng([9, s])) for s in range(4000)])
    assert abs(share - 0.3) < 0.03
    assert not replace(cfg, camera_effects=False).processes(np.random.default_rng(0))
    with pytest.raises(ValueError, match="processed_fraction 1.5"):
        replace(ds.cfg, processed_fraction=1.5)


def test_small_stack_fraction_draws_small_batches_and_nothing_at_zero(ds):
    """small_stack_fraction 1: every training batch has 3-5 frames; 0 (the default) draws nothing, so a batch is the
    earlier runs' batch; the renders' key does not change (how items are read, not what they are)."""
    from dataclasses import replace

    from training.data.anycam import SMALL_STACK_MAX

    torch.manual_seed(0)
    items = [ds[i] for i in range(4)]
    small = AnyCamDataset(replace(ds.cfg, small_stack_fraction=1.0))
    zero = AnyCamDataset(replace(ds.cfg, small_stack_fraction=0.0))
    assert small.cfg.key() == ds.cfg.key()
    sizes, small_sizes = [], []
    for seed in range(12):
        its = [{**it, "seed": seed * 10 + k} for k, it in enumerate(items)]
        a, b = ds.collate(its), zero.collate(its)
        assert torch.equal(a["stack"], b["stack"])
        sizes.append(a["stack"].shape[1])
        small_sizes.append(small.collate(its)["stack"].shape[1])
    assert max(small_sizes) <= SMALL_STACK_MAX and min(small_sizes) >= 3
    assert max(sizes) > SMALL_STACK_MAX  # the test's items allow larger stacks: the bound above means something
    with pytest.raises(ValueError, match="small_stack_fraction -0.1"):
        replace(ds.cfg, small_stack_fraction=-0.1)
