"""training.train.route: one ONNX file running the few-frame net up to T frames and the other above."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from training.train.route import main, route_by_stack_size

ROOT = Path(__file__).resolve().parents[3]
SMALL = ROOT / "models" / "reproduce" / "dfv_aat_v12_s19200.onnx"
LARGE = ROOT / "models" / "reproduce" / "dfv_aat_v10_s23200.onnx"


def _session(path):
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def _feeds(s: int, rng) -> dict:
    h, w = 32, 64
    focus = np.sort(rng.uniform(0.1, 4.0, s))[::-1].astype(np.float32)  # diopters, near to far
    return {"stack": rng.random((1, s, 3, h, w), dtype=np.float32),
            "focus_diopters": np.broadcast_to(focus[None, :, None, None], (1, s, h, w)).copy(),
            "defocus_px_per_d": np.full((1, 1, h, w), 6.0, np.float32)}


@pytest.fixture(scope="module")
def routed(tmp_path_factory):
    out = tmp_path_factory.mktemp("route") / "routed.onnx"
    meta = route_by_stack_size(SMALL, LARGE, 5, out)
    return out, meta


def test_each_stack_size_runs_the_net_it_is_routed_to(routed):
    out, _ = routed
    r, a, b = _session(out), _session(SMALL), _session(LARGE)
    rng = np.random.default_rng(7)
    for s in (3, 5, 6, 9):
        f = _feeds(s, rng)
        got = r.run(None, f)
        want, other = (a, b) if s <= 5 else (b, a)
        exp, oth = want.run(None, f), other.run(None, f)
        for g, e, o in zip(got, exp, oth):
            scale = float(np.abs(e).max()) + 1e-6
            assert float(np.abs(g - e).max()) <= 1e-6 * scale, s  # the same graph, its weights folded alike
        # the two nets differ on this input, so matching one is not matching both
        assert float(np.abs(got[0] - oth[0]).max()) > 1e-2, s


def test_metadata_keeps_the_contract_and_says_what_it_routes(routed):
    out, meta = routed
    from aat_deploy.anycam.model import FocusMapModel

    m = FocusMapModel(out, threads=1)
    assert m.stack_range == (3, 16) and m.size_multiple == 32 and m.tile_px == 0
    assert m.meta["aat.size"] == "small_replicate"  # the speed row times a net of this size
    route = m.meta["aat.route"]  # read as JSON by the runtime
    assert route == json.loads(meta["aat.route"])
    assert route["max_small_frames"] == 5
    assert route["small"]["config_name"] == "dfv_aat_v12" and route["large"]["config_name"] == "dfv_aat_v10"
    assert route["small"]["checkpoint_step"] == "19200" and route["large"]["checkpoint_step"] == "23200"
    assert int(meta["aat.n_params"]) == 2 * int(meta["aat.n_params_per_call"])  # two nets of one size
    assert m.summary()["route"]["max_small_frames"] == 5


def test_refuses_what_it_cannot_route(tmp_path):
    out = tmp_path / "r.onnx"
    lens_model = ROOT / "models" / "rf50_dfvnet_aat.onnx"
    with pytest.raises(ValueError, match="rf50_dfvnet_aat.onnx: not an any-camera model"):
        route_by_stack_size(lens_model, LARGE, 5, out)
    with pytest.raises(ValueError, match="max_small_frames 16 must be in"):
        route_by_stack_size(SMALL, LARGE, 16, out)
    assert not out.exists()
    out.write_bytes(b"user's file")
    with pytest.raises(FileExistsError, match="use --force"):
        route_by_stack_size(SMALL, LARGE, 5, out)
    assert out.read_bytes() == b"user's file"


def test_a_routed_file_is_not_routed_again(routed, tmp_path):
    with pytest.raises(ValueError, match="is itself a routed model"):
        route_by_stack_size(routed[0], LARGE, 5, tmp_path / "again.onnx")


def test_cli_one_line_errors(tmp_path, capsys):
    assert main([str(tmp_path / "missing.onnx"), str(LARGE), "--max-small-frames", "5",
                 "--out", str(tmp_path / "o.onnx")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "missing.onnx: no such model file" in err
    assert not (tmp_path / "o.onnx").exists()


def test_a_file_that_is_not_onnx_is_refused_in_one_line(tmp_path, capsys):
    bad = tmp_path / "notes.onnx"
    bad.write_text("not a model\n")
    assert main([str(bad), str(LARGE), "--max-small-frames", "5", "--out", str(tmp_path / "o.onnx")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "notes.onnx: not an ONNX model" in err
    assert not (tmp_path / "o.onnx").exists()


def test_the_routed_file_imports_every_opset_domain_either_net_uses(tmp_path):
    import onnx
    from onnx import helper

    small = onnx.load(str(SMALL))
    small.opset_import.append(helper.make_opsetid("ai.onnx.ml", 3))  # a domain only the small net declares
    path = tmp_path / "small_ml.onnx"
    onnx.save(small, str(path))
    route_by_stack_size(path, LARGE, 5, tmp_path / "r.onnx")
    got = {(o.domain, o.version) for o in onnx.load(str(tmp_path / "r.onnx")).opset_import}
    assert got == {("", 17), ("ai.onnx.ml", 3)}
