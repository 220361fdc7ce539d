"""Coloured point clouds as binary PLY (little endian): x, y, z float32 and red, green, blue uchar per vertex,
the layout Open3D, trimesh, MeshLab and CloudCompare read."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_ply(path: str | Path, points: np.ndarray, colors: np.ndarray, comments: list[str] = ()) -> None:
    """points (N, 3) float (written as float32), colors (N, 3) uint8 sRGB; comments go into the header, one line
    each (no newlines)."""
    pts = np.asarray(points, np.float32).reshape(-1, 3)
    col = np.asarray(colors, np.uint8).reshape(-1, 3)
    if len(pts) != len(col):
        raise ValueError(f"{len(pts)} points but {len(col)} colours")
    vert = np.empty(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                     ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    vert["x"], vert["y"], vert["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    vert["red"], vert["green"], vert["blue"] = col[:, 0], col[:, 1], col[:, 2]
    head = ["ply", "format binary_little_endian 1.0"]
    head += [f"comment {c}".replace("\n", " ") for c in comments]
    head += [f"element vertex {len(pts)}", "property float x", "property float y", "property float z",
             "property uchar red", "property uchar green", "property uchar blue", "end_header"]
    Path(path).write_bytes(("\n".join(head) + "\n").encode("ascii", "backslashreplace") + vert.tobytes())
