"""DfF networks: parameter counts, the shared head, any S / H / W via the wrapper, frame sorting, normalisation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from training.nets.blocks import count_params
from training.nets.dfvnet import DFVNET_CONFIGS, DFVNet
from training.nets.head import focus_head
from training.nets.model import (
    build_model,
    build_net,
    pad_to_multiple,
    predict,
    sort_by_focus,
)

F32_EPS = float(np.finfo(np.float32).eps)
pytestmark = pytest.mark.numerics  # float bounds, sorted vs unsorted

# Published counts (reference-facts section 4). DFVNet L2's includes ResNet-18's unused 513,000-parameter fc layer.
PUBLISHED = {"aifnet": 16_533_873, "dfvnet": 16_220_778 - 513_000}


@pytest.mark.parametrize("net", ["aifnet", "dfvnet"])
def test_full_size_parameter_counts_match_published(net):
    n = count_params(build_net(net, "full"))
    assert abs(n - PUBLISHED[net]) / PUBLISHED[net] < 0.01, n
    small = count_params(build_net(net, "small"))
    assert small < n / 10


def _stack(b: int, s: int, h: int, w: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    stack = torch.rand(b, s, 3, h, w, generator=g)
    focus = torch.sort(torch.rand(b, s, generator=g) * 4 + 0.5, dim=1).values
    return stack, focus


@pytest.mark.parametrize("net", ["aifnet", "dfvnet"])
@pytest.mark.parametrize("s,h,w", [(2, 45, 70), (5, 64, 32), (7, 33, 97)])
def test_any_stack_and_size(net, s, h, w):
    torch.manual_seed(0)
    model = build_model(net, "small").eval()
    stack, focus = _stack(2, s, h, w)
    with torch.no_grad():
        out = predict(model, stack, focus)
    assert out["depth_m"].shape == (2, h, w) and out["std_m"].shape == (2, h, w) and out["aif"].shape == (2, 3, h, w)
    lo, hi = focus.min(1).values[:, None, None], focus.max(1).values[:, None, None]
    # convex combinations of S float32 values (softmax weights summing to 1 within S roundings): off the hull by
    # at most ~2 S eps of the largest; std also carries the head's sqrt(1e-12) = 1e-6 m
    slack = 2 * s * F32_EPS * hi
    assert (out["depth_m"] >= lo - slack).all() and (out["depth_m"] <= hi + slack).all()
    assert (out["std_m"] >= 0).all() and (out["std_m"] <= (hi - lo) / 2 + slack + 1e-6).all()
    slack = 2 * s * F32_EPS * float(stack.abs().max())
    assert (out["aif"] >= stack.min(1).values - slack).all() and (out["aif"] <= stack.max(1).values + slack).all()


@pytest.mark.parametrize("net", ["aifnet", "dfvnet"])
def test_predict_sorts_frames(net):
    torch.manual_seed(0)
    model = build_model(net, "small").eval()
    stack, focus = _stack(1, 5, 32, 64)
    perm = torch.tensor([3, 0, 4, 1, 2])
    with torch.no_grad():
        a = predict(model, stack, focus)
        b = predict(model, stack[:, perm], focus[:, perm])
        c = model(stack.flip(1), focus.flip(1))  # the raw model does not sort: order matters to 3-D convs
    assert torch.equal(a["depth_m"], b["depth_m"])  # sorted: the same input through the same kernels, bit for bit
    assert (a["depth_m"] - c[0]).abs().max() > 1e-2 * a["depth_m"].abs().max()


def test_head_hand_computed():
    focus = torch.tensor([[1.0, 2.0, 4.0]])
    logits = torch.zeros(1, 3, 1, 2)
    logits[0, 2, 0, 1] = 50.0  # pixel 1: all weight on frame 2
    stack = torch.arange(3.0).reshape(1, 3, 1, 1, 1).expand(1, 3, 3, 1, 2)
    depth, aif, std = focus_head(logits, stack, focus)
    assert depth[0, 0, 0].item() == pytest.approx(7 / 3)
    assert std[0, 0, 0].item() == pytest.approx(np.std([1.0, 2.0, 4.0]), rel=1e-5)
    assert depth[0, 0, 1].item() == pytest.approx(4.0)
    assert std[0, 0, 1].item() == pytest.approx(0.0, abs=1e-5)
    assert aif[0, :, 0, 0].tolist() == pytest.approx([1.0] * 3)
    assert aif[0, :, 0, 1].tolist() == pytest.approx([2.0] * 3)


def test_sort_and_pad_helpers():
    stack = torch.arange(3.0).reshape(1, 3, 1, 1, 1).expand(1, 3, 3, 2, 2)
    s, f = sort_by_focus(stack, torch.tensor([[3.0, 1.0, 2.0]]))
    assert f.tolist() == [[1.0, 2.0, 3.0]] and s[0, :, 0, 0, 0].tolist() == [1.0, 2.0, 0.0]
    x = torch.arange(12.0).reshape(1, 1, 3, 4)
    p, hw = pad_to_multiple(x, 4)
    assert p.shape == (1, 1, 4, 4) and hw == (3, 4)
    assert p[0, 0, 3].tolist() == x[0, 0, 1].tolist()  # reflect: row 3 mirrors row 1
    p, _ = pad_to_multiple(torch.ones(1, 1, 2, 2), 32)  # pad >= size: replicate
    assert p.shape == (1, 1, 32, 32) and (p == 1).all()


def test_differential_volume():
    net = DFVNet(DFVNET_CONFIGS["small"])
    f = torch.arange(3.0).reshape(3, 1, 1, 1).expand(3, 2, 1, 1) ** 2  # frames 0, 1, 4
    v = net.volume(f, 1, 3)
    assert v.shape == (1, 2, 3, 1, 1)
    assert v[0, 0, :, 0, 0].tolist() == [-1.0, -3.0, 4.0]


def test_dfvnet_deep_supervision_levels_only_in_training():
    net = DFVNet(DFVNET_CONFIGS["small"])
    x = torch.rand(1, 3, 3, 64, 64)
    assert len(net.train()(x)) == 2 and len(net.eval()(x)) == 1
    with pytest.raises(ValueError, match="levels"):
        DFVNet(DFVNET_CONFIGS["small"].__class__(levels=5))


def test_bad_inputs_are_clear_errors():
    model = build_model("aifnet", "small")
    with pytest.raises(ValueError, match="at least 2"):
        predict(model, torch.rand(1, 1, 3, 32, 32), torch.ones(1, 1))
    with pytest.raises(ValueError, match="focus_m"):
        predict(model, torch.rand(1, 2, 3, 32, 32), torch.ones(1, 3))
    with pytest.raises(ValueError, match="unknown net"):
        build_net("resnet", "small")


@pytest.mark.parametrize("shape", [(5, 3, 37, 41), (2, 3, 8, 8), (8, 3, 64, 80)])
def test_normalise_by_hand(shape):
    """The contract's rule computed by hand: the 99.5th percentile interpolated linearly between the two order
    statistics around rank 0.995 (n - 1), the stack divided by it and clipped; an image in the stack's units (its
    all-in-focus image) scaled alike."""
    from aat_deploy.infer.normalise import normalise_scale, normalise_stack, scaled

    rng = np.random.default_rng(sum(shape))
    x = (rng.random(shape) ** 3 * rng.uniform(0.1, 1000)).astype(np.float32)
    s = np.sort(x.ravel().astype(np.float64))
    pos = 0.995 * (s.size - 1)
    lo = int(pos)
    p = s[lo] + (s[min(lo + 1, s.size - 1)] - s[lo]) * (pos - lo)
    assert float(normalise_scale(x)) == pytest.approx(p, rel=F32_EPS)
    a = normalise_stack(x)
    assert a.dtype == np.float32 and np.allclose(a, np.clip(x / p, 0, 1), rtol=2 * F32_EPS, atol=0)
    assert a.max() == 1.0 and (a == 1.0).mean() == pytest.approx(0.005, abs=0.002)
    assert np.array_equal(normalise_stack(2 * x), a)  # x 2 is exact in binary floats
    aif = x[0]
    assert np.array_equal(scaled(aif, normalise_scale(x)), a[0])


def test_normalise_edge_cases():
    from aat_deploy.infer.normalise import normalise_stack as normalise_np

    assert (normalise_np(np.zeros((2, 3, 4, 4))) == 0).all()
    with pytest.raises(ValueError, match="NaN"):
        normalise_np(np.full((2, 3, 4, 4), np.nan))
    x = np.arange(1000, dtype=np.float32).reshape(10, 1, 10, 10)
    assert normalise_np(x).max() == 1.0
    assert normalise_np(x)[0, 0, 0, 1] == pytest.approx(1 / np.percentile(np.arange(1000.0), 99.5))


def test_train_levels_pads_sorts_and_crops():
    from training.nets.model import train_levels

    torch.manual_seed(0)
    model = build_model("dfvnet", "small").train()
    stack, focus = _stack(2, 4, 40, 50)
    levels = train_levels(model, stack.flip(1), focus.flip(1), model.size_multiple)
    assert len(levels) == 2 and levels[0][0].shape == (2, 40, 50) and levels[0][1].shape == (2, 3, 40, 50)
    assert levels[1][1] is None and levels[1][0].shape == (2, 40, 50)
    model.eval()
    with torch.no_grad():
        a = train_levels(model, stack.flip(1), focus.flip(1), 32)[0][0]
        b = predict(model, stack, focus)["depth_m"]
    assert torch.equal(a, b)  # the same sorted, padded input through the same eval-mode layers: bit for bit


@pytest.mark.parametrize("net", ["aifnet", "dfvnet"])
def test_field_aware_nets_use_the_field(net):
    """field_channels 2: the field coordinates are an input (the output changes with them) and are required."""
    from training.nets.model import pad_field

    torch.manual_seed(0)
    m = build_model(net, "small", field_channels=2).eval()
    stack, focus = torch.rand(1, 4, 3, 64, 64), torch.tensor([[0.5, 1.0, 2.0, 4.0]])
    f0 = torch.zeros(1, 2, 64, 64)
    with torch.no_grad():
        a, b = m(stack, focus, f0)[0], m(stack, focus, f0 + 0.5)[0]
    assert a.shape == (1, 64, 64) and not torch.allclose(a, b)
    with pytest.raises(ValueError, match="field_xy"):
        m(stack, focus)
    # padding continues the coordinate ramp
    ramp = torch.arange(5.0)[None, None, None].expand(1, 2, 3, 5)
    assert torch.allclose(pad_field(ramp, 4)[0, 0, 0], torch.arange(8.0))


def test_window_mean_is_the_excluding_2d_mean_and_the_global_mean_when_it_covers_the_image():
    import torch.nn.functional as F

    from training.nets.dfvnet import window_mean

    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 3, 8, 5, generator=g)
    ref = F.avg_pool2d(x, 5, 1, 2, count_include_pad=False)
    assert torch.allclose(window_mean(x, 5), ref, atol=1e-6)
    # hand-computed corner: a 3 x 3 window at (0, 0) holds the 2 x 2 cells inside the image
    assert torch.isclose(window_mean(x, 3)[0, 0, 0, 0], x[0, 0, :2, :2].mean(), atol=1e-6)
    # a window of 2n - 1 or more sees the whole image from every cell (8 rows: 15)
    assert torch.allclose(window_mean(x, 15), x.mean((2, 3), keepdim=True).expand_as(x), atol=1e-6)
    assert not torch.allclose(window_mean(x, 13), x.mean((2, 3), keepdim=True).expand_as(x), atol=1e-3)
    with pytest.raises(ValueError, match="odd"):
        window_mean(x, 4)


def test_context_window_changes_nothing_on_images_it_covers_and_localises_larger_ones():
    from training.nets.dfvnet import PyramidPool2d

    torch.manual_seed(0)
    pool = PyramidPool2d(4, 2, 6, 4, (3,)).eval()
    small, big = torch.randn(1, 4, 4, 4), torch.randn(1, 4, 20, 30)
    with torch.no_grad():
        a_small, a_big = pool(small), pool(big)
        pool.global_window = 7
        b_small, b_big = pool(small), pool(big)
    assert torch.allclose(a_small, b_small, atol=1e-6)
    assert not torch.allclose(a_big, b_big, atol=1e-4)
    # far from the window, a change to one corner no longer reaches the other
    big2 = big.clone()
    big2[..., :4, :4] += 5.0
    with torch.no_grad():
        assert torch.allclose(pool(big2)[..., -1, -1], b_big[..., -1, -1], atol=1e-6)
