"""Test helpers for the training side: a tiny synthetic focal-stack set (thin-lens Gaussian blur of random
textures at two depth planes) and a small training config."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from aat_deploy.infer.normalise import normalise_stack
from training.train.config import TrainConfig


def _blur(img: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Gaussian blur of (3, H, W), reflect borders."""
    if sigma_px < 0.3:
        return img
    r = math.ceil(3 * sigma_px)
    x = torch.arange(-r, r + 1, dtype=torch.float32)
    k = torch.exp(-0.5 * (x / sigma_px) ** 2)
    k = k / k.sum()
    y = F.pad(img[:, None], (r, r, r, r), mode="reflect")
    y = F.conv2d(y, k.view(1, 1, 1, -1))
    return F.conv2d(y, k.view(1, 1, -1, 1))[:, 0]


class TwoPlaneStacks(Dataset):
    """Item i: a random texture, left/right (random split) at two depths in [0.6, 3] m, S frames focused
    evenly in diopters over [0.5, 4] m, thin-lens blur sigma = 2.5 px per diopter of defocus. Deterministic per i."""

    def __init__(self, n: int = 16, size: int = 32, s: int = 4, seed: int = 0):
        self.n, self.size, self.s, self.seed = n, size, s, seed

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> dict:
        g = torch.Generator().manual_seed(self.seed * 100003 + i)
        h = w = self.size
        tex = torch.rand(3, h // 4, w // 4, generator=g)
        tex = F.interpolate(tex[None], size=(h, w), mode="bilinear", align_corners=False)[0]
        tex = 0.5 * tex + 0.5 * torch.rand(3, h, w, generator=g)
        d = 1 / torch.empty(2).uniform_(1 / 3.0, 1 / 0.6, generator=g)
        split = int(torch.randint(w // 4, 3 * w // 4, (1,), generator=g))
        depth = torch.full((h, w), float(d[0]))
        depth[:, split:] = d[1]
        focus = 1 / torch.linspace(1 / 0.5, 1 / 4.0, self.s)
        frames = []
        for f in focus:
            left = _blur(tex, 2.5 * abs(1 / float(d[0]) - 1 / float(f)))
            right = _blur(tex, 2.5 * abs(1 / float(d[1]) - 1 / float(f)))
            frames.append(torch.where(torch.arange(w) < split, left, right))
        stack = torch.from_numpy(normalise_stack(torch.stack(frames).numpy()))
        depth[0, 0] = 0.0  # one invalid pixel
        return {"stack": stack, "focus_m": focus.float(), "depth_m": depth, "aif": tex.clamp(0, 1)}


def train_config(**kw) -> TrainConfig:
    base = {"name": "t", "net": "aifnet", "size": "small", "simulator": "thin_lens",
            "lens": "lenses/canon_rf50mm_f1.8.json", "steps": 6, "batch_size": 2, "lr": 2e-3,
            "checkpoint_every": 2, "log_every": 1, "val_items": 4}
    base.update(kw)
    return TrainConfig(**base).validate()
