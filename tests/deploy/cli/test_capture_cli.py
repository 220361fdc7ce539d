"""aat-capture: inspect's exit status says whether aat-infer can run a folder; init writes capture.json (never over
an existing one without --force); plan spaces focus distances evenly in diopters."""

from __future__ import annotations

import json
import math

import pytest
from conftest import ROOT
from deploy_fixtures import write_dng_capture, write_png_capture
from hypothesis import given, settings
from hypothesis import strategies as st

from aat_deploy.capture.folder import read_capture
from aat_deploy.cli import capture as cli

FOCUS = [0.7, 1.2, 2.5]


def test_inspect_exit_status(tmp_path, capsys):
    ok = write_dng_capture(tmp_path / "ok", FOCUS)
    no_focus = write_png_capture(tmp_path / "nofocus", FOCUS, sidecar=False)
    dup = write_dng_capture(tmp_path / "dup", [0.7, 0.7, 2.5])
    assert cli.main(["inspect", str(ok)]) == 0
    assert "ok, 3 frames" in capsys.readouterr().out
    assert cli.main(["inspect", str(no_focus)]) == 1
    err = capsys.readouterr().err
    assert "CANNOT RUN" in err and "no focus distance" in err and "Traceback" not in err
    # a batch: every target is looked at, the status says one cannot be run
    assert cli.main(["inspect", "-q", str(ok), str(dup)]) == 1
    out = capsys.readouterr()
    assert out.out == "" and "duplicate focus distance" in out.err
    assert cli.main(["inspect", "--json", str(ok), str(dup)]) == 1
    rows = json.loads(capsys.readouterr().out)
    assert [r["capture_problem"] is None for r in rows] == [True] * 3 + [False] * 3


def test_inspect_single_file_without_focus_fails(tmp_path, capsys):
    cap = write_png_capture(tmp_path / "c", FOCUS, sidecar=False)
    assert cli.main(["inspect", str(cap / "img_0.png")]) == 1
    assert "no focus distance" in capsys.readouterr().err


def test_init_from_metadata_and_from_focus_list(tmp_path, capsys):
    cap = write_dng_capture(tmp_path / "dng", FOCUS)
    assert cli.main(["init", str(cap)]) == 0
    data = json.loads((cap / "capture.json").read_text())
    assert [f["file"] for f in data["frames"]] == ["frame_00.dng", "frame_01.dng", "frame_02.dng"]
    assert [f["focus_m"] for f in data["frames"]] == pytest.approx(FOCUS)
    assert data["frames"][0]["from"] == "EXIF SubjectDistance"
    assert [f.focus_source for f in read_capture(cap).frames] == ["capture.json"] * 3

    png = write_png_capture(tmp_path / "png", FOCUS, sidecar=False)
    assert cli.main(["init", str(png)]) == 0  # no metadata: a template with nulls to fill in
    assert [f["focus_m"] for f in json.loads((png / "capture.json").read_text())["frames"]] == [None] * 3
    assert "fill in focus_m" in capsys.readouterr().err
    assert cli.main(["inspect", str(png)]) == 1  # still cannot run
    assert cli.main(["init", str(png), "--focus-m", "0.7, 1.2,2.5", "--force"]) == 0
    assert [f.focus_m for f in read_capture(png).frames] == pytest.approx(FOCUS)
    assert (png / "capture.json.bak").is_file()  # the replaced template is kept
    assert cli.main(["inspect", "-q", str(png)]) == 0


def test_init_never_overwrites_without_force(tmp_path, capsys):
    cap = write_png_capture(tmp_path / "c", FOCUS)  # has a capture.json
    before = (cap / "capture.json").read_bytes()
    assert cli.main(["init", str(cap), "--focus-m", "1,2,3"]) == 1
    assert "--force" in capsys.readouterr().err
    assert (cap / "capture.json").read_bytes() == before
    assert cli.main(["init", str(cap), "--focus-m", "1,2,3", "--force"]) == 0
    assert (cap / "capture.json.bak").read_bytes() == before
    assert cli.main(["init", str(cap), "--focus-m", "1,2,4", "--force"]) == 0
    assert (cap / "capture.json.bak2").is_file() and (cap / "capture.json.bak").read_bytes() == before


@pytest.mark.parametrize("focus, message", [("1,2", "gives 2 focus distances"), ("1,x,3", "not a number"),
                                            ("1,-2,3", "not positive"), ("1,2,inf", "infinite")])
def test_init_bad_focus_list_is_a_usage_error(tmp_path, capsys, focus, message):
    cap = write_png_capture(tmp_path / "c", FOCUS, sidecar=False)
    with pytest.raises(SystemExit) as e:
        cli.main(["init", str(cap), "--focus-m", focus])
    assert e.value.code == 2 and message in capsys.readouterr().err
    assert not (cap / "capture.json").exists()


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=40))
def test_focus_list_parses_or_says_why(text):
    try:
        values = cli.parse_focus_list(text)
    except ValueError as e:  # CaptureError, one line naming the entry
        assert str(e).startswith("--focus-m: ") and "\n" not in str(e)
        return
    assert values and all(0 < v <= 1000 and math.isfinite(v) for v in values)


def test_plan_is_even_in_diopters_and_matches_the_sample(capsys):
    fs = cli.plan_focus_m(0.6, 6.0, 8)
    d = [1 / f for f in fs]
    assert fs[0] == pytest.approx(0.6) and fs[-1] == pytest.approx(6.0)
    assert max(d[i] - d[i + 1] for i in range(7)) == pytest.approx(min(d[i] - d[i + 1] for i in range(7)))
    # the shipped sample was rendered with this schedule
    sample = json.loads((ROOT / "captures/sample_rf50/virtual_camera.json").read_text())["focus_m"]
    assert fs == pytest.approx(sample, rel=1e-3)
    assert cli.main(["plan", "--near", "0.6", "--far", "6", "--frames", "8"]) == 0
    assert "0.6,0.6885,0.8077" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        cli.main(["plan", "--near", "2", "--far", "1", "--frames", "8"])
    assert e.value.code == 2
