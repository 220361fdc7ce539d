"""Real photographs as textures for procedural scenes (as FlyingThings3D textures its shapes with Flickr images).

The photographs ship inside pip packages (scikit-image's data set and matplotlib's sample data), so no download
is needed. They are split by file into a training and a test pool, so held-out scenes never show a photograph
seen in training. Images that are not photographs of in-focus content (drawings, test charts, the motion-blurred
clock) are left out, and so is the Middlebury Motorcycle pair: it is a test scene of its own.

A texture is a random crop of a random photograph, resized by a random zoom (never magnified past 1.5 output
pixels per photo pixel, so it keeps fine detail), rotated by a multiple of 90 degrees, maybe mirrored, converted
from sRGB to linear and given a random gain; grey photographs are colourised between two random colours.
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np

# file names inside the packages' data folders; the split is by photograph
TRAIN_PHOTOS = ("astronaut.png", "brick.png", "camera.png", "cell.png", "chelsea.png", "coins.png", "gravel.png",
                "hubble_deep_field.jpg", "ihc.png", "moon.png", "retina.jpg", "page.png", "text.png")
TEST_PHOTOS = ("coffee.png", "rocket.jpg", "grass.png", "grace_hopper.jpg")
SPLITS = ("train", "test")


def _folders() -> list[Path]:
    out = []
    try:
        import skimage.data

        out.append(Path(skimage.data.__file__).parent)
    except ImportError:
        pass
    try:
        import matplotlib

        out.append(Path(matplotlib.__file__).parent / "mpl-data" / "sample_data")
    except ImportError:
        pass
    return out


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear light (IEC 61966-2-1)."""
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


@functools.lru_cache(maxsize=None)
def photo_pool(split: str) -> tuple[np.ndarray, ...]:
    """The photographs of one split as float32 sRGB arrays (h, w, 3) or (h, w) in [0, 1]. Raises when none of
    them can be found (scikit-image and matplotlib are in the `train` extra)."""
    if split not in SPLITS:
        raise ValueError(f"photo split must be one of {SPLITS}, got {split!r}")
    names = TRAIN_PHOTOS if split == "train" else TEST_PHOTOS
    found = {}
    for folder in _folders():
        for n in names:
            p = folder / n
            if n not in found and p.is_file():
                from PIL import Image  # quiet about the ICC profiles some of these PNGs carry (libpng is not)

                with Image.open(p) as f:
                    im = np.asarray(f.convert("L" if f.mode in ("L", "I;16", "1") else "RGB"))
                found[n] = im.astype(np.float32) / 255.0
    if not found:
        raise FileNotFoundError("no photographs found for textures: install scikit-image and matplotlib "
                                "(pip install 'aat-dff[train]')")
    return tuple(found[n] for n in names if n in found)


def photo_texture(rng: np.random.Generator, h: int, w: int, split: str = "train") -> np.ndarray:
    """(h, w, 3) float32 linear RGB texture cut from a random photograph of `split`."""
    pool = photo_pool(split)
    im = pool[int(rng.integers(len(pool)))]
    ph, pw = im.shape[:2]
    # zoom = output pixels per photo pixel; cover (h, w) with a crop of the photo at that zoom
    zoom_min = max(h / ph, w / pw, 0.35)
    zoom = float(np.exp(rng.uniform(np.log(zoom_min), np.log(max(zoom_min, 1.5)))))
    ch, cw = min(ph, int(np.ceil(h / zoom))), min(pw, int(np.ceil(w / zoom)))
    r0, c0 = int(rng.integers(0, ph - ch + 1)), int(rng.integers(0, pw - cw + 1))
    crop = im[r0:r0 + ch, c0:c0 + cw]
    k = int(rng.integers(4))
    if k % 2:  # a quarter turn swaps the crop's axes: resize to the swapped size first
        crop = cv2.resize(crop, (h, w), interpolation=cv2.INTER_AREA if zoom < 1 else cv2.INTER_CUBIC)
    else:
        crop = cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA if zoom < 1 else cv2.INTER_CUBIC)
    crop = np.rot90(crop, k)
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    crop = np.clip(np.ascontiguousarray(crop), 0, 1)
    if crop.ndim == 2:  # grey: map between two random colours
        c0 = rng.random(3)
        c1 = np.clip(c0 + rng.normal(size=3) * 0.6, 0, 1)
        crop = c0[None, None] * (1 - crop[..., None]) + c1[None, None] * crop[..., None]
    out = srgb_to_linear(crop.astype(np.float32))
    gain = rng.uniform(0.6, 1.3, 3) * rng.uniform(0.7, 1.2)
    return np.clip(out * gain[None, None], 0, 1).astype(np.float32)
