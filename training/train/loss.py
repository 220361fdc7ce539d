"""The DfF loss (the paper's): L1 on depth over valid ground truth, plus optional all-in-focus L1 and edge-aware
smoothness terms. Depth in metres, images in normalised units."""

from __future__ import annotations

import torch
from torch import Tensor

from training.train.config import LossConfig


def depth_mask(gt_m: Tensor, focus_m: Tensor | None = None) -> Tensor:
    """(B, H, W) bool: g > 0 and finite [and inside each stack's [min, max] focus when focus_m (B, S) given]."""
    m = torch.isfinite(gt_m) & (gt_m > 0)
    if focus_m is not None:
        lo = focus_m.min(1).values[:, None, None]
        hi = focus_m.max(1).values[:, None, None]
        m = m & (gt_m >= lo) & (gt_m <= hi)
    return m


def masked_l1(pred: Tensor, gt: Tensor, mask: Tensor) -> Tensor:
    """Mean |pred - gt| over the mask (0, still connected to the graph, when the mask is empty)."""
    diff = torch.where(mask, (pred - torch.where(mask, gt, torch.zeros_like(gt))).abs(), torch.zeros_like(pred))
    return diff.sum() / mask.sum().clamp_min(1)


def weighted_l1(pred: Tensor, gt: Tensor, weight: Tensor) -> Tensor:
    """sum w |pred - gt| / sum w over pixels of weight w >= 0 (0, still connected to the graph, when all are 0);
    gt is not read where w = 0. With 0 / 1 weights it is masked_l1."""
    diff = torch.where(weight > 0, (pred - torch.where(weight > 0, gt, torch.zeros_like(gt))).abs(),
                       torch.zeros_like(pred))
    return (weight * diff).sum() / weight.sum().clamp_min(1e-12)


def edge_aware_smoothness(depth_m: Tensor, image: Tensor, edge: float = 150.0, eps: float = 1e-3) -> Tensor:
    """Charbonnier of depth gradients weighted by exp(-edge * mean_c |image gradient|).
    depth_m (B, H, W), image (B, 3, H, W)."""
    dx = depth_m[:, :, 1:] - depth_m[:, :, :-1]
    dy = depth_m[:, 1:, :] - depth_m[:, :-1, :]
    wx = torch.exp(-edge * (image[..., :, 1:] - image[..., :, :-1]).abs().mean(1))
    wy = torch.exp(-edge * (image[..., 1:, :] - image[..., :-1, :]).abs().mean(1))
    return (wx * torch.sqrt(dx * dx + eps * eps)).mean() + (wy * torch.sqrt(dy * dy + eps * eps)).mean()


def dff_loss(levels: list[tuple[Tensor, Tensor | None, Tensor]], batch: dict[str, Tensor],
             cfg: LossConfig) -> tuple[Tensor, dict[str, float]]:
    """levels: head outputs (depth_m (B, H, W), aif (B, 3, H, W) | None, std_m) finest first.
    batch: "depth_m" (B, H, W), "focus_m" (B, S), optional "aif" (B, 3, H, W).
    Returns the total loss and its parts as floats."""
    gt = batch["depth_m"]
    mask = depth_mask(gt, batch["focus_m"] if cfg.mask_focus_range else None)
    weights = list(cfg.level_weights)[: len(levels)]
    wsum = sum(weights)
    if cfg.depth_space == "diopter":  # every depth weighted by its focus information (blur is linear in 1/d)
        inv_gt = 1.0 / torch.where(mask, gt, torch.ones_like(gt))
        l_depth = sum(w * masked_l1(1.0 / lv[0].clamp_min(1e-3), inv_gt, mask)
                      for w, lv in zip(weights, levels)) / wsum
    else:
        l_depth = sum(w * masked_l1(lv[0], gt, mask) for w, lv in zip(weights, levels)) / wsum
    total = cfg.depth * l_depth
    parts = {"depth_l1": float(masked_l1(levels[0][0].detach(), gt, mask))}
    depth0, aif0, _ = levels[0]
    if cfg.aif > 0:
        if "aif" not in batch or aif0 is None:
            raise ValueError("loss.aif > 0 needs an 'aif' ground truth in the batch")
        l_aif = (aif0 - batch["aif"]).abs().mean()
        total = total + cfg.aif * l_aif
        parts["aif_l1"] = float(l_aif.detach())
    if cfg.smooth > 0:
        l_s = edge_aware_smoothness(depth0, aif0.detach(), cfg.smooth_edge)
        total = total + cfg.smooth * l_s
        parts["smooth"] = float(l_s.detach())
    parts["total"] = float(total.detach())
    return total, parts


def focus_map_loss(levels: list[tuple], batch: dict[str, Tensor], cfg: LossConfig) -> tuple[Tensor, dict[str, float]]:
    """The any-camera net's loss (training.nets.dfvaat): L1 of the interpolated diopters in units of each pixel's
    mean frame spacing (so a phone's 10-diopter sweep and a full-frame camera's 2-diopter one weigh alike: the
    error is in frames). Its optimum, the median, is the same in diopters as in metres; a loss in metres is not
    bounded here (a sweep ending near infinity puts some frames' diopters at or past 0, where depth is 1 km), and
    with an L1 of depth relative to the median depth added, such pixels made the first run's loss jump 30-fold.
    The relative depth error is logged (rel_l1), not optimised.
    levels: [(depth_m, aif, std_m, diopters), ...] finest first; batch: "depth_m" (B, H, W), "focus_diopters"
    (B, S, H, W); optional "aif" for cfg.aif."""
    gt = batch["depth_m"]
    mask = depth_mask(gt)
    fd = batch["focus_diopters"]
    s = fd.shape[1]
    # per pixel (a mosaic's quadrants are different cameras; within one camera the field changes it little)
    spacing = ((fd.max(1).values - fd.min(1).values) / max(s - 1, 1)).clamp_min(1e-3)
    inv_gt = 1.0 / torch.where(mask, gt, torch.ones_like(gt))
    med = torch.stack([g[m].median() if m.any() else g.new_tensor(1.0) for g, m in zip(gt, mask)])[:, None, None]
    weights = list(cfg.level_weights)[: len(levels)]
    wsum = sum(weights)
    inside = mask & (inv_gt <= fd.max(1).values) & (inv_gt >= fd.min(1).values)  # what depth from focus can reach
    # pixels beyond their frames' range weigh cfg.out_of_range_weight: their error's floor (the distance to the
    # nearest end frame) is no interpolation's to remove, and L1's gradient there never fades
    px_w = torch.where(inside, torch.ones_like(gt), torch.full_like(gt, float(cfg.out_of_range_weight))) * mask
    l_frames = sum(w * weighted_l1(lv[3] / spacing, inv_gt / spacing, px_w)
                   for w, lv in zip(weights, levels)) / wsum
    total = cfg.depth * l_frames
    parts = {"frames_l1": float(masked_l1(levels[0][3].detach() / spacing, inv_gt / spacing, mask)),
             "frames_l1_in_range": float(masked_l1(levels[0][3].detach() / spacing, inv_gt / spacing, inside)),
             "rel_l1": float(masked_l1(levels[0][0].detach() / med, gt / med, mask)),
             "depth_l1": float(masked_l1(levels[0][0].detach(), gt, mask))}
    if cfg.aif > 0:
        l_aif = (levels[0][1] - batch["aif"]).abs().mean()
        total = total + cfg.aif * l_aif
        parts["aif_l1"] = float(l_aif.detach())
    parts["total"] = float(total.detach())
    return total, parts
