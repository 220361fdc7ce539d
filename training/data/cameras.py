"""Random cameras and focus schedules for training one DfF net on every camera.

A camera is a sensor class (phone 1/2.5" to 1/1.3", 1-inch, APS-C, full frame), a focal length and f-number of that
class, and a working resolution (the pixels the net sees: 320 to 1280 px across, fewer when the blur per diopter
would exceed `K_MAX_PX_PER_D`, as the runtime brings captures to that limit too). Its best-focus map gets random
field curvature, tilt and astigmatism (`training.render.parametric`), sized in units of the schedule's frame
spacing so every camera sees shifts of a fraction of a frame to about two frames. A wide sweep
(`wide_sweep_camera`) is an APS-C or full-frame camera wide open sweeping its scene's whole depth range, the total
blur change drawn first (tens of pixels, as the held-out stacks have): `random_camera`'s sweeps are mostly phones'
and small apertures' of a few pixels.

Schedules are rendered dense (`RENDER_FRAMES` frames) and the frames a training stack shows are a subset chosen
when the item is read (`subset`): any S from 3 to 16, evenly strided (an even schedule stays even), a random
subset, or a phone-like few frames at the near end. Distances are metres from the sensor plane; diopters 1/m.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from aat_deploy.optics.focus_table import even_diopters
from training.render.parametric import Aberrations, Camera

K_MAX_PX_PER_D = 64.0  # blur growth the net is trained for at most (px of blur diameter per diopter)
RENDER_FRAMES = 16
MIN_FOCUS_FOCAL_LENGTHS = 8.0
S_RANGE = (3, 16)


@dataclass(frozen=True)
class SensorClass:
    name: str
    diag_mm: tuple[float, float]  # sensor diagonal range
    aspect: float  # width / height
    focal_mm: tuple[float, float]
    f_number: tuple[float, float]
    min_focus_m: tuple[float, float]  # nearest focus distance range
    weight: float


SENSOR_CLASSES = (
    SensorClass("phone", (7.2, 12.3), 4 / 3, (4.0, 7.0), (1.6, 2.2), (0.07, 0.15), 0.3),
    SensorClass("one_inch", (15.9, 15.9), 3 / 2, (9.0, 25.0), (1.8, 4.0), (0.05, 0.4), 0.15),
    SensorClass("aps_c", (28.2, 28.4), 3 / 2, (16.0, 56.0), (1.4, 4.0), (0.2, 0.5), 0.2),
    SensorClass("full_frame", (43.3, 43.3), 3 / 2, (24.0, 85.0), (1.4, 4.0), (0.25, 0.85), 0.35),
)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) if hi > lo else float(lo)


def random_camera(rng: np.random.Generator) -> tuple[Camera, dict]:
    """A random camera (no aberrations yet) and a description of the draw."""
    w = np.array([c.weight for c in SENSOR_CLASSES])
    cls = SENSOR_CLASSES[int(rng.choice(len(w), p=w / w.sum()))]
    diag = rng.uniform(*cls.diag_mm)
    focal = _log_uniform(rng, *cls.focal_mm)
    fno = _log_uniform(rng, *cls.f_number)
    width_mm = diag * cls.aspect / np.hypot(cls.aspect, 1.0)
    width_px = int(round(_log_uniform(rng, 320, 1280)))
    cam = Camera(focal, fno, (max(8, round(width_px / cls.aspect)), width_px), width_mm / width_px)
    k = cam.defocus_px_per_diopter(2.0)
    if k > K_MAX_PX_PER_D:  # fewer pixels, as the runtime does for such a camera
        width_px = max(160, int(width_px * K_MAX_PX_PER_D / k))
        cam = Camera(focal, fno, (max(8, round(width_px / cls.aspect)), width_px), width_mm / width_px)
    # a lens focuses no nearer than a few focal lengths (4 f is 1:1 macro; 8 f is a normal lens's close focus)
    min_focus = max(_log_uniform(rng, *cls.min_focus_m), MIN_FOCUS_FOCAL_LENGTHS * focal / 1000.0)
    info = {"class": cls.name, "sensor_mm": [width_mm, width_mm / cls.aspect], "focal_mm": focal, "f_number": fno,
            "width_px": cam.sensor_hw[1], "height_px": cam.sensor_hw[0], "min_focus_m": min_focus}
    return cam, info


MIN_SPAN_PX = 4.0  # a sweep changes the blur by at least this much (px), else there is nothing to learn from
MAX_SPAN_PX = 200.0  # and by at most this much: wider blur teaches nothing and renders with huge kernels (memory)


def random_focus_range(rng: np.random.Generator, min_focus_m: float, cls: str, k_px_per_d: float | None = None
                       ) -> tuple[float, float]:
    """(near, far) of a camera's sweep (m): phones mostly sweep the near range, other cameras anything from
    their nearest focus to a far distance (infinity focus kept finite: 50 m). With the camera's defocus scale
    k_px_per_d, sweeps whose blur changes by less than MIN_SPAN_PX or more than MAX_SPAN_PX over the whole range
    are drawn again (a few times; then the widest one drawn is kept, its near end moved back to MAX_SPAN_PX)."""
    best = None
    for _ in range(12):
        if cls == "phone" and rng.random() < 0.6:
            near = _log_uniform(rng, min_focus_m, 0.4)
            far = _log_uniform(rng, max(near * 2.0, 0.5), 5.0)
        else:
            near = _log_uniform(rng, min_focus_m, max(min_focus_m * 1.01, 3.0))
            far = _log_uniform(rng, near * 1.6, max(near * 1.7, 50.0))
        if not k_px_per_d:
            return near, far
        span = (1 / near - 1 / far) * k_px_per_d
        if best is None or (span > best[0] if best[0] < MIN_SPAN_PX else span < best[0]):
            best = (span, near, far)
        if MIN_SPAN_PX <= span <= MAX_SPAN_PX:
            return near, far
    span, near, far = best
    if span > MAX_SPAN_PX:
        near = 1.0 / (1.0 / far + MAX_SPAN_PX / k_px_per_d)
    return near, far


WIDE_SPAN_PX = (16.0, 140.0)  # total blur change of a wide sweep (px), drawn log-uniform: the held-out stacks' 50-80
WIDE_F_NUMBER = (1.4, 2.8)  # wide apertures: a focal stack is shot wide open
WIDE_SCENE_NEAR_M = (0.25, 3.0)  # nearest focus of a wide sweep (m; and no nearer than 8 focal lengths)
WIDE_DEPTH_RATIO = (1.5, 30.0)  # farthest / nearest surface
WIDE_K_PX_PER_D = 8.0  # least blur growth of a wide sweep's camera (px per diopter)
MAX_WIDTH_PX = 6000  # a 24-60 MP sensor's width: the finest working resolution a wide sweep is given
WIDE_SCHEDULES = (("even", "random", "depth"), (0.4, 0.2, 0.4))


def wide_sweep_camera(rng: np.random.Generator, max_width_px: int = MAX_WIDTH_PX
                      ) -> tuple[Camera, dict, float, float]:
    """A large-sensor camera (APS-C or full frame) at a wide aperture sweeping a scene's whole depth range, as
    the paper's protocol and a photographer's focus bracket do: (camera without aberrations, its description, near,
    far of the sweep in m). The total blur change over the sweep, k x (1/near - 1/far) with k the blur growth per
    diopter, is drawn log-uniform over WIDE_SPAN_PX and the working resolution (pixel pitch) set to give it: about
    half the `random_camera` sweeps change the blur by under 9 px in all, where the held-out stacks change it by
    50-80 px (benchmarks/probes/anycam_sweeps.py). k stays <= K_MAX_PX_PER_D as the runtime keeps it, the working
    resolution <= max_width_px: a 128 px render of a 2,000+ px wide camera sees a narrow slice of its scene (often one
    surface), not the depth range its sweep spans (`--window-coverage`). Draws over the limit are drawn again, so
    every draw within it is the same as with a higher limit."""
    by_name = {c.name: c for c in SENSOR_CLASSES}
    for _ in range(60):
        cls = by_name["aps_c" if rng.random() < 0.4 else "full_frame"]
        diag = rng.uniform(*cls.diag_mm)
        focal = _log_uniform(rng, *cls.focal_mm)
        fno = _log_uniform(rng, *WIDE_F_NUMBER)
        width_mm = diag * cls.aspect / np.hypot(cls.aspect, 1.0)
        min_focus = max(WIDE_SCENE_NEAR_M[0], MIN_FOCUS_FOCAL_LENGTHS * focal / 1000.0)
        # the blur change and growth first, then the depth range that gives them (drawing the range first and
        # rejecting what needs k > K_MAX would leave few sweeps of large blur change)
        span_px = _log_uniform(rng, *WIDE_SPAN_PX)
        k = _log_uniform(rng, WIDE_K_PX_PER_D, K_MAX_PX_PER_D)
        ratio = _log_uniform(rng, *WIDE_DEPTH_RATIO)
        near = (1.0 - 1.0 / ratio) / (span_px / k)
        far = min(near * ratio, 50.0)
        k = span_px / (1.0 / near - 1.0 / far)
        # k at the sweep's mid focus, as the net is told it (`AnyCamDataset.focus_maps`)
        k1000 = Camera(focal, fno, (667, 1000), width_mm / 1000).defocus_px_per_diopter(float(np.sqrt(near * far)))
        width_px = int(round(1000 * k / k1000))
        if (min_focus <= near <= WIDE_SCENE_NEAR_M[1] and k <= K_MAX_PX_PER_D
                and 160 <= width_px <= max_width_px):
            break
    else:  # the last draw, brought inside the limits (its blur change then other than drawn)
        near = float(np.clip(near, min_focus, WIDE_SCENE_NEAR_M[1]))
        far = max(far, near * WIDE_DEPTH_RATIO[0])
        width_px = int(np.clip(round(1000 * min(k, K_MAX_PX_PER_D) / k1000), 160, max_width_px))
    cam = Camera(focal, fno, (max(8, round(width_px / cls.aspect)), width_px), width_mm / width_px)
    info = {"class": cls.name, "sweep": "wide", "sensor_mm": [width_mm, width_mm / cls.aspect], "focal_mm": focal,
            "f_number": fno, "width_px": width_px, "height_px": cam.sensor_hw[0], "min_focus_m": min_focus}
    return cam, info, near, far


def dense_schedule(rng: np.random.Generator, near_m: float, far_m: float, n: int = RENDER_FRAMES,
                   kind: str | None = None) -> tuple[np.ndarray, str]:
    """n focus distances (m) near -> far over [near_m, far_m]: 'even' in diopters (jittered by up to 0.2 of a
    spacing), 'random' (sorted uniform diopters) or 'depth' (linear in metres, the paper's protocol's shape)."""
    kind = kind or str(rng.choice(["even", "random", "depth"], p=[0.55, 0.25, 0.2]))
    dn, df = 1.0 / near_m, 1.0 / far_m
    if kind == "even":
        d = even_diopters(near_m, far_m, n)
        d = d + rng.uniform(-0.2, 0.2, n) * (dn - df) / (n - 1)
    elif kind == "random":
        d = np.sort(rng.uniform(df, dn, n))[::-1]
        d[0], d[-1] = dn, df
    else:
        d = 1.0 / np.linspace(near_m, far_m, n)
    d = np.sort(np.clip(d, df * 0.5, None))[::-1]
    # distinct frames: at least 1 % of the mean spacing apart
    gap = (d[0] - d[-1]) / (n - 1) * 0.01
    for i in range(1, n):
        d[i] = min(d[i], d[i - 1] - gap)
    return 1.0 / np.maximum(d, 1e-3), kind


def random_aberrations(rng: np.random.Generator, spacing_d: float, d_mid: float, strength: float = 1.0
                       ) -> Aberrations:
    """Field curvature, tilt and astigmatism in units of the schedule's frame spacing (diopters): up to about two
    frames of curvature at the corner, half a frame of tilt, a frame of astigmatism; about one camera in six is
    nearly perfect."""
    if rng.random() < 0.15:
        strength *= 0.1
    u = spacing_d * strength
    return Aberrations(c2=float(rng.normal(0, 0.8) * u), c4=float(rng.normal(0, 0.4) * u),
                       tx=float(rng.normal(0, 0.2) * u), ty=float(rng.normal(0, 0.2) * u),
                       a2=float(rng.normal(0, 0.5) * u), g=float(rng.uniform(-0.2, 0.2)), d_mid=float(d_mid),
                       b0_px=float(rng.uniform(0.4, 1.6)), shape_p=float(_log_uniform(rng, 2.0, 10.0)))


def least_map_diopters(cam: Camera, focus_m: np.ndarray, grid: int = 65) -> np.ndarray:
    """(S,) the least best-focus object diopters of each frame's map (focus_m sorted near -> far): either
    astigmatic focus, anywhere on the full sensor (a grid x grid lattice of fields, corners and edges included).
    Below 0 a frame's map passes infinity somewhere."""
    g = np.linspace(-1.0, 1.0, grid)
    x, y = np.meshgrid(g, g)
    f = np.sort(np.asarray(focus_m, np.float64))[:, None, None]
    d = 1.0 / f + cam.shift_diopters(x[None], y[None], f) - np.abs(0.5 * cam.aberrations.a2 * cam.radius(x, y) ** 2)
    return d.reshape(len(f), -1).min(1)


def limit_far_map(cam: Camera, focus_m: np.ndarray, floor: float) -> Camera:
    """`cam` with its aberrations scaled down (all of c2, c4, tilt and astigmatism by one factor <= 1) so that no
    frame's best-focus map (`least_map_diopters`) lies beyond 1 / (floor x the far frame's diopters) m: at most
    1 / floor times as far as the sweep's far focus, never past infinity. Aberrations sized in frame spacings
    (`random_aberrations`) exceed the far focus's own diopters on long sweeps (0.2 D of spacing against 0.023 D at
    43 m): the map then reaches 0 D or below in the corners, where a net that picks the far frame answers 1 km (the
    third run's validation spikes). floor 0: unchanged. A map already within the limit is returned as it is (the
    same draw, the same render)."""
    if floor <= 0:
        return cam
    f = np.sort(np.asarray(focus_m, np.float64))
    worst = least_map_diopters(cam, f) - 1.0 / f  # the shift towards the far side, linear in the scale
    room = 1.0 / f - floor / f[-1]  # how far each frame's map may move towards the far side (diopters)
    s = min([1.0] + [float(r / -w) for r, w in zip(room, worst) if w < 0 and r < -w])
    if s >= 1.0:
        return cam
    ab = cam.aberrations
    a = replace(ab, c2=ab.c2 * s, c4=ab.c4 * s, tx=ab.tx * s, ty=ab.ty * s, a2=ab.a2 * s)
    return Camera(cam.focal_mm, cam.f_number, cam.sensor_hw, cam.pixel_mm, a)


MIN_STEP_PX = 1.5  # frames are at least this much blur apart on average (px): finer steps carry little signal


def max_frames(span_px: float) -> int:
    """The most frames a sweep whose blur changes by span_px over its range is split into for training: its frames
    stay at least MIN_STEP_PX apart on average (a phone's few-pixel sweep is 3-4 frames, as phones shoot), within
    S_RANGE."""
    return int(np.clip(1 + np.floor(span_px / MIN_STEP_PX), S_RANGE[0], S_RANGE[1]))


def subset(rng, n: int, kind: str | None = None, s: int | None = None) -> tuple[np.ndarray, str]:
    """Indices (ascending: near -> far) of the frames of a dense schedule of n frames that one stack shows.
    rng: a numpy Generator or a torch Generator-like with `integers`. kind: 'stride' (S frames evenly strided
    through a window: an even schedule stays even), 'random' (any S frames), 'near' (phone-like: 3-6 frames from
    the near end, strided). S is drawn from S_RANGE unless given."""
    kind = kind or str(rng.choice(["stride", "random", "near"], p=[0.5, 0.3, 0.2]))
    if kind == "near":
        s = min(s or int(rng.integers(3, 7)), n)
        stride = int(rng.integers(1, max(1, (n // 2 + 2) // max(s - 1, 1)) + 1))
        stride = max(1, min(stride, (n - 1) // max(s - 1, 1)))
        return np.arange(s) * stride, kind
    s = min(s or int(rng.integers(S_RANGE[0], S_RANGE[1] + 1)), n)
    if kind == "stride":  # mostly the widest stride (the sweep's whole range), else any window
        widest = (n - 1) // max(s - 1, 1)
        stride = widest if rng.random() < 0.7 else int(rng.integers(1, widest + 1))
        start = int(rng.integers(0, n - (s - 1) * stride))
        return start + np.arange(s) * stride, kind
    # random: the sweep's two ends and any frames between (a sweep spans its range, unevenly)
    inner = np.sort(rng.choice(np.arange(1, n - 1), max(s - 2, 0), replace=False)) if s > 2 else np.array([], int)
    return np.concatenate([[0], inner, [n - 1]])[:s].astype(np.int64), kind
