"""training.train.precise_bn: batch norm's statistics become the plain average over the batches read."""

import torch
from torch import nn

from training.train.precise_bn import recompute_bn_stats


def _net():
    torch.manual_seed(0)
    return nn.Sequential(nn.Linear(3, 4), nn.BatchNorm1d(4))


def test_statistics_are_the_average_over_batches_and_weights_untouched():
    net = _net()
    batches = [torch.randn(8, 3) * s + s for s in (1.0, 2.0, 5.0)]
    weights = {k: v.clone() for k, v in net.state_dict().items() if "running" not in k and "num_batches" not in k}
    n = recompute_bn_stats(net, batches, lambda m, b: m(b))
    assert n == 3 and not net.training
    with torch.no_grad():
        feats = [net[0](b) for b in batches]
    bn = net[1]
    # each batch weighted equally: the mean of batch means and of the (unbiased) batch variances
    torch.testing.assert_close(bn.running_mean, torch.stack([f.mean(0) for f in feats]).mean(0))
    torch.testing.assert_close(bn.running_var, torch.stack([f.var(0, unbiased=True) for f in feats]).mean(0))
    assert bn.momentum == 0.1  # restored for any later training
    for k, v in weights.items():
        assert torch.equal(net.state_dict()[k], v), k


def test_no_batches_leaves_the_statistics_as_they_were():
    net = _net()
    net.train()
    net(torch.randn(16, 3) + 3.0)  # some running statistics
    before = {k: v.clone() for k, v in net.state_dict().items()}
    assert recompute_bn_stats(net, [], lambda m, b: m(b)) == 0
    for k, v in before.items():
        assert torch.equal(net.state_dict()[k], v), k
