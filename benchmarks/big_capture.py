"""A synthetic 12-MP phone focal stack as a capture folder: the input of `benchmarks/bench_big_capture.py`.

    python -m benchmarks.big_capture [--out cache/big_capture/phone12mp] [--width 4080 --height 3072]

What a phone's main camera writes when it sweeps focus: five 4080 x 3072 JPEGs (12.5 MP, 4:2:0, quality 90) of a
procedural scene (`training.data.scenes`, photographs of the *training* split) at 0.2-2.5 m, rendered with the
torch-free layered renderer at half the size (2040 x 1536; the defocus blur in pixels is the full size's, only
detail finer than 2 px is missing) and enlarged (bicubic) through a thin lens with the Pixel 6 Pro main camera's first-order optics (6.81 mm,
f/1.85, 1.2 um binned pixels: about 21 px of blur-disk diameter per diopter), focused at five distances even in
diopters over the scene's range (a step of 1.15 D, about 24 px of blur), then Poisson-Gaussian noise and a phone's
processing (`phone_jpeg` effect at its typical settings: local tone mapping, denoising, sharpening, JPEG).
Beside the frames: `capture.json` (the focus distances, as phones rarely write them in EXIF) and the ground truth
`gt_depth_m.npy` (metres from the sensor plane), so the benchmark can score what it times.

Frames are rendered one at a time and cached: a folder whose `make.json` matches the arguments is reused (about
2 minutes and 2.5 GB on 2 cores; rendering at the full size would take four times both).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# Pixel 6 Pro main camera (first-order facts: focal length, f-number, binned pixel pitch, 12.5-MP output)
PHONE = {"focal_length_mm": 6.81, "f_number": 1.85, "pixel_um": 1.2, "width_px": 4080, "height_px": 3072}
NEAR_M, FAR_M = 0.2, 2.5
SEED = 20261125


def phone_lens(width_px: int, height_px: int, pixel_um: float):
    """An aberration-free thin lens with the phone's focal length and f-number on a width x height sensor."""
    from aat_deploy.lens.schema import Lens, Sensor, Surface

    f = PHONE["focal_length_mm"]
    ideal = Surface(curvature_per_mm=0.0, thickness_mm=f, semi_diameter_mm=f / PHONE["f_number"] / 2,
                    kind="ideal", focal_length_mm=f)
    sensor = Sensor(width_px * pixel_um / 1000, height_px * pixel_um / 1000, width_px, height_px)
    return Lens(name="thin lens, Pixel 6 Pro main camera optics", surfaces=(ideal,), stop_index=0, sensor=sensor,
                design_wavelength_nm=550.0, provenance={"source": "benchmarks/big_capture.py"})


def make_capture(out: Path, width: int = PHONE["width_px"], height: int = PHONE["height_px"], frames: int = 5,
                 seed: int = SEED, render_scale: int = 2, quiet: bool = False) -> Path:
    """Render the capture into `out` (reused when its make.json matches): the optics at 1/render_scale of the
    size, enlarged to width x height before the sensor's noise and the phone's processing. Returns out."""
    import cv2

    from aat_deploy.io.atomic import atomic_folder
    from aat_deploy.optics.focus_table import diopter_grid
    from aat_deploy.render import effects as fx
    from aat_deploy.render.effects.phone_jpeg import PhoneJpeg, jpeg_bytes, processed_srgb8
    from aat_deploy.render.layered import LayeredConfig
    from aat_deploy.render.optical import optical_stack
    from aat_deploy.render.sources import GaussianSource
    from training.data.scenes import SceneConfig, procedural_scene

    out = Path(out)
    pixel_um = PHONE["pixel_um"] * PHONE["width_px"] / width  # the same optics and field of view at any size
    params = {"width": width, "height": height, "frames": frames, "seed": seed, "pixel_um": pixel_um,
              "render_scale": render_scale,
              "near_m": NEAR_M, "far_m": FAR_M, "phone": PHONE, "version": 1}
    made = out / "make.json"
    if made.is_file() and json.loads(made.read_text()) == params:
        return out
    t0 = time.perf_counter()
    say = (lambda m: None) if quiet else (lambda m: print(f"  {m} ({time.perf_counter() - t0:.0f} s)",
                                                           file=sys.stderr, flush=True))
    rw, rh = width // render_scale, height // render_scale
    lens = phone_lens(rw, rh, pixel_um * render_scale)
    rng = np.random.default_rng(seed)
    rgb, depth = procedural_scene(SceneConfig(height=rh, width=rw, near_m=NEAR_M, far_m=FAR_M,
                                              photo_fraction=0.5, photo_split="train"), rng)
    rgb = np.ascontiguousarray(rgb.transpose(2, 0, 1), np.float32)
    say("scene")
    focus = diopter_grid(NEAR_M, FAR_M, frames)
    ctx = fx.SimContext(lens, (rh, rw), (0, 0), None, None, 0.0)
    src = GaussianSource(lens)
    # a layer every 3 px of blur at 12 MP (the blur reaches ~100 px); cells only matter for field-varying PSFs
    cfg = LayeredConfig(cell_px=512, layer_blur_px=max(1.0, 3.0 * rw / PHONE["width_px"]))
    noise, phone = fx.parse(["noise:full_well_e=6000"])[0], PhoneJpeg()
    p = phone.params
    with atomic_folder(out, True, "benchmarks/big_capture.py") as tmp:
        names = []
        for i, f in enumerate(focus):
            frame = optical_stack([], src, rgb, depth, [float(f)], ctx, cfg)[0]
            if render_scale > 1:
                frame = np.stack([cv2.resize(c, (width, height), interpolation=cv2.INTER_CUBIC) for c in frame])
            frame = noise.sensor(frame * np.float32(0.8), ctx, rng)  # exposed a little under white
            rgb8 = processed_srgb8(frame, p, (height, width)).transpose(1, 2, 0)
            names.append(f"PXL_{i:04d}.jpg")
            (tmp / names[-1]).write_bytes(jpeg_bytes(rgb8, int(p["quality"]), str(p["subsampling"])))
            say(f"frame {i + 1}/{frames} at {f:.3f} m")
        (tmp / "capture.json").write_text(json.dumps(
            {"frames": [{"file": n, "focus_m": round(float(f), 5)} for n, f in zip(names, focus)]}, indent=1))
        np.save(tmp / "gt_depth_m.npy", cv2.resize(depth, (width, height), interpolation=cv2.INTER_NEAREST))
        (tmp / "make.json").write_text(json.dumps(params, indent=1))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "cache/big_capture/phone12mp")
    ap.add_argument("--width", type=int, default=PHONE["width_px"])
    ap.add_argument("--height", type=int, default=PHONE["height_px"])
    ap.add_argument("--frames", type=int, default=5)
    a = ap.parse_args(argv)
    print(make_capture(a.out, a.width, a.height, a.frames))
    return 0


if __name__ == "__main__":
    sys.exit(main())
