"""Evaluate a DfF model over a dataset with aat_deploy.metrics: mean metrics over images and the mean
absolute depth error map (the paper's field-uniformity figure)."""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset

from aat_deploy.metrics import MetricAccumulator
from training.nets import registry
from training.nets.model import DfFNet, predict


@torch.no_grad()
def evaluate(model: DfFNet, dataset: Dataset, max_items: int | None = None, focus_range_mask: bool = False,
             ) -> tuple[dict[str, float], np.ndarray | None]:
    """Run `model` (via predict: sorted, padded, cropped; float32, on the model's device) over up to `max_items`
    items, one at a time. Returns (metrics averaged over images, error map (H, W) mean |depth - gt| in metres, or
    None when the items differ in size)."""
    dev = next(model.parameters()).device
    was_training = model.training
    model.eval()
    acc = MetricAccumulator(focus_range_mask=focus_range_mask)
    n = len(dataset) if max_items is None else min(max_items, len(dataset))
    spec = registry.NETS.get(getattr(model, "name", ""))
    maps_in = spec is not None and spec.focus_maps
    try:
        for i in range(n):
            item = dataset[i]
            if maps_in:  # per-pixel focus maps (training.nets.dfvaat)
                from training.nets.dfvaat import predict as predict_focus_map

                out = predict_focus_map(model, item["stack"][None].float().to(dev),
                                        item["focus_diopters"][None].float().to(dev),
                                        item["defocus_px_per_d"][None].float().to(dev))
                acc.add(out["depth_m"][0].cpu().numpy(), np.asarray(item["depth_m"]),
                        out["aif"][0].clamp(0, 1).cpu().numpy(), np.asarray(item["aif"]),
                        focus_m=np.asarray(item["focus_m"]))
                continue
            field = item["field_xy"][None].float().to(dev) if model.field_channels and "field_xy" in item else None
            out = predict(model, item["stack"][None].float().to(dev), item["focus_m"][None].float().to(dev), field)
            aif_ref = item.get("aif")
            acc.add(out["depth_m"][0].cpu().numpy(), np.asarray(item["depth_m"]),
                    out["aif"][0].clamp(0, 1).cpu().numpy(),
                    None if aif_ref is None else np.asarray(aif_ref), focus_m=np.asarray(item["focus_m"]))
    finally:
        model.train(was_training)
    return acc.result(), (acc.error_map() if acc.has_error_map else None)
