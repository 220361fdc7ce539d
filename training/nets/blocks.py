"""Small building blocks shared by the DfF networks: conv + batch norm + ReLU in 2-D and 3-D, residual blocks.

Shapes: 2-D blocks take (N, C, H, W); 3-D blocks take (B, C, S, H, W) with S the stack axis.
"""

from __future__ import annotations

from torch import Tensor, nn


def _triple(k: int | tuple[int, int, int]) -> tuple[int, int, int]:
    return (k, k, k) if isinstance(k, int) else tuple(k)


class ConvBNReLU3d(nn.Sequential):
    """Conv3d (no bias) + BatchNorm3d + ReLU; 'same' padding for odd kernels."""

    def __init__(self, c_in: int, c_out: int, kernel: int | tuple[int, int, int] = 3,
                 stride: int | tuple[int, int, int] = 1, relu: bool = True):
        k = _triple(kernel)
        layers: list[nn.Module] = [nn.Conv3d(c_in, c_out, k, _triple(stride), tuple(x // 2 for x in k), bias=False),
                                   nn.BatchNorm3d(c_out)]
        if relu:
            layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)


class ConvBNReLU2d(nn.Sequential):
    """Conv2d (no bias) + BatchNorm2d + ReLU; 'same' padding for odd kernels."""

    def __init__(self, c_in: int, c_out: int, kernel: int = 3, stride: int = 1, relu: bool = True):
        layers: list[nn.Module] = [nn.Conv2d(c_in, c_out, kernel, stride, kernel // 2, bias=False),
                                   nn.BatchNorm2d(c_out)]
        if relu:
            layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)


class BasicBlock2d(nn.Module):
    """ResNet basic block: two 3x3 convs with a (projected when the shape changes) identity path."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1):
        super().__init__()
        self.body = nn.Sequential(ConvBNReLU2d(c_in, c_out, 3, stride), ConvBNReLU2d(c_out, c_out, 3, relu=False))
        self.short = (nn.Identity() if stride == 1 and c_in == c_out
                      else nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride, bias=False), nn.BatchNorm2d(c_out)))
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x: Tensor) -> Tensor:
        return self.relu(self.body(x) + self.short(x))


class ResBlock3d(nn.Module):
    """3-D residual block: two 3x3x3 convs (stride 1, S and H, W kept) around an identity path."""

    def __init__(self, channels: int):
        super().__init__()
        self.body = nn.Sequential(ConvBNReLU3d(channels, channels), ConvBNReLU3d(channels, channels, relu=False))
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x: Tensor) -> Tensor:
        return self.relu(self.body(x) + x)


PAD_MODES = ("zeros", "reflect", "replicate")


def set_padding_mode(module: nn.Module, mode: str) -> nn.Module:
    """Every padded 2-D and 3-D conv in `module` pads with `mode` (PAD_MODES) instead of zeros; the weights and
    their names are unchanged. Zero padding marks the image border, which a net trained on small images can take
    as a cue that whole frames, whose centre is far from any border, never give (docs/training.md)."""
    if mode not in PAD_MODES:
        raise ValueError(f"padding mode must be one of {PAD_MODES}, got {mode!r}")
    for m in module.modules():
        if isinstance(m, (nn.Conv2d, nn.Conv3d)) and any(p > 0 for p in m.padding):
            m.padding_mode = mode
    return module


def init_weights(module: nn.Module) -> None:
    """Kaiming-normal (fan-out, ReLU) for every conv, unit/zero batch norm; the same for 2-D and 3-D layers."""
    for m in module.modules():
        if isinstance(m, (nn.Conv2d, nn.Conv3d, nn.ConvTranspose3d, nn.ConvTranspose2d)):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, (nn.BatchNorm2d, nn.BatchNorm3d)):
            nn.init.ones_(m.weight)
            nn.init.zeros_(m.bias)


def count_params(module: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
