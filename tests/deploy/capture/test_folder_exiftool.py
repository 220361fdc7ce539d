"""read_capture runs exiftool (one process per frame) only as the focus distance's fallback: not when capture.json
or --focus-m gives the distances (issue 34: it cost ~0.2 s a frame on a 12-MP capture whose capture.json had them)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from deploy_fixtures import write_jpeg_capture

from aat_deploy.capture import exiftool
from aat_deploy.capture.folder import SIDECAR, read_capture
from aat_deploy.errors import CaptureError

FOCUS = [0.5, 1.0, 2.0]


@pytest.fixture
def asked(monkeypatch):
    """The files exiftool is asked about (a stand-in exiftool that finds nothing)."""
    calls = []
    empty = SimpleNamespace(focus_tags={}, focus_m=None, focus_source=None, make=None, model=None, lens=None,
                            focal_length_mm=None, f_number=None, focal_length_35mm=None, focal_plane_px_per_mm=None)
    monkeypatch.setattr(exiftool, "available", lambda: True)
    monkeypatch.setattr(exiftool, "read", lambda p: calls.append(p.name) or empty)
    return calls


def test_exiftool_is_not_run_when_capture_json_or_focus_m_give_the_distances(asked, tmp_path):
    cap = write_jpeg_capture(tmp_path / "cap", FOCUS)  # frames without EXIF, focus in capture.json
    c = read_capture(cap)
    assert [f.focus_m for f in c.frames] == FOCUS and [f.focus_source for f in c.frames] == [SIDECAR] * 3
    assert asked == []
    (cap / SIDECAR).unlink()
    c = read_capture(cap, focus_m=FOCUS)
    assert [f.focus_source for f in c.frames] == ["--focus-m"] * 3 and asked == []
    with pytest.raises(CaptureError, match="no focus distance in its metadata"):  # the fallback still asked
        read_capture(cap)
    assert asked == ["img_0.jpg", "img_1.jpg", "img_2.jpg"]
    asked.clear()
    with pytest.raises(CaptureError):
        read_capture(cap, use_exiftool=False)
    assert asked == []
