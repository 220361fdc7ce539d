"""Weight averaging over a run's checkpoints (stochastic weight averaging, Izmailov et al. 2018, done after the run).

Late in a cosine schedule the weights wander around a minimum from one checkpoint to the next; their mean usually
sits nearer its centre than any single one. Only the weights are averaged: batch norm's running statistics of the
mean net are not the mean of the checkpoints' statistics, so they are recomputed afterwards
(`training.train.precise_bn.recompute_bn_stats`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch


def average_state_dicts(states: Sequence[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """The element-wise mean of `states` (model state dicts of one architecture) for floating-point entries; integer
    entries (BatchNorm's num_batches_tracked) are taken from the last state. Raises ValueError naming the entry on
    mismatched keys, shapes or dtypes."""
    if not states:
        raise ValueError("no state dicts to average")
    first = states[0]
    for i, s in enumerate(states[1:], 1):
        if s.keys() != first.keys():
            diff = sorted(set(s.keys()) ^ set(first.keys()))
            raise ValueError(f"state {i} has other entries than state 0: {diff[:3]}")
        for k, v in s.items():
            if v.shape != first[k].shape or v.dtype != first[k].dtype:
                raise ValueError(f"state {i}: entry {k} is {tuple(v.shape)} {v.dtype}, "
                                 f"state 0 has {tuple(first[k].shape)} {first[k].dtype}")
    out = {}
    for k, v in first.items():
        if v.is_floating_point():
            acc = torch.zeros_like(v, dtype=torch.float64)
            for s in states:
                acc += s[k].to(torch.float64)
            out[k] = (acc / len(states)).to(v.dtype)
        else:
            out[k] = states[-1][k].clone()
    return out
