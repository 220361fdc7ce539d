"""Virtual-camera DNG writer: files must read back through rawpy (pixels) and exifread (EXIF) like real RAWs."""

from __future__ import annotations

import shutil
import subprocess
import xml.etree.ElementTree as ET
from fractions import Fraction

import exifread
import numpy as np
import pytest
import rawpy

from aat_deploy.capture.dng import write_dng

# XYZ(D65) -> linear sRGB: a "camera" whose RGB is sRGB, so LibRaw's camera -> sRGB matrix must come out ~identity.
XYZ_TO_SRGB = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])
H, W = 64, 96


def _cfa(seed: int = 0, white: int = 4095) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, white + 1, (H, W)).astype(np.uint16)


def _kwargs(**over) -> dict:
    kw = dict(cfa_pattern="RGGB", black_level=64, white_level=4095, color_matrix=XYZ_TO_SRGB,
              as_shot_neutral=(0.5, 1.0, 0.8), subject_distance_m=0.35, focal_length_mm=50.0, f_number=2.8,
              make="AAT", model="Virtual Camera", lens_model="Sim 50mm f/2.8", exposure_time_s=1 / 250, iso=200,
              datetime="2024:05:06 07:08:09")
    kw.update(over)
    return kw


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_rawpy_round_trip(tmp_path, pattern):
    cfa, p = _cfa(), tmp_path / "frame.dng"
    write_dng(p, cfa, **_kwargs(cfa_pattern=pattern))
    with rawpy.imread(str(p)) as raw:
        assert np.array_equal(raw.raw_image_visible, cfa)  # bit-exact, no crop/margins
        # LibRaw numbers the second green 3 and always reports color_desc b"RGBG".
        desc = raw.color_desc.decode()
        assert "".join(desc[i] for i in raw.raw_pattern.ravel()) == pattern
        assert list(raw.black_level_per_channel) == [64] * 4
        assert raw.white_level == 4095
        np.testing.assert_allclose(raw.camera_whitebalance[:3], [1 / 0.5, 1.0, 1 / 0.8], rtol=1e-6)
        # ColorMatrix1 (signed rationals) was read with the XYZ -> camera convention. Entries of size 1 (the bound
        # is relative to them): our 4-digit XYZ_TO_SRGB against LibRaw's own sRGB constants leaves ~1e-4
        np.testing.assert_allclose(raw.color_matrix[:, :3], np.eye(3), atol=2e-3)
        rgb = raw.postprocess()
    assert rgb.shape == (H, W, 3)


def test_exif_round_trip(tmp_path):
    p = tmp_path / "frame.dng"
    write_dng(p, _cfa(), **_kwargs())
    with open(p, "rb") as f:
        tags = exifread.process_file(f)  # details=False would skip tag 700 (XMP)
        plain = exifread.process_file(f, builtin_types=True)
    # Rationals come back as exifread Ratio (a Fraction): printable "7/20", float() gives metres. Exact equality:
    # float() of a ratio of integers is one correctly rounded division, the same on every CPU.
    assert float(tags["EXIF SubjectDistance"].values[0]) == 0.35
    assert str(tags["EXIF SubjectDistance"]) == "7/20"
    assert float(tags["EXIF FocalLength"].values[0]) == 50.0
    assert float(tags["EXIF FNumber"].values[0]) == 2.8
    assert float(tags["EXIF ExposureTime"].values[0]) == 1 / 250
    assert tags["EXIF ISOSpeedRatings"].values == [200]
    assert str(tags["EXIF DateTimeOriginal"]) == "2024:05:06 07:08:09"
    assert str(tags["Image Make"]) == "AAT"
    assert str(tags["Image Model"]) == "Virtual Camera"
    assert str(tags["EXIF LensModel"]) == "Sim 50mm f/2.8"
    assert tags["Image CFAPattern"].values == [0, 1, 1, 2]
    assert plain["EXIF SubjectDistance"] == 0.35 and plain["EXIF FocalLength"] == 50  # builtin_types: float/int
    # XMP copy of the focus distance (exifread exposes tag 700 as "Image ApplicationNotes", a list of bytes).
    xmp = bytes(tags["Image ApplicationNotes"].values).decode("utf-8")
    desc = ET.fromstring(xmp[xmp.index("<x:xmpmeta"):xmp.index("</x:xmpmeta>") + 12]).find(".//{*}Description")
    assert desc.get("{http://ns.adobe.com/exif/1.0/aux/}ApproximateFocusDistance") == "7/20"


def test_optional_fields_omitted_and_awkward_distance(tmp_path):
    p = tmp_path / "frame.dng"
    write_dng(p, _cfa(), **_kwargs(exposure_time_s=None, iso=None, datetime=None, subject_distance_m=1.2345678))
    with open(p, "rb") as f:
        tags = exifread.process_file(f, details=False)
    assert not {"EXIF ExposureTime", "EXIF ISOSpeedRatings", "EXIF DateTimeOriginal"} & set(tags)
    assert float(tags["EXIF SubjectDistance"].values[0]) == pytest.approx(1.2345678, rel=1e-9)  # a close rational


def test_tiff_structure_with_tifffile(tmp_path):
    """A third, independent parser: the EXIF tags really sit in a sub-IFD, not in IFD0."""
    tifffile = pytest.importorskip("tifffile")  # dev extra
    p, cfa = tmp_path / "frame.dng", _cfa()
    write_dng(p, cfa, **_kwargs())
    with tifffile.TiffFile(p) as tif:
        page = tif.pages[0]
        assert tif.is_dng and page.photometric == 32803
        assert "SubjectDistance" not in page.tags and "FocalLength" not in page.tags
        exif = page.tags["ExifTag"].value
        assert exif["SubjectDistance"] == (7, 20) and exif["FocalLength"] == (50, 1)
        assert exif["LensModel"] == "Sim 50mm f/2.8"
        assert np.array_equal(page.asarray(), cfa)


def test_exiftool_cross_check(tmp_path):
    p = tmp_path / "frame.dng"
    write_dng(p, _cfa(), **_kwargs())
    exiftool = shutil.which("exiftool")
    if exiftool is None:
        return  # optional cross-check only; the rawpy/exifread tests above are the required ones
    out = subprocess.run([exiftool, "-n", "-s3", "-EXIF:SubjectDistance", "-XMP-aux:ApproximateFocusDistance",
                          str(p)], capture_output=True, text=True, check=True).stdout.split()
    assert [float(Fraction(v)) for v in out] == [0.35, 0.35]  # Fraction: accepts "0.35" and "7/20"


def test_overwrite_refused_without_force(tmp_path):
    p = tmp_path / "frame.dng"
    write_dng(p, _cfa(0), **_kwargs())
    with pytest.raises(FileExistsError, match="frame.dng"):
        write_dng(p, _cfa(1), **_kwargs())
    write_dng(p, _cfa(1), **_kwargs(), force=True)
    with rawpy.imread(str(p)) as raw:
        assert np.array_equal(raw.raw_image_visible, _cfa(1))
    assert [q.name for q in tmp_path.iterdir()] == ["frame.dng"]  # no temp files left behind


@pytest.mark.parametrize("cfa, over, msg", [
    (_cfa().astype(np.float32), {}, "uint16"),
    (_cfa()[:, :-1], {}, "even"),
    (_cfa()[:20, :20], {}, ">= 22"),
    (_cfa(), {"cfa_pattern": "RGBG"}, "cfa_pattern"),
    (_cfa(white=4096), {}, "exceeds white_level"),
    (_cfa(), {"black_level": 5000}, "black_level < white_level"),
    (_cfa(), {"subject_distance_m": 0.0}, "subject_distance_m"),
    (_cfa(), {"subject_distance_m": float("inf")}, "subject_distance_m"),
    (_cfa(), {"f_number": -2.0}, "f_number"),
    (_cfa(), {"color_matrix": np.eye(2)}, "color_matrix"),
    (_cfa(), {"as_shot_neutral": (1.0, 0.0, 1.0)}, "as_shot_neutral"),
    (_cfa(), {"iso": 70000}, "iso"),
    (_cfa(), {"datetime": "2024-05-06T07:08:09"}, "datetime"),
    (_cfa(), {"lens_model": "Objektiv \u00fc"}, "lens_model"),
])
def test_bad_inputs(tmp_path, cfa, over, msg):
    p = tmp_path / "bad.dng"
    with pytest.raises(ValueError, match=msg) as e:
        write_dng(p, cfa, **_kwargs(**over))
    assert "\n" not in str(e.value)
    assert not p.exists() and not list(tmp_path.iterdir())
