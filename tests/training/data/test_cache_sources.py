"""A cache folder remembers the lens and PSF files its items were rendered from (sources.json) and refuses to be
read with other files: the key holds their paths, so a file corrected in place would otherwise reuse old items."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from training.data.cache import SOURCES, check_sources, item_path, sha256_file
from training.data.stacks import FocalStackDataset, StackDataConfig

ROOT = Path(__file__).resolve().parents[3]


def _fake(index: int) -> dict:  # an item without rendering: only the cache is under test
    return {"stack": np.full((3, 3, 8, 8), index / 10, np.float32), "focus_m": np.array([1, 2, 3], np.float32),
            "depth_m": np.ones((8, 8), np.float32), "aif": np.zeros((3, 8, 8), np.float32),
            "origin": np.array([0, 0], np.int64)}


def _lens(tmp_path: Path) -> Path:
    lens = tmp_path / "lens.json"
    shutil.copy(ROOT / "lenses" / "canon_rf50mm_f1.8.json", lens)
    return lens


def _dataset(lens: Path, cache: Path, rendered: list) -> FocalStackDataset:
    ds = FocalStackDataset(StackDataConfig(simulator="thin_lens", lens=str(lens), psf=None, height=8, width=8,
                                           stack_size=3, n_items=2, margin_px=0, cache_dir=str(cache)))
    ds.render = lambda i: rendered.append(i) or _fake(i)
    return ds


def test_a_changed_lens_file_is_refused_an_unchanged_one_read(tmp_path):
    lens, cache, rendered = _lens(tmp_path), tmp_path / "cache", []
    ds = _dataset(lens, cache, rendered)
    ds.load_or_render(0)
    rec = json.loads((ds.cache / SOURCES).read_text())
    assert rec == {"lens": {"path": str(lens), "sha256": sha256_file(lens)}, "psf": None}
    again = _dataset(lens, cache, rendered)  # unchanged file: read from the cache, not rendered
    assert np.array_equal(again.load_or_render(0)["stack"], _fake(0)["stack"]) and rendered == [0]

    lens.write_text(lens.read_text() + "\n ")  # corrected in place: same path, so the same key
    changed = _dataset(lens, cache, rendered)
    assert changed.cache == ds.cache
    with pytest.raises(ValueError) as e:
        changed.load_or_render(0)
    msg = str(e.value)
    assert "\n" not in msg and str(ds.cache) in msg and str(lens) in msg and "fresh --cache" in msg
    assert rendered == [0] and item_path(ds.cache, 0).is_file()  # nothing rendered over it, nothing deleted


def test_a_folder_without_the_record_gets_it_and_a_psf_change_is_refused(tmp_path):
    lens, cache, rendered = _lens(tmp_path), tmp_path / "cache", []
    ds = _dataset(lens, cache, rendered)
    ds.load_or_render(1)
    (ds.cache / SOURCES).unlink()  # as a folder made before the record existed
    old = _dataset(lens, cache, rendered)
    old.load_or_render(1)
    assert rendered == [1]
    assert json.loads((ds.cache / SOURCES).read_text())["lens"]["sha256"] == sha256_file(lens)

    psf, folder = tmp_path / "psf.onnx", tmp_path / "other"
    psf.write_bytes(b"surrogate A")
    check_sources(folder, {"lens": lens, "psf": psf})
    check_sources(folder, {"lens": lens, "psf": psf})  # the same files pass
    psf.write_bytes(b"surrogate B, restamped")
    with pytest.raises(ValueError, match=r"other: rendered from psf .*psf.onnx.*fresh --cache"):
        check_sources(folder, {"lens": lens, "psf": psf})
    with pytest.raises(ValueError, match="but psf now none"):
        check_sources(folder, {"lens": lens, "psf": None})
