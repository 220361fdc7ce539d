"""bench_anycam: its results file grows command by command (one lens, one protocol, one table at a time), a rerun
resumes instead of recomputing, and a file of another model or setting is refused with one line."""

import json
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench():
    from benchmarks import bench_anycam

    return bench_anycam


def fake_set(n: int, seed: int) -> dict:
    """{"procedural": n items, "middlebury": 1} of 5 x 3 x 24 x 32 stacks with a plane at 1-3 m."""
    from training.train.testsets import TestItem

    rng = np.random.default_rng(seed)

    def item(name):
        depth = np.full((24, 32), 1.0 + 2.0 * rng.random(), np.float32)
        return TestItem(name, rng.random((5, 3, 24, 32), dtype=np.float32), np.linspace(0.5, 5, 5).astype(np.float32),
                        depth, rng.random((3, 24, 32), dtype=np.float32))

    return {"procedural": [item(f"procedural_{i:03d}") for i in range(n)], "middlebury": [item("middlebury")]}


@pytest.fixture
def fakes(bench, monkeypatch):
    """methods() -> two 'methods' (depth off by 10 % and 20 %), load_test_set -> fake sets; counts the calls."""
    calls = {"methods": 0, "sets": 0}

    def methods(model_path, lens_key, threads, tile=None):
        calls["methods"] += 1
        return {bench.DFV_MAP: lambda it: (it.depth_m * 1.1, it.aif), bench.CL_MAP: lambda it: (it.depth_m * 1.2, it.aif)}

    def load_test_set(spec, cache=None, progress=True):
        calls["sets"] += 1
        return fake_set(spec.n_procedural, spec.stack_size)

    import training.train.testsets as ts

    monkeypatch.setattr(bench, "methods", methods)
    monkeypatch.setattr(ts, "load_test_set", load_test_set)
    return calls


def test_results_grow_per_command_and_a_rerun_resumes(bench, fakes, tmp_path, capsys):
    model = tmp_path / "m.onnx"
    model.write_bytes(b"model one")
    args = ["--model", str(model), "--n", "3", "--out", str(tmp_path), "--label", "t", "--threads", "1"]
    assert bench.main(args + ["--lenses", "paper50", "--protocol", "fixed"]) == 0
    path = tmp_path / "anycam_t.json"
    r = json.loads(path.read_text())
    assert r["model_sha256"] == bench.model_id(model) and list(r["lenses"]) == ["paper50"]
    per = r["lenses"]["paper50"]["fixed"]["per_image"]
    assert len(per[bench.DFV_MAP]["procedural"]) == 3
    # the paired ratio of a 10 % and a 20 % overestimate on every scene
    ratio = r["lenses"]["paper50"]["fixed"]["ratios"][0]["procedural"]
    assert ratio[0] == pytest.approx(0.1 / 0.2, rel=1e-6)
    assert (fakes["methods"], fakes["sets"]) == (1, 1)
    # another protocol adds to the same file; the first is kept and reprinted, not recomputed
    capsys.readouterr()
    assert bench.main(args + ["--lenses", "paper50", "--protocol", "fixed", "paper"]) == 0
    out = capsys.readouterr().out
    assert "#### paper50, fixed protocol" in out and "#### paper50, paper protocol" in out
    assert fakes["sets"] == 2
    r = json.loads(path.read_text())
    assert set(r["lenses"]["paper50"]) == {"fixed", "paper"}
    # one table, then the other, then a rerun that computes nothing
    assert bench.main(args + ["--lenses", "--tables", "stack_size"]) == 0
    assert fakes["sets"] == 2 + len(bench.STACK_SIZES)
    r = json.loads(path.read_text())
    assert r["tables"]["n"] == 8 and list(r["tables"]["stack_size"]) == [str(s) for s in bench.STACK_SIZES]
    assert bench.main(args + ["--lenses", "--tables", "schedule"]) == 0
    n_sets = fakes["sets"]
    capsys.readouterr()
    assert bench.main(args + ["--lenses", "paper50", "--protocol", "fixed", "paper", "--tables"]) == 0
    assert fakes["sets"] == n_sets
    out = capsys.readouterr().out
    assert "MAE by stack size" in out and "MAE by schedule" in out and "| 16 |" in out
    r2 = json.loads(path.read_text())
    assert set(r2["tables"]) == {"n", "stack_size", "schedule"} and set(r2["lenses"]["paper50"]) == {"fixed", "paper"}


def test_a_file_of_another_model_or_setting_is_refused_unless_forced(bench, fakes, tmp_path):
    model = tmp_path / "m.onnx"
    model.write_bytes(b"model one")
    args = ["--model", str(model), "--out", str(tmp_path), "--lenses", "rf50", "--protocol", "fixed", "--threads", "1"]
    assert bench.main(args + ["--n", "2"]) == 0
    path = tmp_path / "anycam.json"
    before = path.read_text()
    with pytest.raises(SystemExit, match=r"anycam\.json: made with another setting \(n 2 here, 3 now\)"):
        bench.main(args + ["--n", "3"])
    model.write_bytes(b"a better model, same name")
    with pytest.raises(SystemExit, match="model_sha256"):
        bench.main(args + ["--n", "2"])
    assert path.read_text() == before  # refused: the file is untouched
    assert bench.main(args + ["--n", "2", "--force"]) == 0
    assert json.loads(path.read_text())["model_sha256"] == bench.model_id(model)
    old = json.loads(path.read_text())
    del old["overlap"]  # a file of the runtime before own_tiles (its tiles overlapped by a quarter)
    path.write_text(json.dumps(old))
    with pytest.raises(SystemExit, match=r"overlap None here, '0.125 of aat.tile_px' now"):
        bench.main(args + ["--n", "2"])
    path.write_text("{not json")
    with pytest.raises(SystemExit, match=r"anycam\.json: not a results file"):
        bench.main(args + ["--n", "2"])


def test_the_tables_rows(bench):
    rows = bench.table_specs("stack_size", 8)
    assert [s.stack_size for s in rows.values()] == list(bench.STACK_SIZES)
    assert all(s.lens == "lenses/paper_50mm_f2.8.json" and not s.middlebury for s in rows.values())
    sched = bench.table_specs("schedule", 8)
    assert [s.protocol for s in sched.values()] == ["fixed", "fixed", "paper", "fixed"]
    phone = sched["phone-like (5 frames over 0.5-2 m)"]
    assert (phone.stack_size, phone.focus_near_m, phone.focus_far_m) == (5, 0.5, 2.0)
    assert Path(bench.LENSES["paper50"]["lens"]).name == "paper_50mm_f2.8.json"
