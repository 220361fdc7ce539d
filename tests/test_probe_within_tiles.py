"""benchmarks/probes/within_tiles: bad arguments are one line before any variant is run and nothing is written; its
--out (a committed results file by default) is never replaced."""

from __future__ import annotations

import json

import pytest

from benchmarks.probes import phone_map_model
from benchmarks.probes import within_tiles as wt


@pytest.fixture
def dumps(tmp_path, monkeypatch):
    cache = tmp_path / "mapmodel"
    cache.mkdir()
    monkeypatch.setattr(phone_map_model, "CACHE", cache)
    for v in ("nominal", "copy"):
        (cache / f"cellphone_near_{v}.npz").write_bytes(b"")
    ran = []
    monkeypatch.setattr(wt, "run", lambda v, ests, log: ran.append(v) or {"variant": v})
    monkeypatch.setattr(wt, "jitter", lambda v, n, sd, log: ran.append(v) or {})
    monkeypatch.setattr(wt, "table", lambda res: "")
    return ran


@pytest.mark.parametrize("args, says", [
    (["--variants", "nominal,copy_s1_9x"], "--variants copy_s1_9x: not among"),
    (["--variants", "nominal", "--estimators", "parabola,gausss"], "--estimators gausss: not among"),
    (["--variants", "nominal", "--jitter", "-1"], "--jitter: 0 or more"),
    (["--variants", "nominal", "--jitter", "3", "--jitter-sd", "0"], "--jitter-sd: above 0 D"),
    (["--variants", "nominal,copy_s2026_1"], "no dump of copy_s2026_1 (run phone_map_model --dump"),
])
def test_bad_arguments_are_one_line_before_any_work(dumps, tmp_path, capsys, args, says):
    out = tmp_path / "w.json"
    with pytest.raises(SystemExit):
        wt.main(args + ["--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert says in err[-1] and not err[-1].startswith("usage") and dumps == [] and not out.exists()


def test_out_is_never_replaced_and_good_arguments_run(dumps, tmp_path, capsys):
    out = tmp_path / "w.json"
    out.write_text("mine")
    with pytest.raises(SystemExit):
        wt.main(["--variants", "nominal", "--out", str(out)])
    assert "w.json: exists" in capsys.readouterr().err and out.read_text() == "mine" and dumps == []
    fresh = tmp_path / "v.json"
    assert wt.main(["--variants", "nominal,copy", "--out", str(fresh)]) == 0
    assert dumps == ["nominal", "copy"] and [v["variant"] for v in json.loads(fresh.read_text())["variants"]] == [
        "nominal", "copy"]
