"""Procedural rooms seen through a camera: floor, walls and ceiling in perspective, furniture boxes standing on the
floor and hanging from the walls, pictures on the walls, occluders near the camera; textured with photographs,
procedural textures, plain colours (large textureless regions) and dark paint, lit by a lamp and ambient light.

The training scenes of `training.data.scenes` are planes and shapes facing the camera; real indoor content has
slanted planes that run through many depths (floor, walls), edges where one surface occludes another, and large
regions without texture. A ray caster over planes and axis-aligned boxes makes such a view for any window of a
camera's sensor (its focal length in pixels and the window's place on the sensor), so the perspective is the
camera's own.

Output: linear RGB (h, w, 3) float32 in [0, 1] and depth (h, w) float32 in metres along the optical axis (the
project's "metres from the sensor plane"; the lens's few centimetres are below the scenes' scale), supersampled 2x.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from training.data.scenes import texture


@dataclass(frozen=True)
class RoomConfig:
    """Room size ranges (m) before scaling; photo_fraction / plain_fraction / dark_fraction: chances that a
    surface is a photograph, a plain colour or dark paint (otherwise a procedural texture); photo_split as in
    training.data.textures."""

    width_m: tuple[float, float] = (3.0, 8.0)
    depth_m: tuple[float, float] = (3.0, 10.0)
    height_m: tuple[float, float] = (2.4, 3.2)
    boxes: tuple[int, int] = (2, 9)
    photo_fraction: float = 0.4
    plain_fraction: float = 0.25
    dark_fraction: float = 0.1
    photo_split: str = "train"


def _rot(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Camera-to-world rotation (x right, y down, z forward): roll about z, pitch about x, yaw about y."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return ry @ rx @ rz


class _Surfaces:
    """Nearest hit over planes and boxes, with per-surface id and 2-D texture coordinates (m)."""

    def __init__(self, origin: np.ndarray, dirs: np.ndarray):
        self.o, self.d = origin, dirs  # dirs (N, 3) world
        n = dirs.shape[0]
        self.t = np.full(n, np.inf)
        self.sid = np.full(n, -1, np.int32)
        self.uv = np.zeros((n, 2))
        self.normal = np.zeros((n, 3))
        self.count = 0

    def _take(self, t: np.ndarray, hit: np.ndarray, uv: np.ndarray, normal: np.ndarray) -> int:
        better = hit & (t > 1e-6) & (t < self.t)
        sid = self.count
        self.t[better] = t[better]
        self.sid[better] = sid
        self.uv[better] = uv[better]
        self.normal[better] = normal
        self.count += 1
        return sid

    def plane(self, axis: int, value: float, normal_sign: float) -> int:
        """The plane world[axis] = value (unbounded; rooms are closed by the other planes)."""
        d = self.d[:, axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (value - self.o[axis]) / d
        p = self.o[None] + t[:, None] * self.d
        other = [a for a in range(3) if a != axis]
        nrm = np.zeros(3)
        nrm[axis] = normal_sign
        return self._take(np.where(np.isfinite(t), t, np.inf), np.isfinite(t), p[:, other], nrm)

    def box(self, lo: np.ndarray, hi: np.ndarray) -> list[int]:
        """An axis-aligned box: one surface id per face hit (slab method; faces get their own texture ids)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / self.d
            t0 = (lo[None] - self.o[None]) * inv
            t1 = (hi[None] - self.o[None]) * inv
        tmin = np.minimum(t0, t1)
        tmax = np.maximum(t0, t1)
        tmin = np.where(np.isnan(tmin), -np.inf, tmin)
        tmax = np.where(np.isnan(tmax), np.inf, tmax)
        enter = tmin.max(1)
        leave = tmax.min(1)
        face = tmin.argmax(1)
        hit = (enter <= leave) & (enter > 1e-6)
        p = self.o[None] + enter[:, None] * self.d
        ids = []
        for axis in range(3):
            other = [a for a in range(3) if a != axis]
            sign = np.where(self.d[:, axis] > 0, -1.0, 1.0)
            for s in (-1.0, 1.0):
                m = hit & (face == axis) & (sign == s)
                nrm = np.zeros(3)
                nrm[axis] = s
                ids.append(self._take(enter, m, p[:, other] - lo[other][None], nrm))
        return ids


def _material(rng: np.random.Generator, cfg: RoomConfig, size: int = 256):
    """A surface's appearance: (texture (size, size, 3) linear RGB, texture metres per image)."""
    u = rng.random()
    if u < cfg.plain_fraction:
        c = rng.uniform(0.05, 0.9, 3)
        tex = np.broadcast_to(c, (size, size, 3)).astype(np.float32).copy()
        tex *= 1 + 0.01 * rng.standard_normal((size, size, 1)).astype(np.float32)  # paint is nearly uniform
    elif u < cfg.plain_fraction + cfg.photo_fraction:
        from training.data.textures import photo_texture

        tex = photo_texture(rng, size, size, cfg.photo_split)
    else:
        tex = texture(rng, size, size)
    if rng.random() < cfg.dark_fraction:
        tex = tex * rng.uniform(0.02, 0.12)
    return np.clip(tex, 0, 1).astype(np.float32), float(np.exp(rng.uniform(np.log(0.3), np.log(4.0))))


def _bilinear(tex: np.ndarray, r: np.ndarray, c: np.ndarray) -> np.ndarray:
    """tex (H, W, 3) sampled at (r, c) (N,) pixel coordinates, bilinear, clamped at the edges -> (N, 3)."""
    h, w = tex.shape[:2]
    r0 = np.clip(np.floor(r).astype(np.int64), 0, h - 1)
    c0 = np.clip(np.floor(c).astype(np.int64), 0, w - 1)
    r1, c1 = np.minimum(r0 + 1, h - 1), np.minimum(c0 + 1, w - 1)
    fr = np.clip(r - r0, 0, 1)[:, None].astype(np.float32)
    fc = np.clip(c - c0, 0, 1)[:, None].astype(np.float32)
    top = tex[r0, c0] * (1 - fc) + tex[r0, c1] * fc
    bot = tex[r1, c0] * (1 - fc) + tex[r1, c1] * fc
    return top * (1 - fr) + bot * fr


def room_scene(rng: np.random.Generator, h: int, w: int, f_px: float, centre_rc: tuple[float, float],
               depth_range_m: tuple[float, float], cfg: RoomConfig = RoomConfig()) -> tuple[np.ndarray, np.ndarray]:
    """One room view: rgb (h, w, 3) linear in [0, 1] and depth (h, w) metres along the optical axis.

    f_px: focal length in pixels; centre_rc: the optical axis's position (row, col) in this window's pixel
    coordinates (pixel centres at +0.5), so a window anywhere on the sensor sees its own part of the view.
    depth_range_m: (near, far) the room is scaled to: its nearest visible point lands near `near` and the far wall
    near `far` (a miniature or giant room looks the same to depth from focus)."""
    s = 2  # supersampling
    rows = (np.arange(h * s) + 0.5) / s - centre_rc[0]
    cols = (np.arange(w * s) + 0.5) / s - centre_rc[1]
    cc, rr = np.meshgrid(cols, rows)
    d_cam = np.stack([cc / f_px, rr / f_px, np.ones_like(cc)], -1).reshape(-1, 3)
    rw, rd, rh = (rng.uniform(*cfg.width_m), rng.uniform(*cfg.depth_m), rng.uniform(*cfg.height_m))
    cam_h = rng.uniform(0.4, min(1.8, rh - 0.3))
    cam_x = rng.uniform(-0.35, 0.35) * rw
    cam_z = rng.uniform(0.0, 0.3) * rd
    yaw = rng.uniform(-0.6, 0.6)
    pitch = rng.uniform(-0.45, 0.25)  # + looks down (y down)
    roll = rng.normal(0, 0.03)
    rot = _rot(yaw, pitch, roll)
    dirs = d_cam @ rot.T
    origin = np.array([cam_x, -cam_h, cam_z])  # world: y down, floor at y = 0
    surf = _Surfaces(origin, dirs)
    materials: dict[int, tuple] = {}

    def mat(ids):
        m = _material(rng, cfg)
        for i in np.atleast_1d(ids):
            materials[int(i)] = m

    mat(surf.plane(1, 0.0, -1.0))  # floor
    mat(surf.plane(1, -rh, 1.0))  # ceiling
    mat(surf.plane(2, rd, -1.0))  # back wall
    mat(surf.plane(2, -1.0, 1.0))  # wall behind the camera
    mat(surf.plane(0, -rw / 2, 1.0))
    mat(surf.plane(0, rw / 2, -1.0))
    fwd = rot[:, 2]
    for _ in range(int(rng.integers(cfg.boxes[0], cfg.boxes[1] + 1))):
        kind = rng.random()
        size = np.array([rng.uniform(0.3, 2.0), rng.uniform(0.3, 1.6), rng.uniform(0.3, 1.2)])
        if kind < 0.6:  # furniture on the floor, somewhere in front of the camera
            dist = rng.uniform(0.4, 1.0) * (rd - cam_z)
            cx = cam_x + fwd[0] / max(np.hypot(fwd[0], fwd[2]), 1e-6) * dist + rng.uniform(-0.5, 0.5) * rw
            cz = cam_z + dist
            lo = np.array([cx - size[0] / 2, -size[1], cz - size[2] / 2])
        elif kind < 0.8:  # a shelf or cabinet against a wall
            side = rng.choice([-1, 1])
            cz = rng.uniform(0.3, 1.0) * rd
            x0 = side * rw / 2 - (size[2] if side > 0 else 0)
            lo = np.array([x0, -rng.uniform(size[1], rh), cz])
            size = np.array([size[2] * 0.6, size[1], size[0]])
        else:  # an occluder close to the camera (a chair back, a plant, a door frame)
            dist = rng.uniform(0.15, 0.45) * (rd - cam_z)
            lo = np.array([cam_x + rng.uniform(-1.2, 1.2) - size[0] / 4, -rng.uniform(0.5, 1.0) * rh,
                           cam_z + dist])
            size = np.array([size[0] * 0.5, rng.uniform(0.3, 1.0) * rh, size[2] * 0.3])
        lo = np.clip(lo, [-rw / 2, -rh, 0.05], [rw / 2, 0, rd])
        hi = np.minimum(lo + size, [rw / 2, 0, rd])
        if np.all(hi - lo > 0.02):
            mat(surf.box(lo, hi))
    n_pix = dirs.shape[0]
    rgb = np.zeros((n_pix, 3), np.float32)
    lamp = np.array([rng.uniform(-rw / 2, rw / 2), -rh + 0.2, rng.uniform(0, rd)])
    ambient = rng.uniform(0.15, 0.6)
    hitp = origin[None] + surf.t[:, None] * dirs
    for sid, (tex, metres) in materials.items():
        m = surf.sid == sid
        if not m.any():
            continue
        uv = surf.uv[m] / metres * tex.shape[0]
        mx = np.mod(uv[:, 0], 2 * tex.shape[1])
        my = np.mod(uv[:, 1], 2 * tex.shape[0])
        mx = np.where(mx >= tex.shape[1], 2 * tex.shape[1] - mx - 1, mx).astype(np.float32)  # mirrored tiling
        my = np.where(my >= tex.shape[0], 2 * tex.shape[0] - my - 1, my).astype(np.float32)
        col = _bilinear(tex, my, mx)
        nrm = surf.normal[m]
        to_l = lamp[None] - hitp[m]
        dist = np.linalg.norm(to_l, axis=1, keepdims=True)
        lam = np.clip((nrm * to_l / np.maximum(dist, 1e-6)).sum(1), 0, None)
        shade = ambient + (1 - ambient) * lam * np.clip(3.0 / np.maximum(dist[:, 0], 0.5), 0, 1.5)
        rgb[m] = col * shade[:, None]
    depth = surf.t * (dirs @ fwd)  # along the optical axis
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    rgb = cv2.resize(rgb.reshape(h * s, w * s, 3), (w, h), interpolation=cv2.INTER_AREA)
    depth = depth.reshape(h * s, w * s)[s // 2::s, s // 2::s]
    if np.isnan(depth).any():
        depth = np.where(np.isnan(depth), np.nanmax(depth) if np.isfinite(depth).any() else 1.0, depth)
    # scale the room so its depths span the requested range (in diopters: near stays near, the far wall far)
    lo, hi = float(depth.min()), float(depth.max())
    near, far = depth_range_m
    # one scale for the whole room keeps its geometry: between the one that puts its nearest point at `near` and
    # the one that puts its farthest at `far`
    a, b = sorted((near / lo, far / hi))
    depth = depth * float(np.exp(rng.uniform(np.log(a), np.log(b))))
    depth = np.clip(depth, 0.5 * near, None)
    return np.clip(rgb, 0, 1).astype(np.float32), depth.astype(np.float32)
