"""Rendering training data at scale (issue 38): shard i of n renders items i, i+n, ...; shards run in any order
fill one cache whose files and manifest equal, byte for byte, those of one unsharded run; a killed shard resumes;
under torchrun the rank picks the shard."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from training.data.cache import item_path, save_item, verify_manifest
from training.devices.shard import Shard, parse_shard, shard_from_env

ROOT = Path(__file__).resolve().parents[3]


def _script():
    spec = importlib.util.spec_from_file_location("render_training_stacks", ROOT / "scripts" / "render_training_stacks.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _config(tmp_path: Path, cache: Path) -> Path:
    data = {"height": 32, "width": 32, "stack_size": 3, "n_items": 5, "seed": 3, "margin_px": 8, "cell_px": 32,
            "cache_dir": str(cache)}
    p = tmp_path / f"cfg_{cache.name}.json"
    p.write_text(json.dumps({"name": "shards", "net": "dfvnet", "size": "small", "simulator": "aat",
                             "lens": "lenses/canon_rf50mm_f1.8.json", "data": data}))
    return p


def _files(cache_root: Path) -> dict[str, bytes]:
    (key,) = [d for d in cache_root.iterdir() if d.is_dir()]
    return {p.name: p.read_bytes() for p in sorted(key.iterdir()) if p.is_file()}


def test_shard_parsing_and_torchrun_world(monkeypatch):
    assert parse_shard("2/3") == Shard(2, 3) and list(Shard(2, 3).items(8)) == [2, 5]
    for bad in ("3/3", "1", "a/2", "-1/2", "0/0"):
        with pytest.raises(Exception, match="--shard"):
            parse_shard(bad)
    assert shard_from_env() == Shard(0, 1)
    monkeypatch.setenv("RANK", "1")
    monkeypatch.setenv("WORLD_SIZE", "4")
    assert shard_from_env() == Shard(1, 4)


def test_save_item_is_byte_deterministic_and_npz(tmp_path):
    arrays = {"stack": np.arange(12, dtype=np.float16).reshape(3, 4), "origin": np.array([3, 4])}
    save_item(tmp_path / "a.npz", arrays)
    save_item(tmp_path / "b.npz", dict(reversed(list(arrays.items()))))
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    with np.load(tmp_path / "a.npz") as z:
        assert set(z.files) == set(arrays) and all(np.array_equal(z[k], v) for k, v in arrays.items())
        assert z["stack"].dtype == np.float16


def test_shards_fill_the_same_cache_as_one_run_bit_for_bit(tmp_path, monkeypatch, capsys):
    mod = _script()
    whole, sharded = tmp_path / "whole", tmp_path / "sharded"
    assert mod.main([str(_config(tmp_path, whole)), "--workers", "1", "-q"]) == 0
    assert "5 of 5 items held, complete" in capsys.readouterr().out
    cfg = str(_config(tmp_path, sharded))
    assert mod.main([cfg, "--workers", "1", "-q", "--shard", "2/3"]) == 0  # any order
    assert "1 of 5 items held, 4 items still missing" in capsys.readouterr().out
    assert mod.main([cfg, "--workers", "1", "-q", "--shard", "0/3"]) == 0
    assert not list(sharded.glob("*/manifest.json"))  # written only once the cache is complete
    assert mod.main([cfg, "--workers", "1", "-q", "--shard", "1/3"]) == 0
    assert "5 of 5 items held, complete, manifest.json written" in capsys.readouterr().out
    a, b = _files(whole), _files(sharded)
    assert sorted(a) == [f"{i:06d}.npz" for i in range(5)] + ["manifest.json", "sources.json"]
    assert a == b  # every item and the manifest, byte for byte
    (key,) = [d for d in sharded.iterdir() if d.is_dir()]
    assert verify_manifest(key) == []
    records = sorted(p.name for p in (key / "shards").iterdir())
    assert records == ["0-of-3.json", "1-of-3.json", "2-of-3.json"]
    assert json.loads((key / "shards" / "1-of-3.json").read_text())["sessions"][0]["rendered"] == 2

    # a shard killed part-way resumes: only what is missing is rendered, into the same bytes
    item_path(key, 4).unlink()
    assert mod.main([cfg, "--workers", "1", "-q", "--shard", "1/3"]) == 0  # 1/3 holds items 1 and 4
    assert "1 rendered now" in capsys.readouterr().out
    assert _files(sharded) == a
    assert len(json.loads((key / "shards" / "1-of-3.json").read_text())["sessions"]) == 2
    item_path(key, 0).write_bytes(b"not this")
    assert verify_manifest(key) == ["000000.npz"]

    # under torchrun the rank is the shard; --shard on top of it is refused
    monkeypatch.setenv("RANK", "0")
    monkeypatch.setenv("WORLD_SIZE", "2")
    with pytest.raises(SystemExit):
        mod.main([cfg, "--workers", "1", "-q", "--shard", "0/3"])
    assert "the rank already picks the shard" in capsys.readouterr().err
    item_path(key, 0).unlink()
    monkeypatch.setenv("RANK", "0")
    assert mod.main([cfg, "--workers", "1", "-q"]) == 0  # rank 0 of 2: items 0, 2, 4
    assert "shard 0/2: 1 rendered now" in capsys.readouterr().out and (key / "shards" / "0-of-2.json").is_file()
    assert _files(sharded) == a


def test_an_any_camera_config_that_reads_only_cached_items_is_rendered_from_an_empty_cache(tmp_path, capsys):
    """The seventh run's config shrunk (only_cached, crop_sizes, fit_sensor): its run reads only cached renders, so
    the renderer must make them from nothing; the run then reads them, one crop side per batch."""
    from training.train.config import load_config
    from training.train.data import make_dataset

    v7 = json.loads((ROOT / "configs" / "anycam" / "dfv_aat_v7.json").read_text())
    tiny = {"n_items": 3, "height": 40, "width": 40, "margin_px": 4, "max_layers": 8, "cache_dir": str(tmp_path)}
    p = tmp_path / "v7.json"
    p.write_text(json.dumps({**v7, "data": {**v7["data"], **tiny, "crop_sizes": [16, 32]},
                             "val_data": {**v7["val_data"], **tiny, "n_items": 1}}))
    assert _script().main([str(p), "--workers", "1", "-q"]) == 0
    out = capsys.readouterr().out
    assert "3 of 3 items held, complete" in out and "1 of 1 items held, complete" in out
    cfg = load_config(p)
    ds = make_dataset(cfg.data, cfg.simulator, cfg.lens)
    assert len(ds) == 3 and ds.check_sources() == "verified"
    assert ds.collate([ds[i] for i in range(3)])["stack"].shape[-1] in (16, 32)
