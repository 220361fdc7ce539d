"""benchmarks.bench_route: the shipped routed file against the nets it names, on a small input."""

import json

from benchmarks import bench_route

MODEL = bench_route.ROOT / "models" / "reproduce" / "dfv_aat_route_v12_v10.onnx"


def test_each_size_is_timed_against_the_net_it_routes_to_and_changes_nothing(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert bench_route.main(["--model", str(MODEL), "--hw", "64x96", "--stacks", "3,7,8", "--rounds", "1",
                             "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["net"] for r in rows] == ["dfv_aat_v12_s19200.onnx"] * 2 + ["dfv_aat_v10_s23200.onnx"]
    assert all(r["max_depth_diff_m"] <= 1e-5 for r in rows)
    assert "| 8 | dfv_aat_v10_s23200.onnx |" in capsys.readouterr().out


def test_refuses_a_model_that_routes_nothing(tmp_path, capsys):
    plain = bench_route.ROOT / "models" / "reproduce" / "dfv_aat_v10_s23200.onnx"
    assert bench_route.main(["--model", str(plain), "--rounds", "1"]) == 2
    assert "not a routed model" in capsys.readouterr().err
