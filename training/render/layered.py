"""The layered renderer's torch backend: the algorithm is `aat_deploy.render.layered` (one algorithm for the
torch simulator and the torch-free twins); this module gives it torch's spelling of the operations that differ
(`LayeredBackend`) and registers it, so `render_layered` takes torch tensors once the training package is imported.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from aat_deploy.render.layered import LayeredBackend, LayeredConfig, layer_diopters, register_backend, render_layered

__all__ = ["TORCH", "LayeredConfig", "layer_diopters", "render_layered"]


class TorchLayered(LayeredBackend):
    """torch's spelling of the layered renderer's operations (pooling, interpolation and fold from
    torch.nn.functional)."""

    xp = torch
    fft = torch.fft

    def asarray(self, x):
        return torch.as_tensor(x)

    def astype(self, x, dtype):
        return x.to(dtype)

    def to_numpy(self, x) -> np.ndarray:
        return x.cpu().numpy()

    def concat(self, arrays, axis: int):
        return torch.cat(arrays, axis)

    def permute(self, x, axes):
        return x.permute(*axes)

    def broadcast_to(self, x, shape):
        return x.expand(*shape)

    def sum_keep(self, x, axis: int):
        return x.sum(axis, keepdim=True)

    def mean_keep(self, x, axis: int):
        return x.mean(axis, keepdim=True)

    def pad_end(self, x, rows: int, cols: int):
        return F.pad(x, (0, cols, 0, rows))

    def pad_edge(self, x, pad: int):
        lead = (None,) * (4 - x.ndim)  # replicate padding wants a batch (and channel) axis
        return F.pad(x[lead], (pad, pad, pad, pad), mode="replicate")[(0,) * len(lead)]

    def box_mean(self, x, m: int):
        return F.avg_pool2d(x[None], m)[0]

    def box_max(self, x, m: int):
        return F.max_pool2d(x[None, None], m)[0, 0]

    def nonzero(self, mask):
        return mask.nonzero()

    def unique_inverse(self, x):
        return torch.unique(x, return_inverse=True)

    def sandwich(self, a, kernels):
        return torch.einsum("npi,nij,nqj->npq", a, kernels, a)

    def overlap_add(self, blocks, idx, ny: int, nx: int, cc: int, r: int):
        na, ctot = blocks.shape[:2]
        if na <= 64:
            return super().overlap_add(blocks, idx, ny, nx, cc, r)
        # fold sums overlapping blocks in one call
        flat = torch.zeros(ny * nx, ctot * (cc + 2 * r) ** 2, dtype=blocks.dtype, device=blocks.device)
        flat[idx[:, 0] * nx + idx[:, 1]] = blocks.reshape(na, -1)
        return F.fold(flat.T[None], (ny * cc + 2 * r, nx * cc + 2 * r), cc + 2 * r, stride=cc)[0]

    def upsample(self, img, m: int):
        return F.interpolate(img[None], scale_factor=m, mode="bilinear", align_corners=False)[0]


TORCH = TorchLayered()
register_backend("torch", TORCH)
