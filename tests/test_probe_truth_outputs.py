"""Issue 33's truth probes never overwrite a result (a committed one is their default --out), refuse before any
work, and `truth_annuli --score` refuses two runs of the same draws (their difference is its noise estimate)."""

from __future__ import annotations

import importlib
import json

import pytest

PROBES = ["measured_share", "truth_texture", "truth_renderer", "truth_annuli", "render_truth"]


@pytest.mark.parametrize("name", PROBES)
def test_an_existing_out_is_refused_and_left_as_it_was(name, tmp_path, capsys):
    probe = importlib.import_module(f"benchmarks.probes.{name}")
    out = tmp_path / "r.json"
    out.write_text('{"kept": true}')
    with pytest.raises(SystemExit):
        probe.main(["--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith(f"{out}: exists (choose another --out)")
    assert out.read_text() == '{"kept": true}'


def test_annuli_score_refuses_shared_seeds_and_missing_runs(tmp_path, capsys):
    from benchmarks.probes import truth_annuli

    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"seeds": "1,2,3", "rows": []}))
    b.write_text(json.dumps({"seeds": "3,4", "rows": []}))
    out = tmp_path / "s.json"
    with pytest.raises(SystemExit):
        truth_annuli.main(["--score", f"{a},{a}", "--out", str(out)])
    assert "share seeds 1,2,3" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        truth_annuli.main(["--score", f"{a},{b}", "--out", str(out)])
    assert "share seeds 3" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        truth_annuli.main(["--score", f"{a},{tmp_path / 'none.json'}", "--out", str(out)])
    assert "two existing runs" in capsys.readouterr().err
    assert not out.exists()
