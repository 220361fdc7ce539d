"""Distances as 16-bit PNG in millimetres: `depth_mm.png`, `std_mm.png` (aat-infer) and `gt_depth_mm.png` (aat-gt
render, the virtual camera) are written by `encode_mm16` alone, so they follow one policy.

Policy, metres -> uint16 millimetres:
- a known value becomes round(metres x 1000) (to the nearest mm, halves to even);
- unknown (NaN, -inf, 0 or negative) becomes 0, which every reader takes as unknown; so does anything below
  0.5 mm, which rounds to 0;
- beyond 65.535 m (+inf included) is **clipped** to 65535: such a pixel reads back as 65.535 m, not as unknown.
  `encode_mm16` returns how many were clipped, and the writers say so (aat-gt: `beyond_png_range` in
  gt_render.json; aat-infer: the file's line in summary.json's `outputs`). The float maps (`*_m.npy`) keep the values.
Reading: metres = value x `M_PER_MM`, 0 = unknown (`aat_deploy.gt.read`).
"""

from __future__ import annotations

import numpy as np

M_PER_MM = 0.001
MAX_MM = 65535  # the largest value a 16-bit PNG holds: 65.535 m


def encode_mm16(x_m: np.ndarray) -> tuple[np.ndarray, int]:
    """(H, W) metres -> ((H, W) uint16 millimetres, number of pixels clipped at MAX_MM). Computed in the input's
    float precision (float32 maps round as float32)."""
    x = np.asarray(x_m)
    if x.dtype.kind != "f":
        x = x.astype(np.float64)
    with np.errstate(invalid="ignore", over="ignore"):  # huge float32 values overflow to inf: clipped
        mm = np.rint(np.where(np.isnan(x) | (x <= 0), 0.0, x) * 1000.0)  # +inf stays inf: clipped below
        clipped = int(np.count_nonzero(mm > MAX_MM))
    return np.clip(mm, 0, MAX_MM).astype(np.uint16), clipped
