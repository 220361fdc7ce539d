"""The reader on real captures in ../shared/data (phone focal stack, PCB focus sweep, Kodak KDC RAW).
Skipped cleanly when that folder is absent (a user's clone). Frames are linked into tmp folders, never copied
into the repository."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import SHARED
from deploy_fixtures import tiny_model_path

from aat_deploy.capture.exif import read_metadata
from aat_deploy.capture.folder import read_capture
from aat_deploy.capture.raw import load_frame
from aat_deploy.errors import CaptureError
from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.pipeline import Options, run_capture


def _need(sub: str):
    d = SHARED / sub
    if not d.exists():
        pytest.skip(f"{d} not present (a user's clone has no ../shared/data)")
    return d


def _linked(src_files, dst):
    dst.mkdir()
    for f in src_files:
        (dst / f.name).symlink_to(f)
    return dst


def test_kodak_kdc_raw():
    path = _need("raw_decodable_real") / "RAW_KODAK_DC50.KDC"
    rgb, info = load_frame(path)
    assert rgb.shape == (512, 768, 3) and rgb.dtype == np.float32
    assert 0 <= rgb.min() and rgb.max() <= 1 and rgb.mean() > 0.01
    assert info["white_level"] > 0
    meta = read_metadata(path, use_exiftool=False)
    assert meta.focus_m == pytest.approx(8.2) and meta.focus_source == "EXIF SubjectDistance"
    assert meta.focal_length_mm == 37 and meta.f_number == pytest.approx(6.2)


def test_pcb_sweep_needs_focus_then_runs_aligned(tmp_path, tmp_path_factory):
    src = _need("focal_stack_pcb_focusstack")
    files = sorted(src.glob("pcb_*.JPG"))
    cap = _linked(files, tmp_path / "pcb")
    with pytest.raises(CaptureError, match=r"pcb_000\.JPG: a link out of the folder .*--allow-outside-links"):
        read_capture(cap, use_exiftool=False)  # the frames are links to ../shared (issue 31: not followed unasked)
    with pytest.raises(CaptureError, match=r"pcb_000\.JPG: no focus distance.*capture\.json"):
        read_capture(cap, use_exiftool=False, allow_outside_links=True)
    # focus distances unknown for this sweep: a sidecar supplies made-up, increasing ones
    (cap / "capture.json").write_text(json.dumps(
        {"frames": [{"file": f.name, "focus_m": round(0.05 + 0.01 * i, 3)} for i, f in enumerate(files)]}))
    model = DfFModel(tiny_model_path(tmp_path_factory), threads=1)
    s = run_capture(cap, model, tmp_path / "out", Options(quiet=True, record=False, align=True, use_exiftool=False,
                                                          allow_outside_links=True))
    assert s["input_size_px"] == [2048, 1536] and s["output_size_px"] == [64, 48]
    assert len(s["align"]) == 10
    assert any("outside the model's range" in w for w in s["warnings"])
    assert any("focal length 2.5 mm" in w for w in s["warnings"])  # EXIF says another camera
    assert np.isfinite(np.load(tmp_path / "out" / "depth_m.npy")).all()


def test_phone_stack_with_sidecar(tmp_path, tmp_path_factory):
    src = _need("focal_stack_mobiledepth_balls")
    files = sorted(src.glob("*.jpg"))
    values = [float(v) for v in (src / "focus_distance.txt").read_text().split()]
    assert len(values) == len(files) == 10
    cap = _linked(files, tmp_path / "balls")
    (cap / "capture.json").write_text(json.dumps(
        {"frames": [{"file": f.name, "focus_m": v} for f, v in zip(files, values)]}))
    with pytest.raises(CaptureError, match=r"frames\[0\] \('00.jpg'\) needs focus_m > 0 in metres, at most 1000"):
        read_capture(cap, use_exiftool=False, allow_outside_links=True)  # frame 00's 7.2e6 ("infinity")
    files, values = files[1:], values[1:]
    (cap / "capture.json").write_text(json.dumps(
        {"frames": [{"file": f.name, "focus_m": v} for f, v in zip(files, values)]}))
    c = read_capture(cap, use_exiftool=False, allow_outside_links=True)
    assert [f.focus_source for f in c.frames] == ["capture.json"] * 9
    assert any("00.jpg" in w and "not listed" in w for w in c.warnings)
    model = DfFModel(tiny_model_path(tmp_path_factory), threads=1)
    s = run_capture(cap, model, tmp_path / "out", Options(quiet=True, record=False, use_exiftool=False,
                                                          allow_outside_links=True))
    assert s["input_size_px"] == [1280, 720]
    assert any("centre-cropped" in w for w in s["warnings"])  # 16:9 frames, 4:3 model
    assert s["focus_m"] == sorted(values)  # sorted near to far
