"""A DfF network plus the shared head, and the wrapper that accepts any stack: sorts frames by focus distance,
pads H, W (reflect) to the network's multiple and crops back.

`DfFNet.forward` is what ONNX exports: it expects sorted frames and H, W multiples of `size_multiple` (the
runtime pads and sorts, see docs/contracts.md). `predict` is the torch-side equivalent of the runtime.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from training.nets import registry
from training.nets.blocks import count_params
from training.nets.head import focus_head


def build_net(net: str, size: str, field_channels: int = 0) -> nn.Module:
    """A fresh (randomly initialised) backbone of a net of the registry (training.nets.registry: AiFNet, DFVNet)
    in one of its sizes; field_channels extra input channels per frame (2: the normalised sensor position x, y of
    each pixel, x right, y up, +-1 at the edges)."""
    spec = registry.get(net)
    spec.check(size, field_channels)
    if spec.focus_maps:
        raise registry.UnknownNet(f"{spec.name} is a whole model (per-pixel focus maps in): build_model builds it")
    return spec.builder(size, 3 + field_channels)


class DfFNet(nn.Module):
    """Network + head. forward(stack (B, S, 3, H, W), focus_m (B, S)[, field_xy (B, 2, H, W)]) ->
    (depth_m (B, H, W), aif (B, 3, H, W), std_m (B, H, W)); frames sorted near to far, H, W multiples of
    `size_multiple`. A field-aware model (field_channels 2) also takes each pixel's normalised sensor position
    (x right, y up, +-1 at the sensor edges), so it can know where in the field a patch lies: a translation-
    invariant CNN cannot, yet field curvature moves best focus with field position."""

    def __init__(self, net: nn.Module, name: str = "", size: str = "", field_channels: int = 0):
        super().__init__()
        self.net, self.name, self.size = net, name, size
        self.field_channels = int(field_channels)
        self.size_multiple: int = int(net.size_multiple)

    def net_input(self, stack: Tensor, field_xy: Tensor | None) -> Tensor:
        """The net's input: the stack, with the field coordinates appended to every frame when field-aware."""
        if not self.field_channels:
            return stack
        if field_xy is None:
            raise ValueError("a field-aware model needs field_xy (B, 2, H, W)")
        f = field_xy[:, None].to(stack.dtype).expand(-1, stack.shape[1], -1, -1, -1)
        return torch.cat([stack, f], 2)

    @property
    def n_params(self) -> int:
        return count_params(self)

    def levels(self, stack: Tensor, focus_m: Tensor, field_xy: Tensor | None = None
               ) -> list[tuple[Tensor, Tensor, Tensor]]:
        """Head outputs for every logit level the net returns (finest first; coarser ones only in training)."""
        out = []
        for i, lg in enumerate(self.net(self.net_input(stack, field_xy))):
            depth, aif, std = focus_head(lg, stack if i == 0 else None, focus_m)
            out.append((depth, aif, std))
        return out

    def forward(self, stack: Tensor, focus_m: Tensor, field_xy: Tensor | None = None, all_levels: bool = False):
        """(depth_m, aif, std_m) of the finest level; with all_levels, the list of `levels` (for training)."""
        levels = self.levels(stack, focus_m, field_xy)
        if all_levels:
            return levels
        depth, aif, std = levels[0]
        return depth, aif, std


def build_model(net: str, size: str, field_channels: int = 0) -> nn.Module:
    """A fresh model of a net of the registry (training.nets.registry): a DfFNet (backbone + focus head), or for a
    net with per-pixel focus maps in (the any-camera "dfvaat") the model its builder makes."""
    spec = registry.get(net)
    spec.check(size, field_channels)
    if spec.focus_maps:
        return spec.builder(size, 3 + field_channels)
    return DfFNet(spec.builder(size, 3 + field_channels), spec.name, size, field_channels)


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


def pad_field(field_xy: Tensor, multiple: int) -> Tensor:
    """Pad field coordinates (B, 2, H, W) at the bottom/right to multiples of `multiple` by continuing them
    linearly (they are linear in the pixel index), so padded pixels carry the positions they would have."""
    h, w = field_xy.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    out = field_xy
    if pw:
        step = out[..., :, -1:] - out[..., :, -2:-1] if w > 1 else torch.zeros_like(out[..., :, -1:])
        k = torch.arange(1, pw + 1, dtype=out.dtype, device=out.device)
        out = torch.cat([out, out[..., :, -1:] + step * k], -1)
    if ph:
        step = out[..., -1:, :] - out[..., -2:-1, :] if h > 1 else torch.zeros_like(out[..., -1:, :])
        k = torch.arange(1, ph + 1, dtype=out.dtype, device=out.device)[:, None]
        out = torch.cat([out, out[..., -1:, :] + step * k], -2)
    return out


def train_levels(module: nn.Module, stack: Tensor, focus_m: Tensor, size_multiple: int,
                 field_xy: Tensor | None = None) -> list:
    """Training forward of a DfFNet (or its DistributedDataParallel wrapper) on any batch: frames sorted,
    H, W padded to `size_multiple` and every level's outputs cropped back. Returns [(depth_m, aif, std_m), ...]."""
    stack, focus_m = sort_by_focus(stack, focus_m)
    padded, (h, w) = pad_to_multiple(stack, size_multiple)
    field = None if field_xy is None else pad_field(field_xy, size_multiple)
    levels = module(padded, focus_m, field, all_levels=True)
    return [tuple(None if t is None else t[..., :h, :w] for t in lv) for lv in levels]


def predict(model: DfFNet, stack: Tensor, focus_m: Tensor, field_xy: Tensor | None = None) -> dict[str, Tensor]:
    """Run `model` on any stack: frames sorted by focus (any input order accepted), any H, W (padded and
    cropped back). stack (B, S, 3, H, W) normalised per docs/contracts.md, focus_m (B, S) metres.
    field_xy (B, 2, H, W): each pixel's normalised sensor position, for field-aware models.
    Returns {"depth_m": (B, H, W), "aif": (B, 3, H, W), "std_m": (B, H, W)}."""
    if stack.dim() != 5 or stack.shape[2] != 3 or focus_m.shape != stack.shape[:2]:
        raise ValueError(f"predict: stack (B, S, 3, H, W) and focus_m (B, S) expected, got "
                         f"{tuple(stack.shape)} and {tuple(focus_m.shape)}")
    if stack.shape[1] < 2:
        raise ValueError(f"predict: a stack needs at least 2 frames, got {stack.shape[1]}")
    stack, focus_m = sort_by_focus(stack, focus_m)
    padded, (h, w) = pad_to_multiple(stack, model.size_multiple)
    field = None if field_xy is None else pad_field(field_xy, model.size_multiple)
    depth, aif, std = model(padded, focus_m, field)
    return {"depth_m": depth[..., :h, :w], "aif": aif[..., :h, :w], "std_m": std[..., :h, :w]}
