"""Batch norm's running statistics recomputed as a plain average over many training batches ("precise BN").

During training each BatchNorm keeps an exponential average (momentum 0.1) of its batches' statistics, so the
statistics a checkpoint carries reflect its last ~10 batches. With batches of 4 stacks that mix stack sizes,
schedules and mosaics, those few batches are a noisy sample, and a net evaluated from one checkpoint to the next can
swing although its weights barely move. Averaging the statistics over N batches with the weights fixed removes that
noise; nothing else changes (no gradient, no weight update).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import torch
from torch import nn


def batch_norms(model: nn.Module) -> list[nn.modules.batchnorm._BatchNorm]:
    return [m for m in model.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]


@torch.no_grad()
def recompute_bn_stats(model: nn.Module, batches: Iterable, forward: Callable[[nn.Module, object], object]) -> int:
    """Replace every BatchNorm's running mean and variance by the average over `batches` of the statistics train-mode
    forwards (`forward(model, batch)`) compute. The weights are untouched; the model is left in eval mode. Returns the
    number of batches read (0 leaves the statistics as they were)."""
    bns = batch_norms(model)
    saved = [(m.running_mean.clone(), m.running_var.clone(), m.num_batches_tracked.clone(), m.momentum)
             for m in bns]
    for m in bns:
        m.reset_running_stats()
        m.momentum = None  # None: a cumulative average over the batches seen, each batch weighted equally
    model.train()
    n = 0
    try:
        for batch in batches:
            forward(model, batch)
            n += 1
    finally:
        for m, (mean, var, count, momentum) in zip(bns, saved):
            m.momentum = momentum
            if n == 0:
                m.running_mean.copy_(mean)
                m.running_var.copy_(var)
                m.num_batches_tracked.copy_(count)
        model.eval()
    return n
