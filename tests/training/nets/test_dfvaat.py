"""The any-camera net (training.nets.dfvaat): its head interpolates the per-pixel focus diopters, it is no larger
than the small DFVNet, and one ONNX export (dynamic S, H, W) matches torch at shapes other than the export's
(the DFVNet pitfall of shape-derived pooling kernels, reference-facts 7)."""

import pytest
import torch

from training.nets.dfvaat import MIN_DIOPTERS, build, focus_map_head, predict
from training.nets.model import build_model


def test_head_puts_a_pixel_sharpest_in_frame_s_where_that_frame_focuses_at_that_pixel():
    b, s, h, w = 1, 4, 3, 5
    fd = torch.rand(b, s, h, w) + torch.arange(s, 0, -1).float()[None, :, None, None]  # per-pixel, near -> far
    sharpest = torch.randint(0, s, (b, h, w))
    logits = torch.full((b, s, h, w), -50.0).scatter(1, sharpest[:, None], 50.0)
    depth, aif, std, d = focus_map_head(logits, None, fd)
    want = torch.gather(fd, 1, sharpest[:, None])[:, 0]
    assert torch.allclose(d, want, atol=1e-5)
    assert torch.allclose(depth, 1.0 / want, rtol=1e-5)
    assert aif is None and float(std.max()) < 1e-3


def test_head_interpolates_in_diopters_and_clamps_past_infinity():
    fd = torch.tensor([2.0, 0.0])[None, :, None, None]  # a frame at 0.5 m and one at infinity
    depth, _, _, d = focus_map_head(torch.zeros(1, 2, 1, 1), None, fd)
    assert float(d) == pytest.approx(1.0)  # the mean of 2 D and 0 D
    assert float(depth) == pytest.approx(1.0)
    depth, _, _, _ = focus_map_head(torch.tensor([-50.0, 50.0])[None, :, None, None], None, fd)
    assert float(depth) == pytest.approx(1.0 / MIN_DIOPTERS, rel=1e-3)


def test_no_larger_than_the_small_dfvnet():
    assert build().n_params <= build_model("dfvnet", "small").n_params


def test_predict_sorts_frames_and_crops_back():
    torch.manual_seed(0)
    m = build().eval()
    stack = torch.rand(1, 5, 3, 40, 50)
    fd = torch.linspace(3, 0.5, 5)[None, :, None, None].expand(1, 5, 40, 50).contiguous()
    k = torch.full((1, 1, 40, 50), 10.0)
    a = predict(m, stack, fd, k)
    perm = torch.tensor([3, 0, 4, 1, 2])
    b = predict(m, stack[:, perm], fd[:, perm], k)
    assert a["depth_m"].shape == (1, 40, 50)
    assert torch.allclose(a["depth_m"], b["depth_m"], atol=1e-5)
    assert float(a["depth_m"].min()) >= 1 / 3 - 1e-4 and float(a["depth_m"].max()) <= 2 + 1e-4


def test_onnx_export_with_dynamic_stack_and_size_matches_torch_at_other_shapes(tmp_path):
    from training.nets.export import export_focus_map_onnx, focus_map_metadata, parity_focus_map, read_metadata

    torch.manual_seed(1)
    m = build()
    for mod in m.modules():  # non-trivial batch-norm statistics, as a trained net has
        if isinstance(mod, (torch.nn.BatchNorm2d, torch.nn.BatchNorm3d)):
            mod.running_mean.normal_(0, 0.2)
            mod.running_var.uniform_(0.5, 2.0)
    md = focus_map_metadata(m, effects=[], stack_range=(3, 16), config_hash="test", k_range=(0.3, 64))
    path = tmp_path / "m.onnx"
    err = export_focus_map_onnx(m, path, md)
    assert err < 1e-3
    # exported at S = 4, 64 x 64: check S = 3 .. 16 and sizes not seen at export
    assert parity_focus_map(m, path, [(1, 3, 32, 96), (1, 16, 96, 64), (2, 7, 160, 96)]) < 1e-3
    meta = read_metadata(path)
    assert meta["aat.inputs"] == "focus_map" and meta["aat.stack_min"] == "3" and meta["aat.stack_max"] == "16"
    with pytest.raises(FileExistsError):
        export_focus_map_onnx(m, path, md)
