"""DFVNet (after Yang, Huang, Zhou, "Deep depth from focus with differential focus volume", CVPR 2022): our
own implementation of the published topology.

Per frame: a ResNet-18-like 2-D encoder (/4 .. /32), a pyramid-pooling context module on the /32 feature and
a top-down path giving features at /32, /16, /8, /4 (published widths 128, 64, 32, 16). Differential focus
volume: slice i = feat(i) - feat(i+1), the last frame's feature kept as is (frames sorted by focus distance).
A 3-D residual decoder per level, coarse to fine (level L uses the L finest scales, /4 first; published
DFVNet uses 4, the aberration-aware paper 2); each level classifies one logit per frame; all levels are
upsampled bilinearly to full resolution (coarser levels only in training, for deep supervision).

Shape independence: the published pyramid pooling derives its pooling kernels from the input size, which an
ONNX export freezes. Ours pools with fixed windows (stride 1, "same" padding, padded cells excluded) plus a
global mean: every kernel is in feature pixels, never computed from the input shape, so one export is exact
at any S, H, W.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from training.nets.blocks import (
    BasicBlock2d,
    ConvBNReLU2d,
    ConvBNReLU3d,
    ResBlock3d,
    init_weights,
    set_padding_mode,
)


@dataclass(frozen=True)
class DFVNetConfig:
    """encoder: ResNet-18 stage widths (/4, /8, /16, /32). features: top-down widths at /32, /16, /8, /4.
    context: channels per pyramid-pooling branch and of its fusion conv; pool_windows: fixed pooling windows
    (feature pixels at /32) besides the global mean. levels: decoder levels (1..4). decoder: 3-D widths per
    level (/4, /8, /16, /32); blocks: residual 3-D blocks per level. pad_mode: the convs' padding
    (blocks.PAD_MODES; zeros as published)."""

    encoder: tuple[int, int, int, int] = (64, 128, 256, 512)
    features: tuple[int, int, int, int] = (128, 64, 32, 16)
    context_branch: int = 128
    context_fuse: int = 344
    pool_windows: tuple[int, ...] = (3, 5, 7)
    levels: int = 2
    decoder: tuple[int, int, int, int] = (16, 32, 64, 128)
    blocks: tuple[int, int, int, int] = (2, 3, 3, 3)
    pad_mode: str = "zeros"


DFVNET_CONFIGS = {
    "full": DFVNetConfig(),
    "small": DFVNetConfig(encoder=(16, 32, 64, 128), features=(32, 16, 12, 8), context_branch=16,
                          context_fuse=64, decoder=(8, 12, 16, 32), blocks=(1, 2, 2, 2)),
}


def window_mean(x: Tensor, k: int) -> Tensor:
    """Mean over a k x k window (k odd) centred on each cell, cells outside the image excluded; separable, so its
    cost grows with k, not k^2, and it is exactly the 2-D mean (the valid cells form a rectangle).
    (N, C, h, w) -> (N, C, h, w)"""
    if k < 1 or k % 2 == 0:
        raise ValueError(f"window_mean: the window must be odd and positive, got {k}")
    x = F.avg_pool2d(x, (k, 1), 1, (k // 2, 0), count_include_pad=False)
    return F.avg_pool2d(x, (1, k), 1, (0, k // 2), count_include_pad=False)


class PyramidPool2d(nn.Module):
    """Context from a global mean and fixed-window means (stride 1, 'same', padded cells excluded), each
    projected by a 1x1 conv, concatenated with the input and fused by a 3x3 conv. (N, C, h, w) -> (N, C_out, h, w)."""

    def __init__(self, c_in: int, c_branch: int, c_fuse: int, c_out: int, windows: tuple[int, ...]):
        super().__init__()
        self.windows = tuple(windows)
        self.proj = nn.ModuleList(ConvBNReLU2d(c_in, c_branch, 1) for _ in range(len(windows) + 1))
        self.fuse = nn.Sequential(ConvBNReLU2d(c_in + c_branch * (len(windows) + 1), c_fuse, 3),
                                  ConvBNReLU2d(c_fuse, c_out, 3))

    # The "global" branch's window (feature pixels, odd) or None for the whole image. A net trained on images of
    # n feature pixels sees the same mean through any window >= 2n - 1, so a window keeps its context the size it
    # trained on when it runs on whole frames, where the image mean is out of its training distribution.
    global_window: int | None = None

    def forward(self, x: Tensor) -> Tensor:
        ctx = x.mean((2, 3), keepdim=True) if self.global_window is None else window_mean(x, self.global_window)
        outs = [x, self.proj[0](ctx).expand(-1, -1, x.shape[2], x.shape[3])]
        for k, proj in zip(self.windows, self.proj[1:]):
            outs.append(proj(F.avg_pool2d(x, k, 1, k // 2, count_include_pad=False)))
        return self.fuse(torch.cat(outs, 1))


class TopDown2d(nn.Module):
    """x2 bilinear upsampling of the coarser feature, a lateral conv of the encoder feature, fused by a 3x3 conv."""

    def __init__(self, c_coarse: int, c_lateral: int, c_out: int):
        super().__init__()
        self.up = ConvBNReLU2d(c_coarse, c_out, 3)
        self.lateral = ConvBNReLU2d(c_lateral, c_out, 3)
        self.fuse = ConvBNReLU2d(2 * c_out, c_out, 3)

    def forward(self, coarse: Tensor, lateral: Tensor) -> Tensor:
        up = F.interpolate(coarse, scale_factor=2.0, mode="bilinear", align_corners=False)
        return self.fuse(torch.cat([self.up(up), self.lateral(lateral)], 1))


class FrameEncoder(nn.Module):
    """ResNet-18-like trunk + pyramid pooling + top-down path: frames (N, 3, H, W) -> [/4, /8, /16, /32] features."""

    def __init__(self, cfg: DFVNetConfig, in_channels: int = 3):
        super().__init__()
        e = cfg.encoder
        self.stem = nn.Sequential(ConvBNReLU2d(in_channels, e[0], 7, 2), nn.MaxPool2d(3, 2, 1))  # /4
        stages, c = [], e[0]
        for i, w in enumerate(e):
            stride = 1 if i == 0 else 2
            stages.append(nn.Sequential(BasicBlock2d(c, w, stride), BasicBlock2d(w, w)))
            c = w
        self.stages = nn.ModuleList(stages)
        f32, f16, f8, f4 = cfg.features
        self.context = PyramidPool2d(e[3], cfg.context_branch, cfg.context_fuse, f32, cfg.pool_windows)
        self.td16 = TopDown2d(f32, e[2], f16)
        self.td8 = TopDown2d(f16, e[1], f8)
        self.td4 = TopDown2d(f8, e[0], f4)

    def forward(self, x: Tensor) -> list[Tensor]:
        feats = []
        x = self.stem(x)
        for stage in self.stages:
            x = stage(x)
            feats.append(x)
        p32 = self.context(feats[3])
        p16 = self.td16(p32, feats[2])
        p8 = self.td8(p16, feats[1])
        p4 = self.td4(p8, feats[0])
        return [p4, p8, p16, p32]


class PyramidPool3d(nn.Module):
    """3-D decoder context at coarse levels: per-frame global mean and fixed-window means over (h, w), added
    through 1x1x1 convs. (B, C, S, h, w) -> same shape."""

    def __init__(self, c: int, windows: tuple[int, ...]):
        super().__init__()
        self.windows = tuple(windows)
        self.proj = nn.ModuleList(ConvBNReLU3d(c, c, 1) for _ in range(len(windows) + 1))

    def forward(self, x: Tensor) -> Tensor:
        out = x + self.proj[0](x.mean((3, 4), keepdim=True)).expand_as(x)
        for k, proj in zip(self.windows, self.proj[1:]):
            out = out + proj(F.avg_pool3d(x, (1, k, k), 1, (0, k // 2, k // 2), count_include_pad=False))
        return out / (len(self.windows) + 2)


class DecoderLevel3d(nn.Module):
    """One decoder level: (volume at this scale [+ upsampled coarser state]) -> residual 3-D blocks
    [-> context] -> logits (B, S, h, w) and the state passed to the next finer level."""

    def __init__(self, c_vol: int, c_coarse: int, c: int, n_blocks: int, context: tuple[int, ...] | None):
        super().__init__()
        self.inp = ConvBNReLU3d(c_vol + c_coarse, c, 3)
        self.blocks = nn.Sequential(*(ResBlock3d(c) for _ in range(n_blocks)))
        self.context = PyramidPool3d(c, context) if context else nn.Identity()
        self.classify = nn.Sequential(ConvBNReLU3d(c, c, 3), nn.Conv3d(c, 1, 3, 1, 1))

    def forward(self, vol: Tensor, coarse: Tensor | None) -> tuple[Tensor, Tensor]:
        if coarse is not None:
            up = F.interpolate(coarse, scale_factor=(1.0, 2.0, 2.0), mode="trilinear", align_corners=False)
            vol = torch.cat([vol, up], 1)
        x = self.context(self.blocks(self.inp(vol)))
        return self.classify(x)[:, 0], x


class DFVNet(nn.Module):
    """Per-frame 2-D features, differential focus volume, 3-D decoder:
    stack (B, S, 3, H, W) -> [logits (B, S, H, W)] finest first (coarser levels only in training)."""

    size_multiple = 32

    def __init__(self, cfg: DFVNetConfig = DFVNetConfig(), differential: bool = True, in_channels: int = 3):
        super().__init__()
        if not 1 <= cfg.levels <= 4:
            raise ValueError(f"DFVNet levels must be 1..4, got {cfg.levels}")
        self.cfg, self.differential = cfg, differential
        self.encoder = FrameEncoder(cfg, in_channels)
        feats = tuple(reversed(cfg.features))  # /4, /8, /16, /32
        decs = []
        for i in range(cfg.levels):  # i = 0 is /4
            c_coarse = cfg.decoder[i + 1] if i + 1 < cfg.levels else 0
            decs.append(DecoderLevel3d(feats[i], c_coarse, cfg.decoder[i], cfg.blocks[i],
                                       cfg.pool_windows if i >= 2 else None))
        self.decoders = nn.ModuleList(decs)
        init_weights(self)
        set_padding_mode(self, cfg.pad_mode)

    def volume(self, feat: Tensor, b: int, s: int) -> Tensor:
        """(B*S, C, h, w) -> focus volume (B, C, S, h, w); differential: slice i = f(i) - f(i+1), last kept."""
        f = feat.reshape(b, s, feat.shape[1], feat.shape[2], feat.shape[3])
        if self.differential:
            f = torch.cat([f[:, :-1] - f[:, 1:], f[:, -1:]], 1)
        return f.transpose(1, 2)

    def forward(self, stack: Tensor) -> list[Tensor]:
        """stack (B, S, C, H, W) (C = in_channels: RGB [+ field coordinates]), H and W multiples of 32 ->
        [logits (B, S, H, W), ...] finest first."""
        b, s, c, h, w = stack.shape
        return self.decode(self.encoder(stack.reshape(b * s, c, h, w)), b, s)

    def decode(self, feats: list[Tensor], b: int, s: int) -> list[Tensor]:
        """Per-frame features [/4, /8, /16, /32] of B x S frames -> [logits (B, S, H, W), ...] finest first."""
        logits, state = [], None
        for i in reversed(range(self.cfg.levels)):
            lg, state = self.decoders[i](self.volume(feats[i], b, s), state)
            logits.append((i, lg))
        out = []
        for i, lg in reversed(logits):  # finest first
            if i > 0 and not self.training:
                continue
            out.append(F.interpolate(lg, scale_factor=float(4 * 2**i), mode="bilinear", align_corners=False))
        return out
