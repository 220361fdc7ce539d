"""benchmarks.probes.anycam_compare: two bench_anycam results paired, lens by lens and table row by table row."""

import json

import pytest

from benchmarks.probes import anycam_compare as ac


def scenes(*maes):
    return {"procedural": [{"mae": m, "mae_outer": m} for m in maes]}


def result(dfv_3, dfv_8, classical=(1.0, 1.0, 1.0)):
    """A bench_anycam result holding only the stack-size table (paper lens), three scenes a row."""
    return {"model": "m.onnx", "lenses": {}, "tables": {"n": 3, "stack_size": {
        "3": {"dfv_aat, lens map": scenes(*dfv_3), "Classical, lens map": scenes(*classical)},
        "8": {"dfv_aat, lens map": scenes(*dfv_8), "Classical, lens map": scenes(*classical)}}}}


def test_table_rows_are_paired_row_by_row(tmp_path, capsys):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(result((1.0, 2.0, 3.0), (1.0, 1.0, 1.0))))
    b.write_text(json.dumps(result((2.0, 4.0, 6.0), (1.0, 1.0, 1.0))))
    out = tmp_path / "c.json"
    assert ac.main([str(a), str(b), "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["rows"] == [] and [(e["table"], e["row"], e["n"]) for e in got["tables"]] == [
        ("stack_size", "3", 3), ("stack_size", "8", 3)]
    # A is half of B on every scene of the 3-frame row, so every bootstrap draw is 0.5; equal on the 8-frame row
    assert got["tables"][0]["a_over_b"] == pytest.approx([0.5, 0.5, 0.5])
    assert got["tables"][1]["a_over_b"] == pytest.approx([1.0, 1.0, 1.0])
    assert "| stack_size | 3 | 3 | 2.000 | 4.000 | 0.50 [0.50, 0.50] |" in capsys.readouterr().out


def test_tables_of_other_scenes_are_refused(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(result((1.0, 2.0, 3.0), (1.0, 1.0, 1.0))))
    b.write_text(json.dumps(result((1.0, 2.0, 3.0), (1.0, 1.0, 1.0), classical=(1.0, 2.0, 1.0))))
    with pytest.raises(SystemExit, match="table stack_size, 3: not the same scenes in both files"):
        ac.main([str(a), str(b)])
