"""FoD500 (Maximov, Galim, Leal-Taixé, "Focus on Defocus", CVPR 2020; the DefocusNet data): 500 Blender scenes,
5-slice focal stacks with metric depth.

Format (the published folder, flat): per scene five 256 x 256 8-bit sRGB images whose names end in `All.tif` and one
depth map whose name ends in `Dpt.exr` (OpenEXR, depth in metres in the R channel, half float), all named by a
6-digit scene number first; sorted by name, a scene's five images are its slices focused at 0.1, 0.15, 0.3, 0.7 and
1.5 m (the DefocusNet settings: focal length 2.9 mm, f/1; depths to 3 m). Splits as DFV and AiFDepthNet use them:
"train" = scenes 0-399, "test" = scenes 400-499.

Scoring as DFV's FoD500 evaluation: metric depth in metres, prediction and ground truth clipped to [0, 1.5] m, over
pixels with ground truth > 0, per scene then the mean over scenes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import Conventions, Dataset, DatasetError, Item, depth_unit, need, select_frames

FOCUS_M = np.array([0.1, 0.15, 0.3, 0.7, 1.5])
SPLITS = {"train": range(0, 400), "test": range(400, 500)}
CLIP_M = (0.0, 1.5)

CONVENTIONS = Conventions(
    unit="depth_m", to_unit=depth_unit, clip=CLIP_M,
    text="FoD500: metric depth (m), prediction and ground truth clipped to [0, 1.5] m, over pixels whose ground "
         "truth is > 0, per scene then the mean over scenes (DFV's protocol). Focus distances 0.1, 0.15, 0.3, 0.7, "
         "1.5 m as rendered (Blender: distances from the camera).")


def read_exr_depth(path: Path) -> np.ndarray:
    """The R channel of an OpenEXR depth map as float32 (H, W)."""
    exr = need("OpenEXR", "reading FoD500's .exr depth")
    try:
        with exr.File(str(path), separate_channels=True) as f:
            ch = f.channels()
            key = "R" if "R" in ch else next((k for k in ch if k.split(".")[-1] in ("R", "Z", "Y")), None)
            if key is None:
                raise DatasetError(f"{path}: no R, Z or Y channel (channels: {', '.join(sorted(ch))})")
            return np.asarray(ch[key].pixels, np.float32)
    except DatasetError:
        raise
    except Exception as e:  # noqa: BLE001 (OpenEXR raises plain exceptions for damaged files)
        raise DatasetError(f"{path}: not a readable OpenEXR file ({str(e).splitlines()[0][:120] if str(e) else type(e).__name__})") from None


def scene_id(name: str) -> int | None:
    return int(name[:6]) if len(name) >= 6 and name[:6].isdigit() else None


class FoD500(Dataset):
    name = "fod500"
    conventions = CONVENTIONS

    def __init__(self, path: Path, split: str = "test", frames: list[int] | None = None):
        if split not in SPLITS:
            raise DatasetError(f"{path}: FoD500 split {split!r} (one of {', '.join(SPLITS)})")
        self.path, self.split = Path(path), split
        if not self.path.is_dir():
            raise DatasetError(f"{self.path}: not a folder (FoD500 is a folder of *All.tif and *Dpt.exr files)")
        images: dict[int, list[Path]] = {}
        depths: dict[int, Path] = {}
        for p in sorted(self.path.iterdir()):
            sid = scene_id(p.name)
            if sid is None or sid not in SPLITS[split] or not p.is_file():
                continue
            if p.name.endswith("All.tif"):
                images.setdefault(sid, []).append(p)
            elif p.name.endswith("Dpt.exr"):
                if sid in depths:
                    raise DatasetError(f"{p}: a second depth map for scene {sid:06d} ({depths[sid].name})")
                depths[sid] = p
        if not images:
            raise DatasetError(f"{self.path}: no FoD500 images (*All.tif named by scene number) of the {split} "
                               f"split (scenes {SPLITS[split].start}-{SPLITS[split].stop - 1})")
        for sid, files in images.items():
            if len(files) != len(FOCUS_M):
                raise DatasetError(f"{files[0]}: scene {sid:06d} has {len(files)} *All.tif images, "
                                   f"FoD500 has {len(FOCUS_M)}")
        self.scenes = sorted(images)
        self.images, self.depths = images, depths
        self.frames = select_frames(len(FOCUS_M), frames, str(self.path))

    def __len__(self) -> int:
        return len(self.scenes)

    def describe(self) -> dict:
        return {**super().describe(), "path": str(self.path), "split": self.split, "frames": self.frames,
                "focus_m": FOCUS_M[self.frames].tolist(), "scenes_without_depth": sum(s not in self.depths
                                                                                       for s in self.scenes)}

    def items(self):
        for sid in self.scenes:
            files = [self.images[sid][k] for k in self.frames]
            gt = None
            if sid in self.depths:
                gt = read_exr_depth(self.depths[sid])
                gt = np.where(np.isfinite(gt) & (gt > 0), gt, np.nan).astype(np.float32)
            yield Item(f"{sid:06d}", [self.frame_loader(p) for p in files], FOCUS_M[self.frames], gt,
                       None, {"files": [p.name for p in files]})
