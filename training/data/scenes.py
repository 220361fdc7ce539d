"""Procedural RGB-D scenes for training without downloads (in the spirit of FlyingThings3D).

A textured background plane, slanted in depth, and textured shapes (ellipses, polygons, rectangles) at random
metric depths, composited far to near so nearer shapes occlude farther ones. Each shape is a slanted plane too:
its inverse depth varies linearly across the image, as a 3-D plane's does. Textures mix multi-scale noise,
stripes, checkers and gradients so every depth has focus cues, and optionally real photographs
(`photo_fraction`, training.data.textures). Output: linear RGB in [0, 1] (H, W, 3) float32
and depth in metres from the sensor (H, W) float32, sampled in diopters between near_m and far_m.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SceneConfig:
    height: int = 480
    width: int = 640
    near_m: float = 0.5
    far_m: float = 10.0
    min_shapes: int = 4
    max_shapes: int = 12
    max_slant_d: float = 0.3  # largest change of inverse depth across the image (diopters)
    photo_fraction: float = 0.0  # chance that a surface is textured with a real photograph (training.data.textures)
    photo_split: str = "train"  # which photographs: "train" or "test" (held-out scenes)


def _surface(rng: np.random.Generator, h: int, w: int, cfg: SceneConfig) -> np.ndarray:
    """A texture for one surface: a photograph with probability photo_fraction, else a procedural one. With
    photo_fraction 0 no extra random number is drawn, so such scenes are the same as before photographs existed."""
    if cfg.photo_fraction > 0 and rng.random() < cfg.photo_fraction:
        from training.data.textures import photo_texture

        return photo_texture(rng, h, w, cfg.photo_split)
    return texture(rng, h, w)


def _noise(rng: np.random.Generator, h: int, w: int, octaves: int = 7) -> np.ndarray:
    """Multi-scale value noise in [0, 1]: random grids upsampled bicubically, halving amplitude per octave."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        cells = 2 ** (o + 2)
        g = rng.random((cells, max(2, cells * w // h))).astype(np.float32)
        out += amp * cv2.resize(g, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.9  # keep fine octaves strong: edges at every scale
    out /= total
    return np.clip((out - out.min()) / (np.ptp(out) + 1e-6), 0, 1)


def texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """(h, w, 3) random texture with edges at many scales and orientations."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    kind = rng.integers(4)
    if kind == 0:
        base = _noise(rng, h, w)
    elif kind == 1:  # stripes at a random angle and period, modulated by noise
        a, period = rng.uniform(0, np.pi), rng.uniform(3, 40)
        base = 0.5 + 0.5 * np.sign(np.sin((xx * np.cos(a) + yy * np.sin(a)) * 2 * np.pi / period))
        base = 0.6 * base + 0.4 * _noise(rng, h, w)
    elif kind == 2:  # checkerboard
        c = rng.uniform(4, 48)
        base = ((np.floor(xx / c) + np.floor(yy / c)) % 2).astype(np.float32)
        base = 0.7 * base + 0.3 * _noise(rng, h, w)
    else:  # smooth gradient plus fine noise
        base = 0.3 * (xx / w * rng.uniform(-1, 1) + yy / h * rng.uniform(-1, 1)) + 0.7 * _noise(rng, h, w)
    base = np.clip((base - base.min()) / (np.ptp(base) + 1e-6), 0, 1)
    # Two colours at least 0.5 apart so every texture has contrast (focus cues).
    c0 = rng.random(3)
    step = rng.normal(size=3)
    c1 = np.clip(c0 + step / np.linalg.norm(step) * rng.uniform(0.5, 1.0), 0, 1)
    return (c0[None, None] * (1 - base[..., None]) + c1[None, None] * base[..., None]).astype(np.float32)


def _shape_mask(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    m = np.zeros((h, w), np.uint8)
    cx, cy = rng.uniform(0, w), rng.uniform(0, h)
    size = rng.uniform(0.08, 0.45) * min(h, w)
    kind = rng.integers(3)
    if kind == 0:
        cv2.ellipse(m, (int(cx), int(cy)), (int(size), int(size * rng.uniform(0.3, 1.0))),
                    float(rng.uniform(0, 180)), 0, 360, 1, -1)
    elif kind == 1:
        n = rng.integers(3, 9)
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        rad = size * rng.uniform(0.4, 1.0, n)
        pts = np.stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang)], -1).astype(np.int32)
        cv2.fillPoly(m, [pts], 1)
    else:
        rect = ((float(cx), float(cy)), (float(size * 2), float(size * rng.uniform(0.3, 2))), float(rng.uniform(0, 90)))
        cv2.fillPoly(m, [cv2.boxPoints(rect).astype(np.int32)], 1)
    return m.astype(bool)


def _plane_inv_depth(rng: np.random.Generator, h: int, w: int, inv0: float, slant: float) -> np.ndarray:
    """Inverse depth of a slanted plane: linear in image coordinates around inv0."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    a = rng.uniform(0, 2 * np.pi)
    ramp = ((xx / w - 0.5) * np.cos(a) + (yy / h - 0.5) * np.sin(a))
    return inv0 + slant * ramp


def procedural_scene(cfg: SceneConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One scene: (rgb (H, W, 3) float32 in [0, 1], depth_m (H, W) float32), depth within near_m..far_m."""
    h, w = cfg.height, cfg.width
    lo, hi = 1.0 / cfg.far_m, 1.0 / cfg.near_m
    # Background in the farther part of the range, shapes anywhere; paint far -> near.
    bg_inv = rng.uniform(lo, lo + 0.3 * (hi - lo))
    inv = _plane_inv_depth(rng, h, w, bg_inv, rng.uniform(0, cfg.max_slant_d))
    rgb = _surface(rng, h, w, cfg)
    n = int(rng.integers(cfg.min_shapes, cfg.max_shapes + 1))
    layers = sorted(rng.uniform(lo, hi, n))  # ascending inverse depth = far first
    for inv0 in layers:
        m = _shape_mask(rng, h, w)
        plane = _plane_inv_depth(rng, h, w, inv0, rng.uniform(0, cfg.max_slant_d))
        front = m & (plane > inv)  # a shape only covers what is behind it
        rgb[front] = _surface(rng, h, w, cfg)[front]
        inv[front] = plane[front]
    inv = np.clip(inv, lo, hi)
    return rgb, (1.0 / inv).astype(np.float32)
