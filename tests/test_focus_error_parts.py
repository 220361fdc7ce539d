"""benchmarks/probes/focus_error_parts.py never writes over a results file it reads."""

import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_out_that_is_an_input_is_refused_and_left_unchanged(tmp_path, monkeypatch):
    from benchmarks.probes import focus_error_parts

    src = tmp_path / "rows.jsonl"
    shutil.copy(ROOT / "results" / "diagnose_focus_fresh2_fitonly_v2.jsonl", src)
    before = src.read_bytes()
    monkeypatch.setattr(sys, "argv", ["focus_error_parts", str(src), "--out", str(src)])
    with pytest.raises(SystemExit, match="is one of the results read"):
        focus_error_parts.main()
    assert src.read_bytes() == before
    out = tmp_path / "parts.md"
    monkeypatch.setattr(sys, "argv", ["focus_error_parts", str(src), "--out", str(out)])
    focus_error_parts.main()
    assert out.read_text().startswith("# Where the per-frame focus estimates' errors come from")


def test_scene_coverage_probe_refuses_an_out_it_reads(tmp_path, monkeypatch):
    """benchmarks/probes/focus_scene_coverage.py: --out naming a --nuisance input is refused before any work."""
    from benchmarks.probes import focus_scene_coverage

    src = tmp_path / "rows.jsonl"
    shutil.copy(ROOT / "results" / "diagnose_focus_fresh3_fitonly.jsonl", src)
    before = src.read_bytes()
    monkeypatch.setattr(sys, "argv", ["focus_scene_coverage", "scene2038:none", "--nuisance", str(src),
                                      "--out", str(src)])
    with pytest.raises(SystemExit, match="is one of the results read"):
        focus_scene_coverage.main()
    assert src.read_bytes() == before
