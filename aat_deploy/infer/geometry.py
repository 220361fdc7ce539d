"""Frame geometry: fit a frame (and a depth map with it) to the model's sensor (centre crop to its aspect, then
resize) and optional alignment of the frames against focus breathing (affine ECC on a reduced grey image) with exposure equalisation."""

from __future__ import annotations

import cv2
import numpy as np


def fit_to_sensor(img: np.ndarray, size_wh: tuple[int, int]) -> tuple[np.ndarray, dict]:
    """img (H, W, 3) → (h, w, 3) with (w, h) = size_wh, keeping the field centred.

    The frame is centre-cropped to the target aspect ratio, then resized (area averaging when shrinking,
    bilinear when enlarging). Returns the image and {"crop_xywh": [...], "scale": s}.
    """
    tw, th = size_wh
    geometry = sensor_crop(img.shape[:2], size_wh)
    x0, y0, cw, ch = geometry["crop_xywh"]
    if (cw, ch) == (tw, th) and (x0, y0) == (0, 0):
        return img, geometry
    crop = img[y0:y0 + ch, x0:x0 + cw]
    interp = cv2.INTER_AREA if cw > tw else cv2.INTER_LINEAR
    out = cv2.resize(np.ascontiguousarray(crop), (tw, th), interpolation=interp)
    return out.astype(np.float32, copy=False), geometry


def sensor_crop(hw: tuple[int, int], size_wh: tuple[int, int]) -> dict:
    """What fit_to_sensor does to a frame of hw = (H, W) px: {"crop_xywh": the centre crop to size_wh's aspect
    ratio, "scale": size_wh's width over the crop's}."""
    tw, th = size_wh
    h, w = int(hw[0]), int(hw[1])
    if (w, h) == (tw, th):
        return {"crop_xywh": [0, 0, w, h], "scale": 1.0}
    target = tw / th
    if w / h > target:  # too wide: crop columns
        cw, ch = round(h * target), h
    else:
        cw, ch = w, round(w / target)
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    return {"crop_xywh": [x0, y0, cw, ch], "scale": tw / cw}



def fit_rgbd_to_sensor(rgb: np.ndarray, depth: np.ndarray, hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """An image (H, W, 3) and its depth (H, W) fitted to a sensor of hw = (rows, cols) px as the runtime fits
    frames (fit_to_sensor), so a rendered capture and a real one are framed alike; depth takes the same crop,
    resized with nearest neighbour (no invented depths)."""
    th, tw = hw
    out, info = fit_to_sensor(rgb, (tw, th))
    x0, y0, cw, ch = info["crop_xywh"]
    d = cv2.resize(np.ascontiguousarray(depth[y0:y0 + ch, x0:x0 + cw]), (tw, th), interpolation=cv2.INTER_NEAREST)
    return out, d

def align_stack(frames: list[np.ndarray], ref: int, max_side: int = 512) -> tuple[list[np.ndarray], list[dict]]:
    """Align every frame (H, W, 3) to frames[ref] with an affine ECC fit (focus breathing is mostly a scale).

    The fit runs on a grey copy reduced to at most `max_side` pixels; the warp is applied at full size.
    A frame whose fit does not converge is left as it is (its info says so).
    Returns the frames and per-frame {"matrix": 2x3 list, "converged": bool}.
    """
    h, w = frames[ref].shape[:2]
    s = min(1.0, max_side / max(h, w))
    small = lambda im: cv2.resize(cv2.cvtColor(im, cv2.COLOR_RGB2GRAY), None, fx=s, fy=s,
                                  interpolation=cv2.INTER_AREA) if s < 1 else cv2.cvtColor(im, cv2.COLOR_RGB2GRAY)
    ref_g = small(frames[ref]).astype(np.float32)
    ref_g /= max(float(ref_g.max()), 1e-6)
    out, info = [], []
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    for i, im in enumerate(frames):
        if i == ref:
            out.append(im)
            info.append({"matrix": [[1, 0, 0], [0, 1, 0]], "converged": True})
            continue
        g = small(im).astype(np.float32)
        g /= max(float(g.max()), 1e-6)
        warp = np.eye(2, 3, dtype=np.float32)
        try:
            _, warp = cv2.findTransformECC(ref_g, g, warp, cv2.MOTION_AFFINE, criteria, None, 5)
        except cv2.error:
            out.append(im)
            info.append({"matrix": [[1, 0, 0], [0, 1, 0]], "converged": False})
            continue
        full = warp.copy()
        full[:, 2] /= s  # translation back to full-resolution pixels
        aligned = cv2.warpAffine(im, full, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                 borderMode=cv2.BORDER_REFLECT)
        out.append(aligned)
        info.append({"matrix": full.astype(float).round(6).tolist(), "converged": True})
    return out, info


def equalise_exposure(frames: list[np.ndarray], ref: int, border: float = 0.1) -> tuple[list[np.ndarray], list[float]]:
    """Scale every frame (H, W, 3) linear so its mean over the central region (a `border` fraction cut off each side,
    where alignment leaves no empty margin) matches frames[ref]'s: handheld or auto-exposed frames differ by a gain,
    which a focus measure would read as sharpness. Defocus keeps the mean, so a gain is all that differs.
    Returns the frames and each frame's gain."""
    h, w = frames[ref].shape[:2]
    y0, y1, x0, x1 = int(h * border), max(int(h * (1 - border)), int(h * border) + 1), int(w * border), \
        max(int(w * (1 - border)), int(w * border) + 1)
    target = float(frames[ref][y0:y1, x0:x1].mean())
    out, gains = [], []
    for im in frames:
        m = float(im[y0:y1, x0:x1].mean())
        g = target / m if m > 0 and target > 0 else 1.0
        out.append(im if g == 1.0 else (im * np.float32(g)).astype(np.float32))
        gains.append(round(g, 6))
    return out, gains
