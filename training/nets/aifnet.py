"""AiFNet (after Wang et al., "Bridging unsupervised and supervised depth from focus via all-in-focus
supervision", ICCV 2021): our own implementation of the published topology.

Encoder: an I3D Inception-v1-style 3-D conv net over the stack with every temporal stride 1 (the stack axis S
is never downsampled; 3x3x3 kernels mix neighbouring frames, so frames must be sorted by focus distance).
Spatial /2 (7x7x7 stem), /4, /8, /16, /32 by max pooling. Decoder: four [ConvTranspose3d (3,4,4) stride (1,2,2)
+ 3x3x3 conv] stages, each fed a 1x1x1 projection of the encoder feature at that scale, then a final transposed
conv to one logit per frame at full resolution. Input (B, S, 3, H, W) with H, W multiples of 32; output logits
(B, S, H, W).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from training.nets.blocks import ConvBNReLU3d, init_weights

# Inception-v1 mixed blocks as in I3D: (1x1, 3x3 reduce, 3x3, "5x5" reduce, "5x5" (a 3x3x3 in I3D), pool proj).
_MIXED = {
    "3b": (64, 96, 128, 16, 32, 32), "3c": (128, 128, 192, 32, 96, 64),
    "4b": (192, 96, 208, 16, 48, 64), "4c": (160, 112, 224, 24, 64, 64), "4d": (128, 128, 256, 24, 64, 64),
    "4e": (112, 144, 288, 32, 64, 64), "4f": (256, 160, 320, 32, 128, 128),
    "5b": (256, 160, 320, 32, 128, 128), "5c": (384, 192, 384, 48, 128, 128),
}


@dataclass(frozen=True)
class AiFNetConfig:
    """width: multiplier on every encoder width (1 = published). decoder: channels after each of the four
    decoder stages (1/16, 1/8, 1/4, 1/2); skip: channels of the projected encoder skips at those scales;
    bottleneck: channels of the 1x1x1 reduction of the 1/32 feature."""

    width: float = 1.0
    bottleneck: int = 320
    decoder: tuple[int, int, int, int] = (132, 64, 32, 16)
    skip: tuple[int, int, int, int] = (128, 64, 32, 16)


AIFNET_CONFIGS = {
    "full": AiFNetConfig(),
    "small": AiFNetConfig(width=0.125, bottleneck=48, decoder=(32, 16, 12, 8), skip=(16, 12, 8, 6)),
}


def _w(c: int, width: float) -> int:
    return max(4, round(c * width))


class Mixed3d(nn.Module):
    """Inception block in 3-D: four branches concatenated along channels; S, H, W kept."""

    def __init__(self, c_in: int, widths: tuple[int, ...], width: float):
        super().__init__()
        b0, b1r, b1, b2r, b2, b3 = (_w(c, width) for c in widths)
        self.b0 = ConvBNReLU3d(c_in, b0, 1)
        self.b1 = nn.Sequential(ConvBNReLU3d(c_in, b1r, 1), ConvBNReLU3d(b1r, b1, 3))
        self.b2 = nn.Sequential(ConvBNReLU3d(c_in, b2r, 1), ConvBNReLU3d(b2r, b2, 3))
        self.b3 = nn.Sequential(nn.MaxPool3d(3, 1, 1), ConvBNReLU3d(c_in, b3, 1))
        self.c_out = b0 + b1 + b2 + b3

    def forward(self, x: Tensor) -> Tensor:
        return torch.cat([self.b0(x), self.b1(x), self.b2(x), self.b3(x)], 1)


class UpStage3d(nn.Module):
    """x2 spatial upsampling (S kept) by a (3,4,4) transposed conv, concatenated with a projected skip, fused by
    a 3x3x3 conv. x (B, C_in, S, h, w), skip (B, C_skip, S, 2h, 2w) -> (B, C_out, S, 2h, 2w)."""

    def __init__(self, c_in: int, c_skip_in: int, c_skip: int, c_out: int):
        super().__init__()
        self.up = nn.Sequential(nn.ConvTranspose3d(c_in, c_out, (3, 4, 4), (1, 2, 2), (1, 1, 1), bias=False),
                                nn.BatchNorm3d(c_out), nn.ReLU(inplace=True))
        self.proj = ConvBNReLU3d(c_skip_in, c_skip, 1)
        self.fuse = ConvBNReLU3d(c_out + c_skip, c_out, 3)

    def forward(self, x: Tensor, skip: Tensor) -> Tensor:
        return self.fuse(torch.cat([self.up(x), self.proj(skip)], 1))


class AiFNet(nn.Module):
    """I3D-style 3-D encoder/decoder: stack (B, S, 3, H, W) -> [logits (B, S, H, W)] (one level)."""

    size_multiple = 32

    def __init__(self, cfg: AiFNetConfig = AiFNetConfig(), in_channels: int = 3):
        super().__init__()
        self.cfg = cfg
        w = cfg.width
        c1, c2b, c2c = _w(64, w), _w(64, w), _w(192, w)
        self.stem = ConvBNReLU3d(in_channels, c1, 7, (1, 2, 2))  # 1/2
        self.pool2 = nn.MaxPool3d((1, 3, 3), (1, 2, 2), (0, 1, 1))  # 1/4
        self.conv2 = nn.Sequential(ConvBNReLU3d(c1, c2b, 1), ConvBNReLU3d(c2b, c2c, 3))
        self.pool3 = nn.MaxPool3d((1, 3, 3), (1, 2, 2), (0, 1, 1))  # 1/8
        blocks, c = {}, c2c
        for name in ("3b", "3c", "4b", "4c", "4d", "4e", "4f", "5b", "5c"):
            blocks[name] = Mixed3d(c, _MIXED[name], w)
            c = blocks[name].c_out
        self.mixed = nn.ModuleDict(blocks)
        self.pool4 = nn.MaxPool3d(3, (1, 2, 2), 1)  # 1/16, temporal stride 1
        self.pool5 = nn.MaxPool3d((1, 3, 3), (1, 2, 2), (0, 1, 1))  # 1/32
        skips_in = (self.mixed["4f"].c_out, self.mixed["3c"].c_out, c2c, c1)
        self.bottleneck = ConvBNReLU3d(c, cfg.bottleneck, 1)
        stages, c = [], cfg.bottleneck
        for c_skip_in, c_skip, c_out in zip(skips_in, cfg.skip, cfg.decoder):
            stages.append(UpStage3d(c, c_skip_in, c_skip, c_out))
            c = c_out
        self.up = nn.ModuleList(stages)
        self.out = nn.ConvTranspose3d(c, 1, (3, 4, 4), (1, 2, 2), (1, 1, 1))  # full resolution, one logit map
        init_weights(self)

    def forward(self, stack: Tensor) -> list[Tensor]:
        """stack (B, S, C, H, W) (C = in_channels: RGB [+ field coordinates]), H and W multiples of 32 ->
        [logits (B, S, H, W)]."""
        x = stack.transpose(1, 2)  # (B, 3, S, H, W)
        e1 = self.stem(x)
        e2 = self.conv2(self.pool2(e1))
        x = self.pool3(e2)
        x = self.mixed["3c"](self.mixed["3b"](x))
        e3 = x
        x = self.pool4(x)
        for name in ("4b", "4c", "4d", "4e", "4f"):
            x = self.mixed[name](x)
        e4 = x
        x = self.pool5(x)
        x = self.mixed["5c"](self.mixed["5b"](x))
        x = self.bottleneck(x)
        for stage, skip in zip(self.up, (e4, e3, e2, e1)):
            x = stage(x, skip)
        return [self.out(x)[:, 0]]
