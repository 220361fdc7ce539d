"""ONNX export of the DfF nets: onnxruntime equals torch up to float32 rounding (`PARITY_TOL` of the inputs'
magnitude) at three (S, H, W) other than the export shape; metadata."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import LENSES

from aat_deploy.lens.io import load_lens
from training.nets.export import PARITY_TOL, dff_metadata, export_dff_onnx, parity, read_metadata
from training.nets.model import build_model

pytestmark = pytest.mark.numerics  # torch vs onnxruntime

CONTRACT_KEYS = ("aat.kind", "aat.net", "aat.size", "aat.simulator", "aat.effects", "aat.lens_name", "aat.lens_hash",
                 "aat.focal_length_mm", "aat.f_number", "aat.sensor_mm", "aat.sensor_px", "aat.pixel_um",
                 "aat.focus_range_m", "aat.stack_min", "aat.stack_max", "aat.size_multiple",
                 "aat.input_normalisation", "aat.config_hash", "aat.version", "aat.distances")
SHAPES = [(1, 5, 64, 96), (2, 3, 32, 32), (1, 9, 96, 64)]  # (B, S, H, W); the export traces (1, 4, 64, 64)


@pytest.fixture(scope="module")
def lens():
    return load_lens(LENSES / "canon_rf50mm_f1.8.json")


def _trained_like(net: str) -> torch.nn.Module:
    """Small model with non-trivial batch-norm statistics (as after training), in eval mode."""
    torch.manual_seed(3)
    model = build_model(net, "small")
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, (torch.nn.BatchNorm2d, torch.nn.BatchNorm3d)):
                m.running_mean.uniform_(-0.2, 0.2)
                m.running_var.uniform_(0.5, 2.0)
    return model.eval()


@pytest.mark.parametrize("net", ["aifnet", "dfvnet"])
def test_export_parity_and_metadata(tmp_path, lens, net):
    model = _trained_like(net)
    md = dff_metadata(model, lens, simulator="aat", effects=["psf"], focus_range_m=(0.5, 5.0), stack_range=(2, 16),
                      config_hash="0123456789abcdef")
    out = tmp_path / f"{net}.onnx"
    err_export = export_dff_onnx(model, out, md, check_shapes=SHAPES[:1])
    err = parity(model, out, SHAPES)
    print(f"{net}: ORT vs torch relative diff {err:.2e} at {SHAPES}")
    assert err <= PARITY_TOL and err_export <= PARITY_TOL
    got = read_metadata(out)
    for k in CONTRACT_KEYS:
        assert got.get(k), k
    assert got["aat.kind"] == "dff" and got["aat.net"] == net and got["aat.size"] == "small"
    assert got["aat.lens_hash"] == lens.prescription_hash() and got["aat.lens_name"] == lens.name
    assert json.loads(got["aat.sensor_px"]) == [lens.sensor.width_px, lens.sensor.height_px]
    assert json.loads(got["aat.focus_range_m"]) == [0.5, 5.0] and json.loads(got["aat.effects"]) == ["psf"]
    assert got["aat.stack_min"] == "2" and got["aat.stack_max"] == "16" and got["aat.size_multiple"] == "32"
    assert 45 < float(got["aat.focal_length_mm"]) < 55 and 1.5 < float(got["aat.f_number"]) < 2.2
    assert not list(tmp_path.glob("*.tmp"))
    with pytest.raises(FileExistsError, match="force"):
        export_dff_onnx(model, out, md)


def test_onnx_io_names_and_dynamic_axes(tmp_path, lens):
    import onnx

    model = _trained_like("dfvnet")
    md = dff_metadata(model, lens, simulator="thin_lens", effects=[], focus_range_m=(0.5, 5.0),
                      stack_range=(2, 16), config_hash="x")
    out = tmp_path / "m.onnx"
    export_dff_onnx(model, out, md, check_shapes=[(1, 2, 32, 64)])
    g = onnx.load(str(out)).graph
    assert [i.name for i in g.input] == ["stack", "focus_m"]
    assert [o.name for o in g.output] == ["depth_m", "aif", "std_m"]
    dims = [d.dim_param or d.dim_value for d in g.input[0].type.tensor_type.shape.dim]
    assert dims == ["B", "S", 3, "H", "W"]


def test_metadata_rejects_bad_simulator(lens):
    with pytest.raises(ValueError, match="simulator"):
        dff_metadata(build_model("aifnet", "small"), lens, simulator="gauss", effects=[], focus_range_m=(1, 2),
                     stack_range=(2, 8), config_hash="x")


def test_parity_detects_a_different_model(tmp_path, lens):
    model = _trained_like("aifnet")
    md = dff_metadata(model, lens, simulator="aat", effects=[], focus_range_m=(0.5, 5.0), stack_range=(2, 8),
                      config_hash="x")
    out = tmp_path / "a.onnx"
    export_dff_onnx(model, out, md, check_shapes=[(1, 3, 32, 32)])
    with torch.no_grad():
        model.net.out.bias += 1.0  # a logit shift common to all frames changes nothing: softmax is shift-invariant
        assert parity(model, out, [(1, 3, 32, 32)]) < PARITY_TOL
        model.net.out.weight.mul_(3.0)
    assert parity(model, out, [(1, 3, 32, 32)]) > 10 * PARITY_TOL
    assert np.isfinite(parity(model, out, [(1, 2, 64, 32)]))


def test_export_trained_checkpoint(tmp_path):
    from training_fixtures import TwoPlaneStacks, train_config

    from training.train.export import export_checkpoint
    from training.train.loop import train

    cfg = train_config(net="aifnet", steps=2, simulator="aat", effects=["psf"])
    train(cfg, tmp_path / "run", train_set=TwoPlaneStacks(n=4), progress=False)
    md, err = export_checkpoint(tmp_path / "run" / "model.pt", tmp_path / "m.onnx")
    assert err <= PARITY_TOL
    got = read_metadata(tmp_path / "m.onnx")
    assert got == md
    assert got["aat.simulator"] == "aat" and got["aat.config_hash"] == cfg.hash() and got["aat.train_steps"] == "2"


@pytest.mark.parametrize("net", ["aifnet", "dfvnet"])
def test_field_aware_export_runs_in_the_runtime(tmp_path, lens, net):
    """A field-aware model exports with a third input `field_xy`; the runtime feeds each pixel's sensor position
    (the whole sensor by default, tiles their own part) and matches torch's predict on an unpadded size."""
    from aat_deploy.infer.model import DfFModel as RuntimeModel
    from aat_deploy.optics.field import pixel_fields
    from training.nets.model import predict

    torch.manual_seed(3)
    model = build_model(net, "small", field_channels=2).eval()
    md = dff_metadata(model, lens, simulator="aat", effects=[], focus_range_m=(0.5, 5.0), stack_range=(2, 16),
                      config_hash="0123456789abcdef")
    out = tmp_path / f"{net}_field.onnx"
    export_dff_onnx(model, out, md, check_shapes=SHAPES[:1])
    got = read_metadata(out)
    assert got["aat.field_channels"] == "2" and "field_xy" in got["aat.field_convention"]
    rt = RuntimeModel(out)
    assert rt.field_aware
    rng = np.random.default_rng(0)
    stack = rng.random((5, 3, 70, 100)).astype(np.float32)
    focus = np.array([0.5, 0.8, 1.2, 2.0, 4.0], np.float32)
    field = torch.from_numpy(np.stack(pixel_fields(70, 100, (70, 100))).astype(np.float32))[None]
    with torch.no_grad():
        ref = predict(model, torch.from_numpy(stack)[None], torch.from_numpy(focus)[None], field)["depth_m"][0]
    depth = rt.infer(stack, focus).depth_m
    # float32 through ~40 conv layers, then a softmax-weighted mean of focus distances of a few metres:
    # relative 1e-4 of the depth is ~20x the rounding seen (the parity checks above allow 1e-3 of the focus range)
    np.testing.assert_allclose(depth, ref.numpy(), rtol=1e-4, atol=0)
    assert not np.allclose(depth, rt.infer(stack, focus, field_xy=np.zeros((2, 70, 100), np.float32)).depth_m)
