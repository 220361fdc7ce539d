"""bench_runtime: the any-camera net's speed row against the DFVNet's of the same size, in one run (issue 35)."""

import json

import pytest


def test_the_ratio_pairs_each_any_camera_row_with_the_dfvnet_of_its_size():
    pytest.importorskip("torch")
    from benchmarks.bench_runtime import anycam_ratios

    rows = [("dfvnet small", 1.4, 0.4, 0.0), ("dfvnet big", 3.0, 2.0, 0.0), ("aifnet small", 2.0, 1.0, 0.0),
            ("dfvaat small (any camera, whole frame)", 1.0, 0.5, 0.0),
            ("dfvaat big (any camera as shipped: tiles of 128 px, 32 overlapping)", 1.0, 3.0, 0.0),
            ("dfvaat tiny (no dfvnet of this size)", 1.0, 1.0, 0.0)]
    assert anycam_ratios(rows) == {"dfvaat small (any camera, whole frame)": pytest.approx(1.25),
                                   "dfvaat big (any camera as shipped: tiles of 128 px, 32 overlapping)": 1.5}
    assert anycam_ratios(rows[:3]) == {}


def test_a_small_run_writes_both_nets_and_their_ratio(tmp_path, capsys):
    pytest.importorskip("torch")
    from benchmarks.bench_runtime import main

    out = tmp_path / "runtime.json"
    main(["--hw", "64x96", "--stack", "3", "--nets", "dfvnet,dfvaat", "--threads", "1", "--tile", "64",
          "--rounds", "2", "--json", str(out)])
    r = json.loads(out.read_text())
    names = [row["net"] for row in r["rows"]]
    assert names[0] == "dfvnet small" and len(names) == 3 and "tiles of 64 px" in names[2]
    assert r["threads"] == 1 and r["stack"] == [3, 3, 64, 96]
    dfv = r["rows"][0]["runtime_s"]
    assert r["anycam_over_dfvnet"][names[1]] == pytest.approx(r["rows"][1]["runtime_s"] / dfv)
    turns = r["rounds_in_turn_s"]["small"]
    assert list(turns)[0] == "DFVNet" and len(turns) == 5 and all(len(v) == 2 for v in turns.values())
    assert "16 px overlap, one per run (the runtime before" in list(turns)[4]
    assert "8 px overlap, batched" in list(turns)[2] and "8 px overlap, one per run" in list(turns)[3]
    out = capsys.readouterr().out
    assert "its time / the DFVNet's" in out and "2 rounds in turn" in out
