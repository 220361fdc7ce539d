"""A cache folder remembers the lens and PSF files its items were rendered from (sources.json) and refuses to be
read with other files: the key holds their paths, so a file corrected in place would otherwise reuse old items."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from training.data.cache import SOURCES, check_sources, item_path, sha256_file, sources_state
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


def _listing(folder: Path) -> dict:
    return {f.relative_to(folder).as_posix(): f.read_bytes() for f in sorted(folder.rglob("*")) if f.is_file()}


def test_a_folder_made_before_the_record_is_read_unverified_and_never_stamped(tmp_path, capsys):
    """A folder that held items before sources.json existed: its items may be of older files (the record would
    vouch for them if it were written now), so it is read with one warning line and nothing is written into it."""
    lens, cache, rendered = _lens(tmp_path), tmp_path / "cache", []
    ds = _dataset(lens, cache, rendered)
    ds.load_or_render(1)
    (ds.cache / SOURCES).unlink()  # as a folder made before the record existed
    before = _listing(ds.cache)
    for _ in range(2):
        old = _dataset(lens, cache, rendered)
        assert np.array_equal(old.load_or_render(1)["stack"], _fake(1)["stack"].astype(np.float16)) and rendered == [1]
        assert old.check_sources() == "unverified"
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(ds.cache) in err[0] and "unverified" in err[0]  # one line, once per process
    assert _listing(ds.cache) == before and not (ds.cache / SOURCES).exists()
    assert sources_state(ds.cache, {"lens": lens, "psf": None})[0] == "unverified"
    # a file outside the folder rendered with it (a test set's Middlebury item) also makes it one of those
    assert sources_state(tmp_path / "empty", {"lens": lens}, also_held=[lens])[0] == "unverified"
    assert sources_state(tmp_path / "empty", {"lens": lens})[0] == "new"


def test_a_new_folder_is_recorded_and_a_psf_change_is_refused(tmp_path):
    lens, psf, folder = _lens(tmp_path), tmp_path / "psf.onnx", tmp_path / "other"
    psf.write_bytes(b"surrogate A")
    assert check_sources(folder, {"lens": lens, "psf": psf}) == "recorded"
    assert check_sources(folder, {"lens": lens, "psf": psf}) == "verified"  # the same files pass
    psf.write_bytes(b"surrogate B, restamped")
    before = _listing(folder)
    with pytest.raises(ValueError, match=r"other: rendered from psf .*psf.onnx.*fresh --cache"):
        check_sources(folder, {"lens": lens, "psf": psf})
    with pytest.raises(ValueError, match="but psf now none"):
        check_sources(folder, {"lens": lens, "psf": None})
    assert _listing(folder) == before  # a refusal writes nothing


# -- the any-camera renders (training.data.anycam): the traced lens's lens and PSF files -----------------------------
def _anycam_fake(index: int) -> dict:
    from training.data.anycam import RENDER_VERSION

    return {"frames": np.full((4, 3, 8, 8), index / 10, np.float32), "focus_m": np.array([1.0, 2, 3, 4]),
            "depth_m": np.ones((8, 8), np.float32), "aif": np.zeros((3, 8, 8), np.float32),
            "origin": np.array([0, 0], np.int64), "sensor_hw": np.array([8, 8], np.int64),
            "render_version": np.int64(RENDER_VERSION), "camera": json.dumps({"traced": None})}


@pytest.fixture
def traced_copies(tmp_path, monkeypatch):
    """The RF50's lens and PSF files copied to tmp_path, the any-camera renders pointed at the copies."""
    from training.data import anycam

    lens, psf = tmp_path / "rf50.json", tmp_path / "psf_rf50.onnx"
    shutil.copy(ROOT / anycam.TRACED["rf50"][0], lens)
    shutil.copy(ROOT / anycam.TRACED["rf50"][1], psf)
    monkeypatch.setitem(anycam.TRACED, "rf50", (str(lens), str(psf)))
    return lens, psf


def _anycam(cache: Path, rendered: list, **kw):
    from training.data.anycam import AnyCamConfig, AnyCamDataset

    ds = AnyCamDataset(AnyCamConfig(n_items=8, height=8, width=8, margin_px=0, crop=0, cache_dir=str(cache), **kw))
    ds.render = lambda i: rendered.append(i) or _anycam_fake(i)
    return ds


def test_anycam_renders_record_the_traced_files_and_refuse_a_changed_psf_writing_nothing(tmp_path, traced_copies):
    lens, psf = traced_copies
    cache, rendered = tmp_path / "cache", []
    ds = _anycam(cache, rendered)
    ds.load_or_render(0)
    assert json.loads((ds.cache / SOURCES).read_text()) == {
        "rf50_lens": {"path": str(lens), "sha256": sha256_file(lens)},
        "rf50_psf": {"path": str(psf), "sha256": sha256_file(psf)}}
    assert _anycam(cache, rendered).check_sources() == "verified" and rendered == [0]

    psf.write_bytes(psf.read_bytes() + b"\0")  # refitted in place: the same path, so the same key
    before = _listing(ds.cache)
    for read in (lambda d: d.load_or_render(0), lambda d: d.load_or_render(1), lambda d: d.is_cached(2)):
        with pytest.raises(ValueError) as e:
            read(_anycam(cache, rendered))
        assert "\n" not in str(e.value) and str(ds.cache) in str(e.value) and str(psf) in str(e.value)
    with pytest.raises(ValueError, match="rf50_psf"):  # a run reading only the cached items refuses at once
        _anycam(cache, rendered, only_cached=True)
    assert rendered == [0] and _listing(ds.cache) == before  # nothing rendered, written or deleted


def test_anycam_renders_without_a_record_are_unverified_and_not_adopted_into_a_recorded_folder(tmp_path,
                                                                                            traced_copies):
    """The v4-v6 renders (made before the record): read, one warning, nothing written. Items shared with a donor
    config are adopted only where the donor's record vouches for them, or into a folder as unverified as it."""
    from training.data.anycam import AnyCamConfig
    from training.data.cache import save_item

    cache, rendered = tmp_path / "cache", []
    legacy = _anycam(cache, rendered)
    legacy.cache.mkdir(parents=True)
    for i in range(8):  # as the old code left them: items, no sources.json
        save_item(item_path(legacy.cache, i), {**_anycam_fake(i), "camera": np.asarray(_anycam_fake(i)["camera"])})
    before = _listing(legacy.cache)
    run = _anycam(cache, rendered, only_cached=True)
    assert len(run) == 8 and run.check_sources() == "unverified"
    assert np.array_equal(run.load_or_render(3)["frames"], _anycam_fake(3)["frames"])
    assert rendered == [] and _listing(legacy.cache) == before

    # a config whose donor (base config) is that legacy folder
    wide = AnyCamConfig(**{**legacy.cfg.__dict__, "wide_sweep_fraction": 0.5})
    shared = [i for i in range(8) if not _anycam(cache, [], wide_sweep_fraction=0.5).is_wide(i)]
    assert wide.base_config().key() == legacy.cfg.key() and shared
    new = _anycam(cache, rendered, wide_sweep_fraction=0.5)
    assert not any(new.is_cached(i) for i in shared)  # a recorded folder does not take unverified renders
    assert new.check_sources() == "recorded" and not list(new.cache.glob("*.npz"))
    # the donor with a record of the same files: adopted
    (legacy.cache / SOURCES).write_text((new.cache / SOURCES).read_text())
    again = _anycam(cache, rendered, wide_sweep_fraction=0.5)
    assert all(again.is_cached(i) for i in shared) and rendered == []
