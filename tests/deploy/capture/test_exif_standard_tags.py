"""Why the runtime reads standard EXIF tags with its own reader and not with exifread (docs/shooting.md): on every
real sample, wherever exifread reads Make, Model, LensModel, FocalLength, FNumber or SubjectDistance, our reader
gives the same value; exifread reads nothing at all from several RAW containers our reader handles (CR3, CRW,
RAF, MRW), so the runtime would need our reader anyway. exifread stays a test oracle (the dev extra)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from conftest import ROOT, SHARED

from aat_deploy.capture.exif import read_metadata

exifread = pytest.importorskip("exifread")
TAGS = {"Make": "make", "Model": "model", "LensModel": "lens", "FocalLength": "focal_length_mm",
        "FNumber": "f_number"}


def _samples() -> list[Path]:
    folders = [SHARED / "raw_exif_makernotes_exiftool", SHARED / "raw_decodable_real"]
    if not all(d.is_dir() for d in folders):
        pytest.skip(f"{folders[0]} not present (a user's clone has no ../shared/data)")
    files = [p for d in folders for p in sorted(d.iterdir()) if p.suffix.lower() not in (".md", ".txt", ".json")]
    return files + [ROOT / "captures/sample_rf50/frame_00.dng"]


def _exifread(path: Path) -> dict[str, object]:
    logging.disable(logging.CRITICAL)  # exifread logs every tag it skips
    try:
        with open(path, "rb") as fh:
            tags = exifread.process_file(fh, details=False)
    finally:
        logging.disable(logging.NOTSET)
    out = {}
    for k, v in tags.items():
        name = k.split()[-1]
        if name in (*TAGS, "SubjectDistance") and k.split()[0] in ("Image", "EXIF"):
            val = v.values[0] if isinstance(v.values, list) else v.values
            out[name] = float(val) if name not in ("Make", "Model", "LensModel") else str(val).strip()
    return out


def test_our_reader_agrees_with_exifread_wherever_it_reads():
    compared = 0
    for p in _samples():
        theirs = _exifread(p)
        ours = read_metadata(p, use_exiftool=False)
        for name, v in theirs.items():
            mine = ours.focus_tags.get("SubjectDistance") if name == "SubjectDistance" else getattr(ours, TAGS[name])
            if isinstance(v, float):
                assert mine == pytest.approx(v, rel=1e-9), (p.name, name, mine, v)
            else:
                assert mine == v, (p.name, name, mine, v)
            compared += 1
    assert compared >= 90, compared  # 29 files, 98 values on the shared samples


def test_exifread_reads_nothing_from_raw_containers_we_read():
    files = {p.name: p for p in _samples()}
    for name in ("CanonRaw.cr3", "CanonRaw.crw", "FujiFilm.raf", "Minolta.mrw"):
        assert _exifread(files[name]) == {}, name
        ours = read_metadata(files[name], use_exiftool=False)
        assert ours.make and ours.model, name
    # and two of them carry a focus distance that only a maker-note reader finds
    assert read_metadata(files["CanonRaw.cr3"], use_exiftool=False).focus_m == pytest.approx(0.2296, rel=1e-3)
    assert read_metadata(files["CanonRaw.crw"], use_exiftool=False).focus_m == pytest.approx(1.295, rel=1e-3)


def test_runtime_never_imports_exifread():
    src = [p.read_text() for p in (ROOT / "aat_deploy").rglob("*.py")]
    assert not any("import exifread" in s or "from exifread" in s for s in src)
