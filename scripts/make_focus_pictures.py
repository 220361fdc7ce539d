"""Pictures of the classical depth from focus (aat_deploy.focus) on real JPEG focal stacks in ../shared/data:

    python scripts/make_focus_pictures.py [--out docs/figures] [--max-side 480]

- focal_stack_pcb_focusstack: a 10-frame focus sweep of a circuit board (small-sensor camera, magnification
  changes with focus: aligned with the runtime's --align, exposure equalised);
- focal_stack_mobiledepth_balls: a 10-frame phone stack (Mobile Depth), already aligned;
- focal_stack_lytro_refocus_epfl48: 9 slices refocused near to far from a Lytro Illum light field, beside the
  all-in-focus image Lytro exported.
None has metric focus distances (the phone's values have undocumented units), so frames are placed at even steps
and the map shows the in-focus position as a fractional frame index (0 = nearest frame): relative depth, shown,
not scored. One PNG per stack: a frame, the all-in-focus blend, the in-focus frame map, the confidence.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aat_deploy.io.atomic import atomic_file  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"

STACKS = {  # name: (folder, frame files near to far, align)
    "pcb": ("focal_stack_pcb_focusstack", [f"pcb_{i:03d}.JPG" for i in range(10)], True),
    "phone_balls": ("focal_stack_mobiledepth_balls", [f"{i:02d}.jpg" for i in range(9, -1, -1)], False),
    "lytro": ("focal_stack_lytro_refocus_epfl48", [f"48__refocus_{i:02d}.jpg" for i in range(9)], False),
}


def load(folder: Path, files: list[str], max_side: int, align: bool) -> np.ndarray:
    from aat_deploy.capture.raw import load_frame
    from aat_deploy.geometry import align_stack, equalise_exposure, fit_to_sensor

    frames = [load_frame(folder / f)[0] for f in files]
    h, w = frames[0].shape[:2]
    s = min(1.0, max_side / max(h, w))
    size = (round(w * s), round(h * s))
    frames = [fit_to_sensor(f, size)[0] for f in frames]
    if align:
        frames, _ = align_stack(frames, ref=len(frames) // 2)
        frames, _ = equalise_exposure(frames, ref=len(frames) // 2)
    return np.stack([f.transpose(2, 0, 1) for f in frames]).astype(np.float32)


def srgb8(img_chw: np.ndarray) -> np.ndarray:
    from aat_deploy.capture.raw import linear_to_srgb

    x = img_chw.transpose(1, 2, 0)
    x = x / max(float(np.percentile(x, 99.5)), 1e-6)
    return np.rint(linear_to_srgb(np.clip(x, 0, 1)) * 255).astype(np.uint8)


PANEL_PX = 220  # panel height in the saved picture (small PNGs)


def panel(title: str, img_rgb8: np.ndarray) -> np.ndarray:
    h, w = img_rgb8.shape[:2]
    img_rgb8 = cv2.resize(img_rgb8, (round(w * PANEL_PX / h), PANEL_PX), interpolation=cv2.INTER_AREA)
    out = np.full((img_rgb8.shape[0] + 22, img_rgb8.shape[1], 3), 255, np.uint8)
    out[22:] = img_rgb8
    cv2.putText(out, title, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs/figures")
    ap.add_argument("--max-side", type=int, default=480)
    a = ap.parse_args(argv)
    from aat_deploy.focus import depth_from_focus

    a.out.mkdir(parents=True, exist_ok=True)
    for name, (folder, files, align) in STACKS.items():
        d = SHARED / folder
        if not d.is_dir():
            print(f"{d}: not present, skipped", file=sys.stderr)
            continue
        stack = load(d, files, a.max_side, align)
        s = stack.shape[0]
        focus = 1.0 / np.linspace(2.0, 1.0, s)  # placeholders even in diopters: relative positions only
        t0 = time.perf_counter()
        r = depth_from_focus(stack, focus)
        dt = time.perf_counter() - t0
        frac = (2.0 - 1.0 / r.depth_m) / (1.0 / (s - 1))  # fractional frame index, 0 = nearest
        cmap = cv2.applyColorMap(np.rint(np.clip(frac / (s - 1), 0, 1) * 255).astype(np.uint8),
                                 cv2.COLORMAP_VIRIDIS)[..., ::-1]
        conf = np.repeat(np.rint(r.confidence * 255).astype(np.uint8)[..., None], 3, 2)
        panels = [panel(f"frame {s // 2} of {s}", srgb8(stack[s // 2])), panel("all-in-focus (blend)", srgb8(r.aif)),
                  panel("in-focus frame (yellow = far)", cmap), panel("confidence", conf)]
        if name == "lytro" and (d / "afocus.png").is_file():
            ref = cv2.imread(str(d / "afocus.png"))[..., ::-1]
            panels.insert(2, panel("Lytro's all-in-focus", cv2.resize(ref, cmap.shape[1::-1], cv2.INTER_AREA)))
        img = np.concatenate(panels, 1)
        path = a.out / f"focus_real_{name}.png"
        with atomic_file(path) as tmp:
            cv2.imwrite(str(tmp), img[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
        print(f"{name}: {s} frames {stack.shape[3]}x{stack.shape[2]} px, {dt:.2f} s -> {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
