"""A DfF network plus the shared head, and the wrapper that accepts any stack: sorts frames by focus distance,
pads H, W (reflect) to the network's multiple and crops back.

`DfFModel.forward` is what ONNX exports: it expects sorted frames and H, W multiples of `size_multiple` (the
runtime pads and sorts, see docs/contracts.md). `predict` is the torch-side equivalent of the runtime.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from training.nets.aifnet import AIFNET_CONFIGS, AiFNet
from training.nets.blocks import count_params
from training.nets.dfvnet import DFVNET_CONFIGS, DFVNet
from training.nets.head import focus_head

NETS = ("aifnet", "dfvnet")
SIZES = ("small", "full")


def build_net(net: str, size: str) -> nn.Module:
    """A fresh (randomly initialised) AiFNet or DFVNet in its 'small' or 'full' configuration."""
    if net not in NETS:
        raise ValueError(f"unknown net {net!r}; expected one of {NETS}")
    if size not in SIZES:
        raise ValueError(f"unknown size {size!r}; expected one of {SIZES}")
    return AiFNet(AIFNET_CONFIGS[size]) if net == "aifnet" else DFVNet(DFVNET_CONFIGS[size])


class DfFModel(nn.Module):
    """Network + head. forward(stack (B, S, 3, H, W), focus_m (B, S)) -> (depth_m (B, H, W), aif (B, 3, H, W),
    std_m (B, H, W)); frames sorted near to far, H, W multiples of `size_multiple`."""

    def __init__(self, net: nn.Module, name: str = "", size: str = ""):
        super().__init__()
        self.net, self.name, self.size = net, name, size
        self.size_multiple: int = int(net.size_multiple)

    @property
    def n_params(self) -> int:
        return count_params(self)

    def levels(self, stack: Tensor, focus_m: Tensor) -> list[tuple[Tensor, Tensor, Tensor]]:
        """Head outputs for every logit level the net returns (finest first; coarser ones only in training)."""
        out = []
        for i, lg in enumerate(self.net(stack)):
            depth, aif, std = focus_head(lg, stack if i == 0 else None, focus_m)
            out.append((depth, aif, std))
        return out

    def forward(self, stack: Tensor, focus_m: Tensor, all_levels: bool = False):
        """(depth_m, aif, std_m) of the finest level; with all_levels, the list of `levels` (for training)."""
        levels = self.levels(stack, focus_m)
        if all_levels:
            return levels
        depth, aif, std = levels[0]
        return depth, aif, std


def build_model(net: str, size: str) -> DfFModel:
    return DfFModel(build_net(net, size), net, size)


def sort_by_focus(stack: Tensor, focus_m: Tensor) -> tuple[Tensor, Tensor]:
    """Reorder frames near to far. stack (B, S, 3, H, W), focus_m (B, S) -> same shapes, focus ascending."""
    order = torch.argsort(focus_m, dim=1)
    idx = order[:, :, None, None, None].expand_as(stack)
    return torch.gather(stack, 1, idx), torch.gather(focus_m, 1, order)


def pad_to_multiple(x: Tensor, multiple: int) -> tuple[Tensor, tuple[int, int]]:
    """Reflect-pad the last two dims of (..., H, W) at the bottom/right to multiples of `multiple`
    (replicate where reflect is impossible, i.e. pad >= size). Returns the padded tensor and the original (H, W)."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph == 0 and pw == 0:
        return x, (h, w)
    lead = x.shape[:-2]
    flat = x.reshape(-1, 1, h, w)
    mode = "reflect" if ph < h and pw < w else "replicate"
    flat = F.pad(flat, (0, pw, 0, ph), mode=mode)
    return flat.reshape(*lead, h + ph, w + pw), (h, w)


def train_levels(module: nn.Module, stack: Tensor, focus_m: Tensor, size_multiple: int) -> list:
    """Training forward of a DfFModel (or its DistributedDataParallel wrapper) on any batch: frames sorted,
    H, W padded to `size_multiple` and every level's outputs cropped back. Returns [(depth_m, aif, std_m), ...]."""
    stack, focus_m = sort_by_focus(stack, focus_m)
    padded, (h, w) = pad_to_multiple(stack, size_multiple)
    levels = module(padded, focus_m, all_levels=True)
    return [tuple(None if t is None else t[..., :h, :w] for t in lv) for lv in levels]


def predict(model: DfFModel, stack: Tensor, focus_m: Tensor) -> dict[str, Tensor]:
    """Run `model` on any stack: frames sorted by focus (any input order accepted), any H, W (padded and
    cropped back). stack (B, S, 3, H, W) normalised per docs/contracts.md, focus_m (B, S) metres.
    Returns {"depth_m": (B, H, W), "aif": (B, 3, H, W), "std_m": (B, H, W)}."""
    if stack.dim() != 5 or stack.shape[2] != 3 or focus_m.shape != stack.shape[:2]:
        raise ValueError(f"predict: stack (B, S, 3, H, W) and focus_m (B, S) expected, got "
                         f"{tuple(stack.shape)} and {tuple(focus_m.shape)}")
    if stack.shape[1] < 2:
        raise ValueError(f"predict: a stack needs at least 2 frames, got {stack.shape[1]}")
    stack, focus_m = sort_by_focus(stack, focus_m)
    padded, (h, w) = pad_to_multiple(stack, model.size_multiple)
    depth, aif, std = model(padded, focus_m)
    return {"depth_m": depth[..., :h, :w], "aif": aif[..., :h, :w], "std_m": std[..., :h, :w]}
