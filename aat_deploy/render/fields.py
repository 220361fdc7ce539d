"""Where a pixel looks: normalised field positions (x right, y up; +-1 at the sensor edges) of pixel coordinates
of a crop placed on the full sensor. Shared by the torch simulator and the torch-free twin renderer."""

from __future__ import annotations

import numpy as np


def field_of(rows, cols, sensor_hw: tuple[int, int], origin: tuple[int, int] = (0, 0)):
    """Normalised field (x right, y up; +-1 at the sensor edges) of points at (rows, cols) pixel coordinates of a
    window at `origin` of the sensor (pixel centres at +0.5)."""
    hs, ws = sensor_hw
    x = 2 * (np.asarray(cols, dtype=np.float64) + origin[1]) / ws - 1
    y = 1 - 2 * (np.asarray(rows, dtype=np.float64) + origin[0]) / hs
    return x, y


def pixel_fields(height: int, width: int, sensor_hw: tuple[int, int], origin: tuple[int, int] = (0, 0)):
    """Normalised field (x, y) of every pixel centre of an (height, width) window whose top-left pixel is
    `origin` = (row, col) of a full sensor of `sensor_hw` = (rows, cols) pixels. Returns two (H, W) arrays."""
    rows = np.arange(height, dtype=np.float64) + 0.5
    cols = np.arange(width, dtype=np.float64) + 0.5
    cc, rr = np.meshgrid(cols, rows, indexing="xy")
    return field_of(rr, cc, sensor_hw, origin)
