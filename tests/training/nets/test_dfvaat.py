"""The any-camera net (training.nets.dfvaat): its head interpolates the per-pixel focus diopters, it is no larger
than the small DFVNet, and one ONNX export (dynamic S, H, W) matches torch at shapes other than the export's
(the DFVNet pitfall of shape-derived pooling kernels, reference-facts 7)."""

import math
from pathlib import Path

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


def _definition_logits(m, stack, fd, k):
    """The conditioned net's logits by the definition the first export computed: both `focus_channels` of every frame
    at full resolution, average-pooled to each level's scale and projected by its 1x1 convolution."""
    import torch.nn.functional as F

    from training.nets.dfvaat import focus_channels

    net = m.net
    b, s, c, h, w = stack.shape
    feats = net.encoder(stack.reshape(b * s, c, h, w))
    flat = focus_channels(fd, k).reshape(b * s, 2, h, w)
    for i, proj in enumerate(net.cond):
        feats[i] = feats[i] + proj(F.avg_pool2d(flat, 4 * 2**i, 4 * 2**i))
    return net.decode(feats, b, s)


@pytest.mark.parametrize("shape", [(1, 3, 32, 96), (2, 7, 64, 64), (1, 16, 96, 32)])
def test_conditioning_in_its_cheaper_order_equals_its_definition(shape):
    from training.nets.dfvaat import cond_inputs
    from training.nets.export import _focus_map_example

    torch.manual_seed(2)
    m = build().eval()
    for conv in m.net.cond:  # weights of a trained net's size, bias included
        conv.weight.data.normal_(0, 0.5)
        conv.bias.data.normal_(0, 0.5)
    stack, fd, k = _focus_map_example(*shape, seed=5)
    with torch.no_grad():
        want = _definition_logits(m, stack, fd, k)
        got = m.net(stack, *cond_inputs(fd, k))
    for g, w in zip(got, want):
        scale = float(w.abs().max())
        assert scale > 1e-2 and float((g - w).abs().max()) < 1e-5 * scale


def test_the_export_of_the_first_runs_checkpoint_matches_its_first_export_and_has_no_softmax(tmp_path):
    """The current export of checkpoints/dfv_aat_v1 (cheaper conditioning, the head's softmax written as exp / sum:
    onnxruntime's Softmax on the frame axis is 7x slower) against the file the first export wrote from the same
    weights, models/reproduce/dfv_aat_v1.onnx, on random inputs at S, H, W the export never saw: within 1e-5 of
    the outputs' scale (measured <= 4e-7); same inputs, outputs, dynamic axes and metadata (plus the step now recorded)."""
    import numpy as np
    import onnx
    import onnxruntime as ort

    from training.nets.export import _focus_map_example, read_metadata
    from training.train.export import export_checkpoint

    root = Path(__file__).resolve().parents[3]
    ckpt, first = root / "checkpoints/dfv_aat_v1/last.pt", root / "models/reproduce/dfv_aat_v1.onnx"
    if not (ckpt.is_file() and first.is_file()):
        pytest.skip(f"needs {ckpt} and {first} (tracked in the repository)")
    new = tmp_path / "v1.onnx"
    _, err = export_checkpoint(ckpt, new)
    assert err < 1e-3
    ops = {n.op_type for n in onnx.load(str(new)).graph.node}
    assert "Softmax" not in ops and "Exp" in ops
    sessions = [ort.InferenceSession(str(p), providers=["CPUExecutionProvider"]) for p in (first, new)]
    io = [[(a.name, a.shape) for a in (*s.get_inputs(), *s.get_outputs())] for s in sessions]
    assert io[0] == io[1] and ("focus_diopters", ["B", "S", "H", "W"]) in io[1]
    md_new = read_metadata(new)
    # exports since 2026-11-27 also record the weights' own step (an early stop is not the schedule's end)
    assert md_new.pop("aat.checkpoint_step") == md_new["aat.train_steps"]  # the first run's last.pt: its last step
    assert md_new == read_metadata(first)
    for i, shp in enumerate([(1, 3, 32, 96), (2, 9, 96, 64), (1, 16, 64, 160), (1, 6, 128, 128)]):
        stack, fd, k = _focus_map_example(*shp, seed=10 + i)
        feeds = {"stack": stack.numpy(), "focus_diopters": fd.numpy(), "defocus_px_per_d": k.numpy()}
        old, cur = (s.run(None, feeds) for s in sessions)
        dmax = float((1.0 / fd.clamp_min(MIN_DIOPTERS)).max())
        for o, c, scale in zip(old, cur, (dmax, float(stack.max()), dmax)):
            assert o.shape == c.shape and float(np.abs(o - c).max()) < 1e-5 * scale, shp


def test_tile_px_follows_the_padding():
    """Zero-padded any-camera nets run in tiles of their largest training image; edge-padded ones on whole frames."""
    from dataclasses import replace

    from training.nets.dfvaat import build
    from training.train.export import tile_px_for

    data = {"height": 256, "width": 256, "crop_sizes": [128, 192, 256]}
    assert tile_px_for(build("small"), data) == 256
    assert tile_px_for(build("small"), {"height": 128, "width": 128}) == 128
    assert tile_px_for(build("small_replicate"), data) == 0
    untested = build("small")
    untested.net.cfg = replace(untested.net.cfg, pad_mode="reflect")
    assert tile_px_for(untested, data) == 256


# the extrapolating head ("_x" sizes): a pixel may be placed beyond its own frames


def _end_weights(m, a_near: float, a_far: float):
    """EndExtrapolation whose outputs are softplus(a * (l_end - l_next)): hand-checkable."""
    for mlp, a in zip(m.mlp, (a_near, a_far)):
        with torch.no_grad():
            mlp[0].weight.zero_(), mlp[0].bias.zero_()
            mlp[0].weight[0, 0, 0, 0] = 1.0  # hidden 0 = relu(l_end - l_next)
            mlp[2].weight.zero_(), mlp[2].bias.zero_()
            mlp[2].weight[0, 0, 0, 0] = a


def test_extrapolation_moves_an_end_frames_weight_beyond_it_by_hand():
    from training.nets.dfvaat import EndExtrapolation

    ex = EndExtrapolation()
    _end_weights(ex, 1.0, 2.0)
    fd = torch.tensor([3.0, 2.0, 1.5, 1.0])[None, :, None, None]  # near -> far; end gaps 1.0 and 0.5 D
    # all weight on the nearest frame, its logit 10 over the next: e_near = softplus(10)
    near = torch.tensor([10.0, 0.0, -5.0, -5.0])[None, :, None, None]
    _, _, _, d = focus_map_head(near, None, fd, ex)
    p0 = torch.softmax(near, 1)[0, 0, 0, 0]
    e = torch.nn.functional.softplus(torch.tensor(10.0))
    assert float(d) == pytest.approx(float((torch.softmax(near, 1) * fd).sum() + p0 * e * 1.0), rel=1e-5)
    assert float(d) > 3.0  # nearer than the nearest frame
    far = torch.tensor([-5.0, -5.0, 0.0, 10.0])[None, :, None, None]
    _, _, _, d = focus_map_head(far, None, fd, ex)
    pl = torch.softmax(far, 1)[0, -1, 0, 0]
    e = torch.nn.functional.softplus(torch.tensor(20.0))
    assert float(d) == pytest.approx(float((torch.softmax(far, 1) * fd).sum() - pl * e * 0.5), rel=1e-5)
    assert float(d) < 1.0


def test_a_peak_inside_the_sweep_is_hardly_moved_by_the_untrained_extrapolation():
    from training.nets.dfvaat import EndExtrapolation

    fd = torch.tensor([3.0, 2.0, 1.0])[None, :, None, None]
    logits = torch.tensor([-3.0, 5.0, -3.0])[None, :, None, None]
    _, _, _, plain = focus_map_head(logits, None, fd)
    _, _, _, moved = focus_map_head(logits, None, fd, EndExtrapolation())
    assert abs(float(moved - plain)) < 1e-3


def test_an_extrapolating_net_starts_from_a_base_checkpoint_and_matches_it(tmp_path):
    from training.nets.warm_start import InitError, init_model

    torch.manual_seed(2)
    base = build("small_replicate")
    ck = tmp_path / "base.pt"
    torch.save({"model": base.state_dict(), "config": {"net": "dfvaat", "size": "small_replicate"}, "step": 5}, ck)
    m = build("small_replicate_x")
    info = init_model(m, ck)
    assert info["new_tensors"] == len([k for k in m.state_dict() if k.startswith("extrap.")]) > 0
    stack = torch.rand(1, 4, 3, 32, 64)
    fd = torch.linspace(2, 0.5, 4)[None, :, None, None].expand(1, 4, 32, 64).contiguous()
    k = torch.full((1, 1, 32, 64), 8.0)
    a, b = predict(base.eval(), stack, fd, k), predict(m.eval(), stack, fd, k)
    assert torch.allclose(a["diopters"], b["diopters"], atol=0.01)  # the head starts as the interpolating one
    # the other way round is refused: a base net cannot take an extrapolating checkpoint
    torch.save({"model": m.state_dict(), "config": {"net": "dfvaat", "size": "small_replicate_x"}, "step": 5}, ck)
    with pytest.raises(InitError, match="small_replicate_x model; the run trains a dfvaat small_replicate"):
        init_model(build("small_replicate"), ck)


def test_the_extrapolating_net_exports_with_dynamic_shapes_and_stays_small(tmp_path):
    from training.nets.export import export_focus_map_onnx, focus_map_metadata, parity_focus_map

    torch.manual_seed(3)
    m = build("small_replicate_x")
    assert m.n_params <= build_model("dfvnet", "small").n_params
    for mlp in m.extrap.mlp:  # trained-like: the extrapolation is active
        torch.nn.init.normal_(mlp[2].weight, 0, 0.5)
        torch.nn.init.constant_(mlp[2].bias, 0.5)
    md = focus_map_metadata(m, effects=[], stack_range=(3, 16), config_hash="test", k_range=(0.3, 64))
    path = tmp_path / "x.onnx"
    assert export_focus_map_onnx(m, path, md) < 1e-3
    assert parity_focus_map(m, path, [(1, 3, 32, 96), (1, 16, 96, 64)]) < 1e-3


def test_the_bounded_extrapolation_caps_both_ends_and_never_passes_twice_the_far_frame():
    from training.nets.dfvaat import EndExtrapolation

    ex = EndExtrapolation(bounded=True)
    for mlp in ex.mlp:  # a trained-like head that wants to move a pixel ~20 spacings
        torch.nn.init.constant_(mlp[2].weight, 1.0)
        torch.nn.init.constant_(mlp[2].bias, 0.0)
    fd = torch.tensor([3.0, 2.0, 1.5, 1.0])[None, :, None, None]  # near -> far; end gaps 1.0 and 0.5 D
    near = torch.tensor([10.0, 0.0, -5.0, -5.0])[None, :, None, None]
    e_near, _ = ex(near)
    assert 3.5 < float(e_near) <= ex.E_MAX  # softplus ~ 20 spacings, capped smoothly under 4
    _, _, _, d = focus_map_head(near, None, fd, ex)
    assert 3.0 < float(d) <= 3.0 + ex.E_MAX * 1.0 + 1e-5
    far = torch.tensor([-5.0, -5.0, 0.0, 10.0])[None, :, None, None]
    _, _, _, d = focus_map_head(far, None, fd, ex)
    # 4 spacings of 0.5 D would reach -1 D (past infinity); the cap holds the move to half the far frame's 1 D
    assert float(d) == pytest.approx(float((torch.softmax(far, 1) * fd).sum()
                                           - torch.softmax(far, 1)[0, -1] * 0.5), rel=1e-5)
    assert float(d) >= 0.5 - 1e-6  # depth at most 2 m, twice the far frame's 1 m
    unbounded = EndExtrapolation()
    unbounded.load_state_dict(ex.state_dict())
    _, _, _, d_free = focus_map_head(far, None, fd, unbounded)
    assert float(d_free) < 0.5  # the same weights without the bound go past it
    # a far frame at infinity: no move beyond it at all
    fd_inf = torch.tensor([2.0, 1.0, 0.5, 0.0])[None, :, None, None]
    _, _, _, d = focus_map_head(far, None, fd_inf, ex)
    # (what moves it at all is the near end's share, p_0 ~ 1e-7)
    assert float(d) == pytest.approx(float((torch.softmax(far, 1) * fd_inf).sum()), abs=1e-5)
    assert float(d) >= 0.0


def test_a_bounded_net_starts_from_a_base_checkpoint_and_exports(tmp_path):
    from training.nets.export import export_focus_map_onnx, focus_map_metadata, parity_focus_map
    from training.nets.warm_start import init_model

    torch.manual_seed(4)
    base = build("small_replicate")
    ck = tmp_path / "base.pt"
    torch.save({"model": base.state_dict(), "config": {"net": "dfvaat", "size": "small_replicate"}, "step": 5}, ck)
    m = build("small_replicate_xb")
    assert m.extrap is not None and m.extrap.bounded
    assert init_model(m, ck)["new_tensors"] > 0
    for mlp in m.extrap.mlp:
        torch.nn.init.normal_(mlp[2].weight, 0, 0.5)
        torch.nn.init.constant_(mlp[2].bias, 0.5)
    md = focus_map_metadata(m, effects=[], stack_range=(3, 16), config_hash="test", k_range=(0.3, 64))
    path = tmp_path / "xb.onnx"
    assert export_focus_map_onnx(m, path, md) < 1e-3
    assert parity_focus_map(m, path, [(1, 3, 32, 96), (1, 16, 96, 64)]) < 1e-3


def test_the_blur_spacing_head_reads_each_end_spacing_in_blur_pixels():
    from training.nets.dfvaat import EndExtrapolation

    ex = EndExtrapolation(bounded=True, blur_spacing=True)
    for mlp in ex.mlp:  # only the fourth input (log2 of the spacing in blur px / 4) drives e
        torch.nn.init.zeros_(mlp[0].weight)
        with torch.no_grad():
            mlp[0].weight[:, 3] = 1.0
        torch.nn.init.zeros_(mlp[0].bias)
        torch.nn.init.constant_(mlp[2].weight, 1.0)
        torch.nn.init.constant_(mlp[2].bias, -3.0)
    fd = torch.tensor([3.0, 2.0, 1.5, 1.0])[None, :, None, None]  # end gaps 1.0 and 0.5 D
    logits = torch.tensor([10.0, 0.0, -5.0, -5.0])[None, :, None, None]
    e_small, _ = ex(logits, (torch.full((1, 1, 1), 2.0), torch.full((1, 1, 1), 1.0)))
    e_wide, _ = ex(logits, (torch.full((1, 1, 1), 64.0), torch.full((1, 1, 1), 32.0)))
    # hand-computed: hidden units = log2(g)/4, 8 of them summed, minus 3, softplus, 4 tanh(. / 4)
    for e, g in ((e_small, 2.0), (e_wide, 64.0)):
        z = torch.nn.functional.softplus(torch.tensor(8 * math.log2(g) / 4 - 3.0))
        assert float(e) == pytest.approx(float(4 * torch.tanh(z / 4)), rel=1e-5)
    k = torch.full((1, 1, 1, 1), 2.0)  # px per D: the near gap of 1 D is 2 px
    _, _, _, d = focus_map_head(logits, None, fd, ex, k)
    p0 = torch.softmax(logits, 1)[0, 0]
    assert float(d) == pytest.approx(float((torch.softmax(logits, 1) * fd).sum() + p0 * e_small * 1.0
                                           - torch.softmax(logits, 1)[0, -1] * 0.0), rel=1e-4, abs=1e-6)
    with pytest.raises(ValueError, match="needs defocus_px_per_d"):
        focus_map_head(logits, None, fd, ex)
    with pytest.raises(ValueError, match="needs gaps_px"):
        ex(logits)


def test_a_blur_spacing_net_starts_from_a_base_checkpoint_matches_it_and_exports(tmp_path):
    from training.nets.export import export_focus_map_onnx, focus_map_metadata, parity_focus_map
    from training.nets.warm_start import init_model

    torch.manual_seed(6)
    base = build("small_replicate")
    ck = tmp_path / "base.pt"
    torch.save({"model": base.state_dict(), "config": {"net": "dfvaat", "size": "small_replicate"}, "step": 5}, ck)
    m = build("small_replicate_xbk")
    assert m.extrap.bounded and m.extrap.blur_spacing and m.n_params <= build_model("dfvnet", "small").n_params
    assert init_model(m, ck)["new_tensors"] > 0
    stack = torch.rand(1, 4, 3, 32, 64)
    fd = torch.linspace(2, 0.5, 4)[None, :, None, None].expand(1, 4, 32, 64).contiguous()
    k = torch.full((1, 1, 32, 64), 8.0)
    a, b = predict(base.eval(), stack, fd, k), predict(m.eval(), stack, fd, k)
    assert torch.allclose(a["diopters"], b["diopters"], atol=0.01)  # the head starts as the interpolating one
    for mlp in m.extrap.mlp:
        torch.nn.init.normal_(mlp[2].weight, 0, 0.5)
        torch.nn.init.constant_(mlp[2].bias, 0.5)
    md = focus_map_metadata(m, effects=[], stack_range=(3, 16), config_hash="test", k_range=(0.3, 64))
    path = tmp_path / "xbk.onnx"
    assert export_focus_map_onnx(m, path, md) < 1e-3
    assert parity_focus_map(m, path, [(1, 3, 32, 96), (1, 16, 96, 64)]) < 1e-3
