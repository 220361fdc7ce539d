"""Mobile Depth (Suwajanakorn, Hernandez, Seitz, "Depth from Focus with Your Mobile Phone", CVPR 2015): real phone
focal stacks of 14 scenes, already aligned. It has **no ground-truth depth**: `aat-eval` runs the method and shows
the result (depth previews), it scores nothing.

Format (either layout, a folder per scene under the dataset folder, or one scene folder itself):
- the release as DFV reads it: frames `a0.jpg, a1.jpg, ...` (numbered) and `focus_dpth.txt`, one focus value per
  frame;
- DfF-in-the-Wild's copy: frames `00.jpg, 01.jpg, ...` and `focus_distance.txt` (and `focal_length.txt`).
The focus values are the dataset's own estimates in undocumented units (larger = farther in the published scenes;
the first frame of "balls" is 7.2e6), except "metals", whose estimates run the other way (smaller = farther; DFV's
evaluation negates them too). The frames are ordered by them, near to far, and given placeholder focus
distances even in diopters between 0.5 and 1 m: the depth maps show relative position in the sweep, not metres.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aat_deploy.optics.focus_table import diopter_grid

from .base import Conventions, Dataset, DatasetError, Item, depth_unit, select_frames

LAYOUTS = (("a", "focus_dpth.txt"), ("", "focus_distance.txt"))  # (frame name prefix, focus file)
PLACEHOLDER_M = (0.5, 1.0)  # placeholder focus distances (m), near to far, even in diopters (2 ... 1 D)
REVERSED = ("metals",)  # scenes whose focus values grow towards the camera

CONVENTIONS = Conventions(
    unit="depth_m", to_unit=depth_unit, clip=None,
    text="Mobile Depth has no ground truth: shown, not scored. Frames ordered by the dataset's focus values "
         "(undocumented units) with placeholder focus distances even in diopters over 0.5-1 m: relative depth only.")


def scene_frames(folder: Path) -> tuple[list[Path], np.ndarray] | None:
    """(frames in file order, their focus values) of a Mobile Depth scene folder, or None if it is not one."""
    for prefix, focus_name in LAYOUTS:
        focus_file = folder / focus_name
        if not focus_file.is_file():
            continue
        numbered = []
        for p in folder.iterdir():
            stem = p.stem[len(prefix):] if p.stem.startswith(prefix) else None
            if p.suffix.lower() == ".jpg" and stem is not None and stem.isdigit():
                numbered.append((int(stem), p))
        numbered.sort()
        try:
            values = np.atleast_1d(np.loadtxt(focus_file, dtype=np.float64, ndmin=1)).ravel()
        except ValueError as e:
            raise DatasetError(f"{focus_file}: not a list of numbers ({str(e)[:80]})") from None
        if len(values) != len(numbered):
            raise DatasetError(f"{focus_file}: {len(values)} focus values for {len(numbered)} frames")
        if not np.all(np.isfinite(values)):
            raise DatasetError(f"{focus_file}: focus values must be finite")
        return [p for _, p in numbered], values
    return None


class MobileDepth(Dataset):
    name = "mobile_depth"
    conventions = CONVENTIONS

    def __init__(self, path: Path, split: str = "all", frames: list[int] | None = None):
        if split != "all":
            raise DatasetError(f"{path}: Mobile Depth has no splits (split 'all')")
        self.path = Path(path)
        if not self.path.is_dir():
            raise DatasetError(f"{self.path}: not a folder")
        own = scene_frames(self.path)
        folders = [self.path] if own is not None else sorted(p for p in self.path.iterdir() if p.is_dir())
        self.scenes = [(f, sf) for f in folders if (sf := own if f == self.path else scene_frames(f)) is not None]
        if not self.scenes:
            raise DatasetError(f"{self.path}: no Mobile Depth scene (frames a0.jpg... with focus_dpth.txt, or "
                               "00.jpg... with focus_distance.txt)")
        self.frames = frames

    def __len__(self) -> int:
        return len(self.scenes)

    def describe(self) -> dict:
        return {**super().describe(), "path": str(self.path), "scenes": [f.name for f, _ in self.scenes]}

    def items(self):
        for folder, (files, values) in self.scenes:
            order = np.argsort(-values if folder.name in REVERSED else values, kind="stable")  # near to far
            keep = select_frames(len(order), self.frames, str(folder))
            order = order[keep]
            s = len(order)
            focus = diopter_grid(*PLACEHOLDER_M, s)
            yield Item(folder.name, [self.frame_loader(files[i]) for i in order], focus, None, None,
                       {"focus": "placeholders even in diopters over 0.5-1 m (relative)",
                        "focus_values": values[order].tolist(), "files": [files[i].name for i in order]})
