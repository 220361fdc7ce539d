"""The real-stack gallery: depth, all-in-focus and confidence of every real focal stack in ../shared/data, made as
`aat-infer` makes them, into docs/gallery/*.png and docs/real_stacks.md. Shown, not scored: none has ground truth.

    python -m scripts.make_real_gallery [--max-side 640] [--methods focus] [--out docs] [--model M] [--panel-px 240]

Stacks (`STACKS`; each with the focus distances it carries, or placeholder positions where it has none, as a
user would pass `--focus-m`):
- mobiledepth_balls: a 10-frame phone stack (Mobile Depth); its focus values in undocumented units;
- pcb: a 10-frame focus sweep of a circuit board (2.5 mm lens, F/1.8); no focus distances, sweep direction
  undocumented; aligned and exposure-equalised (`--align`);
- lytro_refocus: 9 slices refocused near to far by Lytro Desktop from an Illum light field (EPFL), no values;
- watanabe_nayar: the depth-from-defocus pair "breakfast" (telecentric 25 mm, F/8.3), focused at 0.529 and
  0.869 m: two frames, the focus method's two-point estimate;
- lytro_lightfield: the 9 x 9 views of Lytro light field 2067 (EPINET) refocused by shift-and-add over
  disparities -1 .. 1.5 px (11 slices): depth as the in-focus disparity.

Method columns (`METHODS`): each is a function (stack, frames, focus_m) -> `Column` (depth in the stack's focus
units, all-in-focus, confidence or None) and a title. `focus` is the classical method as `aat-infer --method
focus` runs it (the runtime's `depth_from_frames`: fit, optional alignment, normalisation, calibrated
confidence; depth below the confidence threshold is unknown, grey). `dfv_aat` is the any-camera model
(`models/dfv_aat.onnx`, `aat-infer --model dfv_aat`) told a thin lens: it needs each frame's focus in metres (or
placeholders whose inverse is affine in defocus) and the blur growth in px per (placeholder) diopter; a stack
that gives neither shows the reason instead of panels (`RealStack.defocus_px_per_d`). `--model` runs another
any-camera model file in that column (a candidate before it ships: its column and page name the file and say it is
not the shipped model). Depth panels of one stack share one colour scale, so the columns compare. To add a method (a DfF
model), write its column function (returning a Column, or one line saying why it cannot run on that stack) and
add it to METHODS; rows get one more group of panels, the page one more column.
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

SHARED = ROOT.parent / "shared" / "data"
PANEL_PX = 240  # panel height in the saved pictures


@dataclass
class RealStack:
    """A real focal stack: frames (S, H, W, 3) linear RGB, near to far; focus_m (S,) positive, ascending: distances
    in `unit` when `kind` is "depth" (metres, or the stack's own units), else placeholder positions whose inverse
    is affine in the quantity `unit` names (kind "position": a frame index, a disparity; see `display`);
    align: run the runtime's --align; reference: an all-in-focus image the source ships, or None."""

    name: str
    title: str
    source: str
    frames: np.ndarray
    focus_m: np.ndarray
    focus_note: str
    unit: str = "m"
    kind: str = "depth"
    offset: float = 0.0  # display value = (1 / depth - offset) * sign for non-metric units
    sign: float = 1.0
    align: bool = False
    reference: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    # blur-disk diameter (px at the frames' size) per diopter of focus_m's inverse, where the stack's optics say it;
    # else why not (the any-camera model needs it)
    defocus_px_per_d: float | None = None
    no_defocus_why: str = "its optics are unknown"

    def display(self, depth: np.ndarray) -> np.ndarray:
        """Depth in the method's (pseudo-)metres -> the quantity shown: metres, or frame index / disparity."""
        if self.kind == "depth":
            return depth
        with np.errstate(divide="ignore", invalid="ignore"):
            return (1.0 / depth - self.offset) * self.sign


def _files(folder: Path, names: list[str]) -> np.ndarray:
    from aat_deploy.capture.raw import load_frame

    return np.stack([load_frame(folder / n)[0] for n in names])


def _by_index(frames: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Placeholder focus positions for a stack without values: frame k (0 = nearest) at 1 / (S - k) "metres", so
    the shown quantity S - 1/depth is the in-focus frame index."""
    s = len(frames)
    return 1.0 / (s - np.arange(s, dtype=np.float64)), float(s), -1.0


def stack_balls() -> RealStack:
    d = SHARED / "focal_stack_mobiledepth_balls"
    values = np.loadtxt(d / "focus_distance.txt")
    order = np.argsort(values)  # near to far (frame 09 first)
    frames = _files(d, [f"{i:02d}.jpg" for i in order])
    return RealStack("mobiledepth_balls", "Mobile Depth \"balls\" (phone, 10 frames)",
                     "Suwajanakorn et al., CVPR 2015, via DfFintheWild", frames, values[order],
                     "the stack's own focus values (focus_distance.txt, units undocumented: 10 .. 208, and 7.2e6 for "
                     "the frame focused at infinity); depth is in those units", unit="file units",  # kind "depth"
                     no_defocus_why="its focus values' units are undocumented (no metric focus, no blur scale)")


def stack_pcb() -> RealStack:
    d = SHARED / "focal_stack_pcb_focusstack"
    frames = _files(d, [f"pcb_{i:03d}.JPG" for i in range(10)])
    f, off, sign = _by_index(frames)
    return RealStack("pcb", "circuit board (focus sweep, 10 frames)", "PetteriAimonen/focus-stack", frames, f,
                     "none carried: frames placed one step apart in file order (the sweep's direction is not "
                     "documented); depth is the in-focus frame index", unit="frame", kind="position", offset=off, sign=sign,
                     align=True, no_defocus_why="its frames carry no focus distances (placeholders: no blur scale)")


def stack_lytro_refocus() -> RealStack:
    d = SHARED / "focal_stack_lytro_refocus_epfl48"
    frames = _files(d, [f"48__refocus_{i:02d}.jpg" for i in range(9)])
    f, off, sign = _by_index(frames)
    ref = _files(d, ["afocus.png"])[0] if (d / "afocus.png").is_file() else None
    return RealStack("lytro_refocus", "Lytro Illum refocus sweep (EPFL #48, 9 slices)",
                     "EPFL light-field dataset via hosseinjavidnia/Depth-Focal-Stack", frames, f,
                     "none carried: slices placed one step apart near to far (Lytro Desktop's sweep); depth is "
                     "the in-focus slice index", unit="slice", kind="position", offset=off, sign=sign, reference=ref,
                     no_defocus_why="the refocus step between slices is not documented (no blur scale)")


def stack_watanabe_nayar() -> RealStack:
    d = SHARED / "dfd_pair_breakfast_watanabe_nayar"
    frames = _files(d, ["breakfast_near.png", "breakfast_far.png"])
    return RealStack("watanabe_nayar", "Watanabe-Nayar \"breakfast\" (depth-from-defocus pair)",
                     "Watanabe & Nayar, IJCV 1998, via CrisDamian/BlurEqualisationTechnique", frames,
                     np.array([0.529, 0.869]), "0.529 and 0.869 m (readme.txt; telecentric lens, so distances are "
                     "the lens's focus settings); two frames: depth only between them",
                     no_defocus_why="two frames (the model takes 3 or more)")


REFOCUS_D = np.linspace(-1.0, 1.5, 11)  # disparities (px) of the shift-and-add slices
REFOCUS_OFFSET = 2.0  # placeholder diopters = disparity + 2 (> 0 over the range)
# Shift-and-add over 9 views per axis: a point whose disparity is off the slice's by e px lands e (c - 4) px apart in
# view column c = 0..8, so its blur spans 8 |e| px: 8 px per placeholder diopter (a 9 x 9 sampled square aperture,
# not a disk: an approximation the model was not trained on)
REFOCUS_BLUR_PX_PER_D = 8.0


def refocus(views: np.ndarray, d: float) -> np.ndarray:
    """Shift-and-add: views (9, 9, H, W, 3) linear, row r and column c shifted by d (r - 4), d (c - 4) px (the
    HCI convention the data's MANIFEST checked) and averaged: (H, W, 3)."""
    n_r, n_c, h, w, _ = views.shape
    acc = np.zeros((h, w, 3), np.float64)
    for r in range(n_r):
        for c in range(n_c):
            m = np.float32([[1, 0, d * (c - n_c // 2)], [0, 1, d * (r - n_r // 2)]])
            acc += cv2.warpAffine(views[r, c], m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return (acc / (n_r * n_c)).astype(np.float32)


def stack_lytro_lightfield() -> RealStack:
    from aat_deploy.capture.raw import load_frame

    d = SHARED / "lightfield_lytro_real_epinet2067"
    views = np.stack([np.stack([load_frame(d / f"2067_{r:02d}_{c:02d}.png")[0] for c in range(1, 10)])
                      for r in range(1, 10)])
    # near to far: a larger disparity focuses nearer under this shift convention? Unknown: order by placeholder
    # diopters, which only needs to be monotone in d; the picture shows the in-focus disparity itself.
    x = REFOCUS_D + REFOCUS_OFFSET
    order = np.argsort(-x)  # placeholder metres ascending
    frames = np.stack([refocus(views, float(REFOCUS_D[i])) for i in order])
    return RealStack("lytro_lightfield", "Lytro light field 2067 refocused by shift-and-add (11 slices)",
                     "EPINET (chshin10/epinet), Lytro Illum", frames, 1.0 / x[order],
                     "none carried: slices made at disparities -1 .. 1.5 px (steps of 0.25); depth is the in-focus "
                     "disparity in px of the 9 x 9 views", unit="px disparity", kind="position", offset=REFOCUS_OFFSET, sign=1.0,
                     reference=views[4, 4], defocus_px_per_d=REFOCUS_BLUR_PX_PER_D)


STACKS: dict[str, Callable[[], RealStack]] = {
    "mobiledepth_balls": stack_balls, "pcb": stack_pcb, "lytro_refocus": stack_lytro_refocus,
    "watanabe_nayar": stack_watanabe_nayar, "lytro_lightfield": stack_lytro_lightfield}
FOLDERS = {"mobiledepth_balls": "focal_stack_mobiledepth_balls", "pcb": "focal_stack_pcb_focusstack",
           "lytro_refocus": "focal_stack_lytro_refocus_epfl48", "watanabe_nayar": "dfd_pair_breakfast_watanabe_nayar",
           "lytro_lightfield": "lightfield_lytro_real_epinet2067"}


@dataclass
class Column:
    """One method's maps of one stack: depth (H, W) in the stack's focus units (NaN = unknown), aif (3, H, W)
    linear, confidence (H, W) or None; seconds; notes (one line each)."""

    depth: np.ndarray
    aif: np.ndarray
    confidence: np.ndarray | None
    seconds: float
    notes: list[str] = field(default_factory=list)
    unknown_share: float | None = None


def focus_column(stack: RealStack, max_side: int) -> Column:
    """The classical method as aat-infer runs it (thin-lens mapping: no lens given)."""
    from aat_deploy.confidence import MIN_CONFIDENCE, mark_unknown
    from aat_deploy.focus.runner import FocusMethod
    from aat_deploy.infer.process import depth_from_frames

    t0 = time.perf_counter()
    res = depth_from_frames(list(stack.frames), stack.focus_m.astype(np.float32), FocusMethod(max_side=max_side),
                            align=stack.align, name=stack.name)
    depth, unknown = mark_unknown(res.maps.depth_m, res.maps.confidence, MIN_CONFIDENCE)
    return Column(depth, res.maps.aif, res.maps.confidence, time.perf_counter() - t0, res.warnings,
                  unknown["unknown_share"])


DFV_AAT = ROOT / "models" / "dfv_aat.onnx"
DFV_FOCAL_MM, DFV_F_NUMBER = 10.0, 2.0  # any thin lens: the pixel pitch is solved so its blur growth is the stack's


def camera_for_blur(px_per_d: float, focus_m: np.ndarray) -> tuple[float, float, float]:
    """(focal mm, f-number, pixel um) of a thin lens whose blur grows by px_per_d px per diopter at the middle of the
    sweep (in diopters), as the any-camera model computes it (`CameraOptics.defocus_px_per_d`); the blur growth is
    inversely proportional to the pixel pitch."""
    from aat_deploy.calibrate.format import thin_lens_defocus_scale_px_per_d

    mid_m = 2.0 / (1.0 / float(np.min(focus_m)) + 1.0 / float(np.max(focus_m)))
    k_at_1um = thin_lens_defocus_scale_px_per_d(DFV_FOCAL_MM, DFV_F_NUMBER, 1.0, mid_m)
    return DFV_FOCAL_MM, DFV_F_NUMBER, k_at_1um / px_per_d


def dfv_aat_column(stack: RealStack, max_side: int, model: Path | None = None) -> Column | str:
    """The any-camera model as `aat-infer --model dfv_aat --camera F,N,PIXEL_UM` runs it (thin-lens map), or why not."""
    from aat_deploy import api

    model = DFV_AAT if model is None else model
    if not model.is_file():
        return f"{model.name} not present (scripts/train_dfv_aat.sh, then export)"
    if stack.defocus_px_per_d is None:
        return f"not run: {stack.no_defocus_why}"
    t0 = time.perf_counter()
    net = api.load_model(model, threads=2)
    net.max_side = max_side
    camera = camera_for_blur(stack.defocus_px_per_d, stack.focus_m)
    res = api.depth_from_focus(stack.frames, stack.focus_m, net, camera=camera, align=stack.align)
    # without a confidence calibration nothing is marked unknown: no share to show (it would read as 0 % doubtful)
    share = res.unknown["unknown_share"] if res.unknown and res.confidence is not None else None
    return Column(res.depth_m, res.aif.transpose(2, 0, 1), res.confidence, time.perf_counter() - t0, res.warnings,
                  share)


METHODS: dict[str, tuple[str, Callable[[RealStack, int], Column | str]]] = {
    "focus": ("classical (--method focus)", focus_column),
    "dfv_aat": ("dfv_aat (any-camera model, thin lens)", dfv_aat_column),
}


# --- pictures ---------------------------------------------------------------------------------------------------
def srgb8(img: np.ndarray) -> np.ndarray:
    """(3, H, W) or (H, W, 3) linear, any scale -> (H, W, 3) uint8 sRGB, white at the 99.5th percentile."""
    from aat_deploy.io.color import linear_to_srgb

    x = img.transpose(1, 2, 0) if img.ndim == 3 and img.shape[0] == 3 else img
    x = x / max(float(np.percentile(x, 99.5)), 1e-6)
    return np.rint(linear_to_srgb(np.clip(x, 0, 1)) * 255).astype(np.uint8)


def panel(title: str, rgb8: np.ndarray, height: int = PANEL_PX) -> np.ndarray:
    h, w = rgb8.shape[:2]
    img = cv2.resize(rgb8, (max(1, round(w * height / h)), height), interpolation=cv2.INTER_AREA)
    out = np.full((height + 22, img.shape[1], 3), 255, np.uint8)
    out[22:] = img
    scale = 0.45  # smaller for a title wider than the panel, so none is cut off
    width = cv2.getTextSize(title, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]
    scale *= min(1.0, (out.shape[1] - 8) / max(width, 1))
    cv2.putText(out, title, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def display_range(stack: RealStack, depths: list[np.ndarray]) -> tuple[float, float]:
    """One colour scale for a stack's depth maps (every method's, so their panels compare): (near, far) in the
    stack's units for metric depth, else (low, high) of the shown quantity; robust percentiles of all known pixels."""
    from aat_deploy.io.colorize import depth_range

    if stack.kind == "depth":
        return depth_range(np.concatenate([d.ravel() for d in depths]))
    v = np.concatenate([stack.display(d).ravel() for d in depths])
    known = v[np.isfinite(v)]
    lo, hi = (np.percentile(known, [0.5, 99.5]) if known.size else (0.0, 1.0))
    return float(lo), float(hi if hi > lo else lo + 1)


def depth_panel(stack: RealStack, col: Column, rng: tuple[float, float] | None = None) -> np.ndarray:
    from aat_deploy.io.colorize import DEPTH_COLORMAP, depth_preview, linear_preview

    lo, hi = display_range(stack, [col.depth]) if rng is None else rng
    if stack.kind == "depth":
        return depth_preview(col.depth, lo, hi, unit=stack.unit)[0]
    return linear_preview(stack.display(col.depth), lo, hi, stack.unit, "", DEPTH_COLORMAP)


def row_picture(stack: RealStack, cols: dict[str, Column | str], methods: dict | None = None,
                height: int = PANEL_PX) -> np.ndarray:
    """One stack's picture: a middle frame (and the source's reference image), then per method that ran its
    all-in-focus, depth (one colour scale for all methods) and confidence; (height + 22, W, 3) uint8 RGB.
    methods: {key: (title, column function)} the titles come from (default METHODS)."""
    from aat_deploy.io.colorize import linear_preview

    methods = METHODS if methods is None else methods
    s = len(stack.frames)
    panels = [panel(f"frame {s // 2 + 1} of {s}", srgb8(stack.frames[s // 2]), height)]
    if stack.reference is not None:
        panels.append(panel("the source's all-in-focus" if stack.name == "lytro_refocus" else "centre view",
                            srgb8(stack.reference), height))
    ran = {k: c for k, c in cols.items() if not isinstance(c, str)}  # the others: said on the page, no panels
    rng = display_range(stack, [c.depth for c in ran.values()]) if ran else None
    for key, col in ran.items():
        panels.append(panel(f"{methods[key][0]}: all-in-focus", srgb8(col.aif), height))
        unk = (" (no confidence)" if col.confidence is None else "" if col.unknown_share is None
               else f" ({col.unknown_share:.0%} unknown, grey)")
        panels.append(panel(f"depth{unk}", depth_panel(stack, col, rng), height))
        if col.confidence is not None:
            panels.append(panel("confidence", linear_preview(col.confidence, 0.0, 1.0, "conf.", "", "viridis"),
                                height))
    return np.concatenate(panels, 1)


def page(rows: list[tuple[RealStack, dict[str, Column | str], str]], max_side: int, methods: dict | None = None,
         note: str = "") -> str:
    """The gallery's markdown page; methods as row_picture's (its keys: the columns, in order); note: a paragraph
    after the introduction (which model file ran, where it is not the shipped one)."""
    methods = METHODS if methods is None else methods
    lines = ["# Real focal stacks: depth, all-in-focus and confidence (shown, not scored)", "",
             "Made by `python -m scripts.make_real_gallery` from every real stack in `../shared/data` (not in the "
             "repository: research data of others, see each folder's MANIFEST.md). None has ground truth, so "
             "nothing here is a score. Each method runs as `aat-infer` runs it, with the stack's own focus "
             f"distances or, where it has none, placeholder positions (as `--focus-m` would give), at most "
             f"{max_side} px on the longer side. Depth whose calibrated confidence (the chance of being within 10 % "
             "of the truth, docs/contracts.md) is below 0.5 is unknown and grey; with placeholder positions (and the phone "
             "stack's undocumented units) its tolerance refers to those positions, so read it as relative there. "
             "No lens is given (thin-lens mapping). To add a method column, see the script's docstring.", ""]
    lines += [note, ""] if note else []
    lines += ["| stack | frames | focus distances | " + " | ".join(f"{methods[k][0]}: time, unknown"
                                                              for k in methods) + " |",
              "|---|---|---|" + "---|" * len(methods)]
    for st, cols, _ in rows:
        cells = [c if isinstance(c, str) else f"{c.seconds:.2f} s, {c.unknown_share:.0%}"
                 if c.unknown_share is not None else f"{c.seconds:.2f} s, no confidence" if c.confidence is None
                 else f"{c.seconds:.2f} s" for c in (cols.get(k, "–") for k in methods)]
        lines.append(f"| {st.title} | {len(st.frames)} × {st.frames.shape[2]}×{st.frames.shape[1]} px | "
                     f"{st.focus_note} | " + " | ".join(cells) + " |")
    lines.append("")
    for st, cols, png in rows:
        lines += [f"## {st.title}", "", f"Source: {st.source}. Focus: {st.focus_note}."
                  + (" Frames aligned and exposure-equalised (`--align`)." if st.align else ""), ""]
        for k, c in cols.items():
            for n in [c] if isinstance(c, str) else dict.fromkeys(c.notes):
                lines.append(f"- {methods[k][0]}: {n}")
        if any(isinstance(c, str) or c.notes for c in cols.values()):
            lines.append("")
        lines += [f"![{st.name}](gallery/{png})", ""]
    return "\n".join(lines)


def model_methods(keys: list[str], model: Path) -> tuple[dict, str]:
    """The method columns `keys` of METHODS, the dfv_aat column running `model`, and the page's note on it: a file
    other than the shipped models/dfv_aat.onnx is named in the column's title and the note, as not shipped."""
    methods = {k: METHODS[k] for k in keys}
    if "dfv_aat" not in methods or model.resolve() == DFV_AAT.resolve():
        return methods, ""
    methods["dfv_aat"] = (f"any-camera {model.stem} (not shipped)", functools.partial(dfv_aat_column, model=model))
    return methods, (f"The any-camera column runs `{model.name}`, a candidate model that is **not** the shipped "
                     "`models/dfv_aat.onnx` (BENCHMARKS.md, \"The any-camera model\", says why), as `aat-infer "
                     "--model` runs it: in the model's own tiles (`aat.tile_px`), told a thin lens.")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs", help="folder for real_stacks.md and gallery/")
    ap.add_argument("--max-side", type=int, default=640, help="working size: longer side in px (as --max-side)")
    ap.add_argument("--methods", default=",".join(METHODS), help=f"method columns (of {', '.join(METHODS)})")
    ap.add_argument("--stacks", default=",".join(STACKS), help=f"stacks (of {', '.join(STACKS)})")
    ap.add_argument("--model", type=Path, default=DFV_AAT,
                    help="the any-camera model file of the dfv_aat column (default the shipped models/dfv_aat.onnx)")
    ap.add_argument("--panel-px", type=int, default=PANEL_PX, help="panel height in the pictures (px)")
    a = ap.parse_args(argv)
    keys = [m for m in a.methods.split(",") if m]
    stacks = [s for s in a.stacks.split(",") if s]
    bad = [m for m in keys if m not in METHODS] + [s for s in stacks if s not in STACKS]
    if bad:
        ap.error(f"unknown method or stack: {', '.join(bad)}")
    methods, note = model_methods(keys, a.model)
    from tqdm import tqdm

    from aat_deploy.io.atomic import atomic_file, write_text_atomic

    (a.out / "gallery").mkdir(parents=True, exist_ok=True)
    rows = []
    for name in tqdm(stacks, desc="real stacks", unit="stack", file=sys.stderr):
        if not (SHARED / FOLDERS[name]).is_dir():
            print(f"{SHARED / FOLDERS[name]}: not present, skipped", file=sys.stderr)
            continue
        st = STACKS[name]()
        cols = {m: methods[m][1](st, a.max_side) for m in methods}
        png = f"{name}.png"
        with atomic_file(a.out / "gallery" / png) as tmp:
            cv2.imwrite(str(tmp), row_picture(st, cols, methods, a.panel_px)[..., ::-1],
                        [cv2.IMWRITE_PNG_COMPRESSION, 9])
        rows.append((st, cols, png))
        print(f"{name}: {len(st.frames)} frames; " + ", ".join(f"{m} {c if isinstance(c, str) else f'{c.seconds:.2f} s'}"
                                                           for m, c in cols.items()),
              file=sys.stderr)
    write_text_atomic(a.out / "real_stacks.md", page(rows, a.max_side, methods, note) + "\n")
    print(f"wrote {a.out / 'real_stacks.md'} and {len(rows)} pictures in {a.out / 'gallery'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
