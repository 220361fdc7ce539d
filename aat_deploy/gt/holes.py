"""Holes in a depth map filled for rendering: a renderer needs a depth at every pixel, ground truth has holes."""

from __future__ import annotations

import cv2
import numpy as np


def fill_holes(depth_m: np.ndarray) -> np.ndarray:
    """Copy of depth (H, W) with unknown pixels (<= 0) filled from the nearest known ones, for rendering. Filling
    takes the *farther* of neighbouring values first, since holes in stereo/lidar GT are mostly occluded background.
    Raises ValueError when no pixel is known."""
    d = np.asarray(depth_m, dtype=np.float32).copy()
    if not (d > 0).any():
        raise ValueError("depth has no valid pixel to fill from")
    kernel = np.ones((3, 3), np.uint8)
    for _ in range(4096):
        hole = d <= 0
        if not hole.any():
            break
        grown = cv2.dilate(d, kernel)  # the farthest valid neighbour
        d = np.where(hole & (grown > 0), grown, d)
    return d
