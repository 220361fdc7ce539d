"""The on-disk cache of rendered training items (training.data.stacks): one file per item, a record per shard of
the work, and a manifest once every item is there.

A cache folder (`cache_dir/<key>/`, key = `StackDataConfig.key()`, a hash of everything that defines the items):

    000000.npz, 000001.npz, ...   item i: the arrays of `FocalStackDataset.render` (the stack stored as float16)
    shards/<i>-of-<n>.json        what shard i of n did: its items, how many it rendered, when, in how long
    manifest.json                 once all items 0 .. n_items - 1 exist: the data config that defines them, the item
                                  count and the SHA-256 of every item file
    sources.json                  the SHA-256 of the lens and PSF files the items were rendered from: the key holds
                                  their paths, not their contents, so a file corrected in place is caught here.
                                  Written into new folders only: a folder that held items before the record existed
                                  is read as unverified (`check_sources`), never stamped with today's files

Item files are byte-deterministic (an uncompressed zip with fixed timestamps, as np.savez lays it out otherwise),
and an item depends only on (config, index), so a cache filled by n shards in any order, on any number of
machines, equals file for file the cache one process fills; the manifest, which holds no times, is identical too.
Writes are atomic (a temporary file, then a rename): processes that write the same item at once cannot tear it.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import sys
import time
import zipfile
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import atomic_file, write_text_atomic
from training.devices.shard import Shard

MANIFEST_FORMAT = "aat-stack-cache-v1"
SOURCES = "sources.json"
# Renders with focus varying over the field changed at c9c07bd (each anchor's PSF at its own cell size): their
# keys carry this mark so renders cached before it are not read as current. Other renders did not change and keep
# their keys.
FIELD_FOCUS_RENDERER = 2
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # the earliest a zip can hold: no wall-clock time in the bytes


def renderer_marks(effects) -> dict:
    """What to add to a cache key for these effects (aat_deploy.render.effects specs or instances): the mark of
    the renderer's field-varying focus when one of them varies focus over the field, else nothing."""
    from aat_deploy.render import effects as fx

    parsed = [e for e in effects if not isinstance(e, (str, dict))] + fx.parse(
        [e for e in effects if isinstance(e, (str, dict))])
    return {"field_focus_renderer": FIELD_FOCUS_RENDERER} if fx.varies_focus(parsed) else {}


def item_path(cache: Path, index: int) -> Path:
    return Path(cache) / f"{index:06d}.npz"


def save_item(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write `arrays` as an .npz (np.load reads it) whose bytes depend only on the arrays, atomically."""
    with atomic_file(Path(path)) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as z:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME)
            info.external_attr = 0o644 << 16
            with z.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(arrays[name]), allow_pickle=False)


def missing_items(cache: Path, n_items: int) -> list[int]:
    return [i for i in range(n_items) if not item_path(cache, i).is_file()]


def write_shard_record(cache: Path, shard: Shard, n_items: int, rendered: int, seconds: float,
                       device: str = "cpu") -> Path:
    """shards/<i>-of-<n>.json: this shard's share, how many items it rendered now and before, where (a resumed
    shard adds a session) and how many of its items exist."""
    path = Path(cache) / "shards" / f"{shard.index}-of-{shard.count}.json"
    old = json.loads(path.read_text()) if path.is_file() else {}
    mine = shard.items(n_items)
    rec = {"shard": shard.name, "n_items": n_items, "items": len(mine),
           "held": sum(item_path(cache, i).is_file() for i in mine),
           "sessions": old.get("sessions", []) + [{"rendered": rendered, "seconds": round(seconds, 1), "device": device,
                                                   "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}]}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(rec, indent=1) + "\n")
    return path


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_manifest(cache: Path, data_config: dict, n_items: int) -> Path | None:
    """manifest.json when items 0 .. n_items - 1 all exist (None otherwise): the data config that defines them
    (`StackDataConfig` without cache_dir), the count and each item file's SHA-256. Several processes may write
    it at once: they write the same bytes."""
    cache = Path(cache)
    if missing_items(cache, n_items):
        return None
    man = {"format": MANIFEST_FORMAT, "key": cache.name, "n_items": n_items,
           "data": {k: v for k, v in data_config.items() if k not in ("cache_dir", "n_items")},
           "items": {item_path(cache, i).name: sha256_file(item_path(cache, i)) for i in range(n_items)}}
    path = cache / "manifest.json"
    write_text_atomic(path, json.dumps(man, indent=1, sort_keys=True) + "\n")
    return path


def verify_manifest(cache: Path) -> list[str]:
    """Item files that are missing or differ from manifest.json's hashes (empty: the cache is as recorded)."""
    cache = Path(cache)
    man = json.loads((cache / "manifest.json").read_text())
    return [name for name, h in man["items"].items()
            if not (cache / name).is_file() or sha256_file(cache / name) != h]


@functools.lru_cache(maxsize=None)
def _sha256_stat(path: str, mtime_ns: int, size: int) -> str:
    return sha256_file(Path(path))


def sha256_file_cached(path: Path) -> str:
    """sha256_file, hashed once per process per (path, modification time, size): items are read many times."""
    st = os.stat(path)
    return _sha256_stat(str(Path(path).resolve()), st.st_mtime_ns, st.st_size)


def _held_items(cache: Path, also_held=()) -> bool:
    """Whether a cache folder already holds rendered items (or `also_held` files rendered with it exist)."""
    cache = Path(cache)
    return (cache.is_dir() and (any(cache.glob("[0-9]*.npz")) or (cache / "manifest.json").is_file())) or any(
        Path(f).is_file() for f in also_held)


def sources_state(cache: Path, sources: dict[str, Path | None], also_held=()) -> tuple[str, str]:
    """What a cache folder's record says of `sources` ({role: path or None}), without writing anything:
    ("verified", "") when sources.json names the same SHA-256 for every role; ("changed", one-line reason) when it
    names other files or cannot be read; ("unverified", one-line reason) when the folder holds items (or
    `also_held` files exist) but no record: made before the record existed, so what they were rendered from cannot be
    known; ("new", "") when it holds nothing yet."""
    cache = Path(cache)
    rec = cache / SOURCES
    if not rec.is_file():
        if _held_items(cache, also_held):
            return "unverified", (f"{cache}: made before caches recorded their sources ({SOURCES}): cannot check "
                                  f"which lens/PSF files its items were rendered from; read as unverified")
        return "new", ""
    try:
        old = json.loads(rec.read_text())
    except ValueError as e:
        return "changed", f"{rec}: not readable JSON ({e}); render into a fresh --cache directory"
    for role, cur in _sources_now(sources).items():
        was = old.get(role)
        if (was or {}).get("sha256") != (cur or {}).get("sha256"):
            what = f"{cur['path']} now hashes {cur['sha256'][:12]}" if cur else "now none"
            return "changed", (f"{cache}: rendered from {role} {(was or {}).get('path')} with SHA-256 "
                               f"{str((was or {}).get('sha256'))[:12]}, but {role} {what}: its items are of the old "
                               f"file; render into a fresh --cache directory (nothing was deleted)")
    return "verified", ""


def _sources_now(sources: dict[str, Path | None]) -> dict:
    return {role: None if p is None else {"path": str(p), "sha256": sha256_file_cached(p)}
            for role, p in sorted(sources.items())}


_WARNED: set[str] = set()


def check_sources(cache: Path, sources: dict[str, Path | None], also_held=()) -> str:
    """Check a cache folder against the files its items are rendered from (`sources`, {role: path or None}; e.g.
    {"lens": ..., "psf": ...}) before reading or adding items; `sources_state` says how. Returns:

    - "verified": its sources.json names the same SHA-256 for every role;
    - "recorded": a new folder (no items): sources.json written now (the same bytes from every process);
    - "unverified": items but no record (made before it existed): one warning line on stderr (once per process
      and folder) and nothing written: stamping today's hashes would certify items that may be of older files.

    A record naming other files: ValueError, one line, nothing written or deleted."""
    cache = Path(cache)
    state, why = sources_state(cache, sources, also_held)
    if state == "changed":
        raise ValueError(why)
    if state == "unverified":
        if str(cache) not in _WARNED:
            _WARNED.add(str(cache))
            print(f"warning: {why}", file=sys.stderr, flush=True)
        return "unverified"
    if state == "new":
        cache.mkdir(parents=True, exist_ok=True)
        write_text_atomic(cache / SOURCES, json.dumps(_sources_now(sources), indent=1, sort_keys=True) + "\n")
        return "recorded"
    return "verified"
