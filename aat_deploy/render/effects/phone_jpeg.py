"""phone_jpeg: a phone's image processing after the sensor: local tone mapping, denoising, unsharp masking, JPEG.

A phone does not hand over what its sensor measured. Before the JPEG is written it lifts the shadows and holds
the highlights locally, smooths away low-contrast detail and noise, sharpens edges, and quantises 8 x 8 blocks. A
focus measure (a high-pass energy) reads the sharpening as texture and the denoising as blur, so a stack that went
through this has other focus curves than the simulator's linear frames. The effect runs on the sensor's linear
frame (after `noise` and `raw_pipeline`), and gives back what the runtime reads from the JPEG: the decoded 8-bit
sRGB values made linear again (`aat_deploy.io.color.srgb_to_linear`, as `load_image` does). In order:

1. **Local tone mapping** (`tone`, 0 = off): every pixel's linear RGB is multiplied by (B / 0.18)^-tone, B the
   local mean luminance (geometric mean over a Gaussian of standard deviation `tone_scale` x the sensor's longer
   side; Rec. 709 luminance). On a uniform area of luminance L the result is L^(1 - tone) 0.18^tone: mid-grey stays,
   shadows rise, highlights fall, and detail smaller than the Gaussian keeps its contrast. Gains are kept within
   1/8 .. 8 (three stops). Typical phones: 0.2 .. 0.6.
2. sRGB encoding (IEC 61966-2-1), values clipped to [0, 1]; then JFIF YCbCr (BT.601, full range).
3. **Denoising** (`denoise`, 0 = off): the luma through a bilateral filter, range sigma `denoise` (encoded units,
   1 = white) and spatial sigma `denoise_px`; the chroma through a Gaussian of 2 x `denoise_px`. Texture whose
   contrast is below about `denoise` is smoothed away, edges above it stay. Typical: 0.01 .. 0.06.
4. **Unsharp masking** (`sharpen`, 0 = off): Y + sharpen x (Y - G(Y)), G a Gaussian of `sharpen_px`. A sinusoid
   of period P px gains contrast by the factor 1 + sharpen (1 - exp(-2 pi^2 sharpen_px^2 / P^2)) (the Gaussian's
   transfer function). Typical: 0.3 .. 1.5 at 0.7 .. 1.5 px.
5. 8-bit rounding and **JPEG** (`quality` 1 .. 100, libjpeg's scale as OpenCV writes it; `subsampling` "420"
   (phones) or "444"), decoded again. Quality 100 with 4:4:4 is the identity within the 8-bit and DCT rounding
   (about 1 DN). The 8 x 8 blocks (16 x 16 with 4:2:0) sit on the full sensor's grid: a crop at `ctx.origin`
   keeps their phase, as `raw_pipeline` keeps the Bayer phase.

The effect draws nothing: the same frame gives the same output. `random_settings(rng)` draws settings from the
ranges above (one phone per stack, for training data spanning phones). The diagnosis tries `candidates` (light,
typical, strong, JPEG only); binning would average the 8 x 8 blocks and the sharpening away, so it is left out of
the reduced-resolution screening and scored at full resolution.
"""

from __future__ import annotations

import cv2
import numpy as np

from aat_deploy.focus.measures import LUMA  # Rec. 709 luminance of linear RGB
from aat_deploy.io.color import linear_to_srgb, srgb_to_linear
from aat_deploy.render.effects import Effect, SimContext, register

MID_GREY = 0.18  # the tone mapping's fixed point (linear)
MAX_GAIN = 8.0  # tone-mapping gains within 1/8 .. 8
SUBSAMPLING = {"420": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420, "444": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444}

# JFIF YCbCr (BT.601 full range) on encoded values, as JPEG itself converts
_RGB2YCC = np.array([[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]], np.float32)
_YCC2RGB = np.linalg.inv(_RGB2YCC).astype(np.float32)

# documented ranges: random_settings draws from them; __init__ refuses settings outside the hard limits
RANGES = {"tone": (0.0, 0.6), "denoise": (0.0, 0.06), "sharpen": (0.0, 1.5), "sharpen_px": (0.7, 1.5),
          "quality": (75, 97)}


def gaussian(img: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur (H, W) float32 with reflected borders; for large sigma at reduced size (the result is smooth)."""
    if sigma_px <= 0:
        return img
    h, w = img.shape
    k = int(max(1, sigma_px // 4))
    if k == 1:
        return cv2.GaussianBlur(img, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
    small = cv2.resize(img, (max(1, w // k), max(1, h // k)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigma_px / k, borderType=cv2.BORDER_REFLECT)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def local_tone(linear: np.ndarray, strength: float, sigma_px: float) -> np.ndarray:
    """(C, H, W) linear in [0, 1] -> the same times (B / 0.18)^-strength, B the Gaussian-weighted geometric mean
    of the luminance (sigma_px); gains within 1/MAX_GAIN .. MAX_GAIN."""
    if strength <= 0:
        return linear
    lum = np.einsum("chw,c->hw", linear, LUMA) if linear.shape[0] == 3 else linear[0]
    log_b = gaussian(np.log(np.maximum(lum, 1e-4)).astype(np.float32), sigma_px)
    gain = np.clip(np.exp(-strength * (log_b - np.log(MID_GREY))), 1 / MAX_GAIN, MAX_GAIN)
    return np.clip(linear * gain[None].astype(np.float32), 0.0, 1.0)


def unsharp(y: np.ndarray, amount: float, sigma_px: float) -> np.ndarray:
    """(H, W) -> y + amount (y - G_sigma(y)) (no clipping)."""
    if amount <= 0:
        return y
    return y + np.float32(amount) * (y - cv2.GaussianBlur(y, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT))


def denoise_ycc(ycc: np.ndarray, range_sigma: float, sigma_px: float) -> np.ndarray:
    """(C, H, W) YCbCr (or (1, H, W) luma): bilateral luma, Gaussian chroma (2 x sigma_px)."""
    if range_sigma <= 0:
        return ycc
    out = np.empty_like(ycc)
    out[0] = cv2.bilateralFilter(np.ascontiguousarray(ycc[0]), -1, float(range_sigma), float(sigma_px),
                                 borderType=cv2.BORDER_REFLECT)
    for c in range(1, ycc.shape[0]):
        out[c] = cv2.GaussianBlur(ycc[c], (0, 0), 2 * sigma_px, borderType=cv2.BORDER_REFLECT)
    return out


def jpeg_bytes(rgb8: np.ndarray, quality: int, subsampling: str) -> bytes:
    """(H, W, 3) RGB or (H, W) uint8 -> a JPEG file's bytes at `quality` and chroma `subsampling` ("420" | "444")."""
    bgr = rgb8[..., ::-1] if rgb8.ndim == 3 else rgb8
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr),
                           [cv2.IMWRITE_JPEG_QUALITY, int(quality), cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                            SUBSAMPLING[subsampling]])
    if not ok:
        raise RuntimeError("effect 'phone_jpeg': OpenCV could not encode the JPEG")
    return buf.tobytes()


def jpeg_roundtrip(rgb8: np.ndarray, quality: int, subsampling: str, origin: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) or (H, W) uint8 through a JPEG at `quality`, with the block grid of the full sensor: the crop is
    padded (reflected) to start on a block boundary of the sensor, encoded, decoded and cut back."""
    mcu = 16 if (subsampling == "420" and rgb8.ndim == 3) else 8
    pr, pc = origin[0] % mcu, origin[1] % mcu
    pad = ((pr, 0), (pc, 0)) + (((0, 0),) if rgb8.ndim == 3 else ())
    img = np.pad(rgb8, pad, mode="reflect") if (pr or pc) else rgb8
    buf = np.frombuffer(jpeg_bytes(img, quality, subsampling), np.uint8)
    dec = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED if img.ndim == 2 else cv2.IMREAD_COLOR)
    dec = dec[..., ::-1] if dec.ndim == 3 else dec
    return dec[pr:, pc:]


def processed_srgb8(frame: np.ndarray, p: dict, sensor_hw: tuple[int, int]) -> np.ndarray:
    """(C, H, W) linear (1.0 = white level), C = 3 or 1 -> the phone's 8-bit sRGB image before the JPEG, uint8
    (C, H, W): steps 1-4 of the module doc, p the effect's settings."""
    c = frame.shape[0]
    if c not in (1, 3):
        raise ValueError(f"effect 'phone_jpeg' needs RGB (3, H, W) or grey (1, H, W) frames, got {frame.shape}")
    x = np.clip(np.nan_to_num(np.asarray(frame, np.float32)), 0.0, 1.0)
    x = local_tone(x, float(p["tone"]), float(p["tone_scale"]) * max(sensor_hw))
    enc = linear_to_srgb(x)
    ycc = np.einsum("ij,jhw->ihw", _RGB2YCC, enc) if c == 3 else enc.copy()
    ycc = denoise_ycc(ycc, float(p["denoise"]), float(p["denoise_px"]))
    ycc[0] = unsharp(ycc[0], float(p["sharpen"]), float(p["sharpen_px"]))
    enc = np.einsum("ij,jhw->ihw", _YCC2RGB, ycc) if c == 3 else ycc
    return np.rint(np.clip(enc, 0.0, 1.0) * 255).astype(np.uint8)


def develop(frame: np.ndarray, p: dict, sensor_hw: tuple[int, int], origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """(C, H, W) linear (1.0 = white level), C = 3 or 1 -> the phone's JPEG decoded to linear, float32 (C, H, W);
    p the effect's settings (module doc)."""
    c = frame.shape[0]
    rgb8 = processed_srgb8(frame, p, sensor_hw)
    dec = jpeg_roundtrip(rgb8.transpose(1, 2, 0) if c == 3 else rgb8[0], int(p["quality"]), str(p["subsampling"]),
                         origin)
    dec = dec.transpose(2, 0, 1) if c == 3 else dec[None]
    return srgb_to_linear(dec.astype(np.float32) / 255.0)


def random_settings(rng: np.random.Generator) -> dict:
    """Settings of one random phone, uniform over RANGES (quality an integer), 4:2:0 as phones write."""
    s = {k: float(rng.uniform(*v)) for k, v in RANGES.items() if k != "quality"}
    s["quality"] = int(rng.integers(RANGES["quality"][0], RANGES["quality"][1] + 1))
    return s


@register
class PhoneJpeg(Effect):
    name = "phone_jpeg"
    description = ("a phone's processing after the sensor: local tone mapping (tone, tone_scale), denoising "
                   "(denoise, denoise_px), unsharp masking (sharpen, sharpen_px), JPEG (quality, subsampling), "
                   "read back as the runtime decodes a JPEG")
    order = 95  # after the sensor's noise (90) and the RAW development (92): the last thing before the file
    defaults = {"tone": 0.4, "tone_scale": 0.05, "denoise": 0.03, "denoise_px": 1.5, "sharpen": 0.8,
                "sharpen_px": 1.0, "quality": 90.0, "subsampling": "420"}
    candidates = [{"tone": 0.2, "denoise": 0.015, "sharpen": 0.5, "quality": 95.0},  # light
                  {},  # typical (the defaults)
                  {"tone": 0.6, "denoise": 0.06, "sharpen": 1.2, "quality": 80.0},  # strong
                  {"tone": 0.0, "denoise": 0.0, "sharpen": 0.0, "quality": 85.0}]  # JPEG only

    def __init__(self, **params):
        super().__init__(**params)
        p = self.params
        if str(p["subsampling"]).split(".")[0] not in SUBSAMPLING:  # '420' read from text may come as 420.0
            raise ValueError(f"effect 'phone_jpeg': subsampling must be one of {sorted(SUBSAMPLING)}, "
                             f"got {p['subsampling']!r}")
        p["subsampling"] = str(p["subsampling"]).split(".")[0]
        checks = {"tone": (0.0, 1.0), "tone_scale": (1e-4, 1.0), "denoise": (0.0, 1.0), "denoise_px": (0.1, 50.0),
                  "sharpen": (0.0, 10.0), "sharpen_px": (0.1, 50.0), "quality": (1.0, 100.0)}
        for k, (lo, hi) in checks.items():
            try:
                ok = lo <= float(p[k]) <= hi
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ValueError(f"effect 'phone_jpeg': {k} must be a number in [{lo:g}, {hi:g}], got {p[k]!r}")
        if float(p["quality"]) != int(float(p["quality"])):
            raise ValueError(f"effect 'phone_jpeg': quality must be a whole number, got {p['quality']!r}")

    def binned(self, factor: int):
        """Binning averages the 8 x 8 blocks and the pixel-scale sharpening away: left out of the diagnosis's
        reduced-resolution screening (scored at full resolution)."""
        return self if factor == 1 else None

    def sensor(self, frame: np.ndarray, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
        return develop(frame, self.params, ctx.sensor_hw, ctx.origin).astype(frame.dtype, copy=False)
