"""Training data: RGB-D loaders and the on-the-fly focal-stack dataset."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from aat_deploy.gt.holes import fill_holes
from training.data.rgbd import RGBDError, load_middlebury_motorcycle, load_rgbd, read_depth
from training.data.stacks import FocalStackDataset, StackDataConfig


def test_read_depth_units_and_errors(tmp_path):
    mm = np.array([[0, 1500], [2500, 65535]], dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "d.png"), mm)
    assert np.allclose(read_depth(tmp_path / "d.png"), [[0, 1.5], [2.5, 65.535]])
    assert np.allclose(read_depth(tmp_path / "d.png", scale_m=0.0001), [[0, 0.15], [0.25, 6.5535]])
    np.save(tmp_path / "d.npy", np.array([[np.nan, 2.0], [-1.0, 3.0]]))
    assert np.allclose(read_depth(tmp_path / "d.npy"), [[0, 2.0], [0, 3.0]])
    np.save(tmp_path / "z.npy", np.zeros((3, 3)))
    with pytest.raises(RGBDError, match="z.npy: no valid depth"):
        read_depth(tmp_path / "z.npy")
    cv2.imwrite(str(tmp_path / "rgb.png"), np.zeros((3, 3, 3), np.uint8))
    with pytest.raises(RGBDError, match="d.png: depth is 2x2 but .*rgb.png is 3x3"):
        load_rgbd(tmp_path / "rgb.png", tmp_path / "d.png")


def test_middlebury_motorcycle_metric_depth():
    rgb, depth = load_middlebury_motorcycle()
    assert rgb.shape == (500, 741, 3) and depth.shape == (500, 741)
    valid = depth > 0
    assert 0.9 < valid.mean() < 1.0
    assert 2.0 < depth[valid].min() < 2.2 and 4.9 < depth[valid].max() < 5.1  # 2.11 .. 5.04 m
    filled = fill_holes(depth)
    assert (filled > 0).all() and np.array_equal(filled[valid], depth[valid])


def _cfg(**kw):
    base = dict(height=48, width=64, stack_size=4, n_items=3, seed=5, cell_px=32, margin_px=8)
    return StackDataConfig(**{**base, **kw})


@pytest.mark.numerics
def test_items_shapes_order_and_determinism():
    ds = FocalStackDataset(_cfg())
    a, b = ds[1], ds[1]
    assert a["stack"].shape == (4, 3, 48, 64) and a["aif"].shape == (3, 48, 64) and a["depth_m"].shape == (48, 64)
    f = a["focus_m"].numpy()
    assert np.all(np.diff(f) > 0) and f[[0, -1]] == pytest.approx([0.5, 10.0], rel=1e-6)  # float32 of 1 / diopters
    assert np.array_equal(a["stack"].numpy(), b["stack"].numpy())  # deterministic: the same item, bit for bit
    assert 0 <= float(a["stack"].min()) and float(a["stack"].max()) <= 1.0
    with pytest.raises(IndexError):
        ds[3]


def test_aat_and_thin_share_scenes_but_not_blur():
    aat, thin = FocalStackDataset(_cfg(simulator="aat"))[0], FocalStackDataset(_cfg(simulator="thin_lens"))[0]
    assert np.array_equal(aat["depth_m"].numpy(), thin["depth_m"].numpy())
    assert np.array_equal(aat["origin"].numpy(), thin["origin"].numpy())
    assert float((aat["stack"] - thin["stack"]).abs().mean()) > 1e-3


@pytest.mark.numerics
def test_crops_keep_the_psfs_of_their_field_position():
    ds = FocalStackDataset(_cfg(simulator="aat"))
    seen = []
    real = ds.sim.render_stack

    def spy(img, depth, focus, origin=(0, 0), rng=None):
        seen.append(origin)
        return real(img, depth, focus, origin=origin, rng=rng)

    ds.sim.render_stack = spy
    origins = [ds.render(i)["origin"].tolist() for i in range(3)]
    hs, ws = ds.sensor_hw
    for (r, c), o in zip(origins, seen):
        assert o == (r - 8, c - 8)  # the rendered margin sits around the crop's true place
        assert 0 <= r <= hs - 48 and 0 <= c <= ws - 64
    assert len({tuple(o) for o in origins}) == 3  # crops land all over the field
    # The same scene rendered at another field position differs with the lens's PSFs, not with a thin lens.
    item = ds.render(0)
    img = item["aif"].copy()
    import torch

    t = torch.from_numpy(img)
    d = torch.from_numpy(np.maximum(item["depth_m"], 0.5))
    for sim, expect_same in ((FocalStackDataset(_cfg(simulator="thin_lens")).sim, True), (ds.sim, False)):
        a = sim.render_stack(t, d, [1.0], origin=(0, 0)).frames
        b = sim.render_stack(t, d, [1.0], origin=(hs // 2 - 24, ws // 2 - 32)).frames
        # field-invariant PSFs render the same numbers up to the FFT's float32 rounding (~1e-6 of the frame)
        assert (float((a - b).abs().max()) < 1e-5 * float(a.abs().max())) == expect_same


def test_default_fields_keep_the_cache_key_and_the_scenes():
    """The richer-data fields are off by default: a config that does not use them hashes and renders as before."""
    base = _cfg()
    assert base.key() == _cfg(scene_range="fixed", photo_fraction=0.0, schedule="fixed").key()
    assert base.key() == _cfg(crop_height=32, crop_width=32, flips=True).key()  # crops are cut when read
    assert base.key() != _cfg(photo_fraction=0.5).key()
    a = FocalStackDataset(base).render(0)
    b = FocalStackDataset(_cfg(crop_height=32, crop_width=32)).render(0)
    assert np.array_equal(a["stack"], b["stack"])


def test_photo_textures_random_ranges_and_the_scene_schedule():
    ds = FocalStackDataset(_cfg(scene_range="random", photo_fraction=1.0, schedule="scene", n_items=6))
    spans = []
    for i in range(6):
        it = ds.render(i)
        d, f = it["depth_m"], it["focus_m"]
        assert np.all(np.diff(f) > 0)
        # the paper's protocol: focus spread over this item's own depth range (perturbed by < 1/4 spacing)
        step = (d.max() - d.min()) / (len(f) - 1)
        slack = 1e-5 * d.max()  # float32 depths and focus distances (from diopters): a few dozen ulps
        assert f[0] >= d.min() - 0.26 * step - slack and f[-1] <= d.max() + 0.26 * step + slack
        spans.append(d.max() / d.min())
        assert 0.5 * (1 - 2e-4) <= d.min() and d.max() <= 10.0 * (1 + 1e-4)
    assert min(spans) < 8  # some items got a sub-range (the full range spans 20x)


def test_random_crops_flips_and_field_coordinates():
    """A crop is a window of the cached item; a mirrored crop shows the window mirrored, and its field
    coordinates are those of the mirrored sensor position (sign flipped), as the rotationally symmetric lens's."""
    import torch

    ds = FocalStackDataset(_cfg(height=64, width=96, crop_height=32, crop_width=48, flips=True, n_items=2))
    whole = ds.load_or_render(0)
    hs, ws = ds.sensor_hw
    torch.manual_seed(0)
    flips_seen = set()
    for _ in range(16):
        it = ds[0]
        assert it["stack"].shape == (4, 3, 32, 48) and it["field_xy"].shape == (2, 32, 48)
        r0, c0 = (int(v) for v in it["origin"])
        x_plain = 2 * (c0 + np.arange(48) + 0.5) / ws - 1
        y_plain = 1 - 2 * (r0 + np.arange(32) + 0.5) / hs
        fx, fy = it["field_xy"][0, 0].numpy(), it["field_xy"][1, :, 0].numpy()  # in [-1, 1]: atol is relative
        lr = not np.allclose(fx, x_plain, atol=1e-5)
        ud = not np.allclose(fy, y_plain, atol=1e-5)
        if lr:
            assert np.allclose(fx, -x_plain[::-1], atol=1e-5)
        if ud:
            assert np.allclose(fy, -y_plain[::-1], atol=1e-5)
        r, c = r0 - int(whole["origin"][0]), c0 - int(whole["origin"][1])
        sub = whole["stack"][..., r:r + 32, c:c + 48]
        sub = sub[..., ::-1] if lr else sub
        sub = sub[..., ::-1, :] if ud else sub
        assert np.array_equal(it["stack"].numpy(), sub)
        flips_seen.add((lr, ud))
    assert len(flips_seen) >= 3


def test_field_focus_training_data_keys_carry_the_renderer_mark():
    """Training data with sensor_tilt or lens_tolerance is rendered again after the renderer's per-anchor cell
    fix (c9c07bd); noise-only data keeps its cache (its key as before the mark existed)."""
    assert _cfg(effects=("noise",)).key() == "eb8f712e3c7d"
    assert _cfg(effects=("sensor_tilt",)).key() != "25811c8eb9f8"
    assert _cfg(effects=("noise", "lens_tolerance")).key() != "dea9ae866009"
