"""ZEDD (Zuo, Wen, Subramanian et al., "Zero-Shot Depth from Defocus", 2026; CC BY 4.0): 100 real scenes, focus
sweeps of 9 focus distances (0.82-8.10 m) at five apertures (F1.4-5.6) and an all-in-focus F16, with dense metric
ground truth.

Format (the published folder):
    ZEDD/metadata.txt                 one line per run: run id, motor position (hex), focus distance in metres,
                                      tab-separated ('#' starts a comment), e.g. "run_1<TAB>6D3E<TAB>0.82"
    ZEDD/val/val_0001/focus_stack/img_run_<r>_motor_<HEX>_aperture_F<N.N>.jpg
    ZEDD/val/val_0001/gt/depth.npy    float metres (1216 x 1824), the frames' field of view; K.txt intrinsics
    ZEDD/test/test_0001/...           the same without depth.npy (hidden: scored by ZEDD's server)
Defaults as FOSSA's ZEDD evaluation: aperture F2.8, runs 1, 3, 5, 7, 9 (`--frames 0,2,4,6,8` of the 9);
`--frames` and `--aperture` choose others.

Scoring: metric depth in metres over pixels with ground truth finite and within 0.01-1000 m (FOSSA's mask), per
scene then the mean. FOSSA scores a 640 x 480 centre crop after resizing to 480 rows; here the runtime's working
grid over the whole field of view (the ground truth nearest-sampled to it): the same kind of number, not the same
crop.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import Conventions, Dataset, DatasetError, Item, depth_unit, select_frames

SPLITS = ("val", "test")
APERTURES = (1.4, 2.0, 2.8, 4.0, 5.6, 16.0)
DEFAULT_FRAMES = [0, 2, 4, 6, 8]
VALID_M = (0.01, 1000.0)

CONVENTIONS = Conventions(
    unit="depth_m", to_unit=depth_unit, clip=None,
    text="ZEDD: metric depth (m) over pixels whose ground truth is finite and within 0.01-1000 m (FOSSA's mask), "
         "per scene then the mean over scenes; scored on the runtime's working grid over the whole field of view "
         "(FOSSA scores a 640 x 480 centre crop). Focus distances from metadata.txt as published.")


def read_metadata(path: Path) -> dict[int, tuple[str, float]]:
    """metadata.txt -> {run number: (motor hex code, focus distance m)}; DatasetError naming the line."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read ZEDD's metadata ({e})") from None
    runs: dict[int, tuple[str, float]] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split("\t") if "\t" in line else line.split()
        try:
            run_id, code, focus = parts
            if not run_id.startswith("run_"):
                raise ValueError
            r, f = int(run_id[4:]), float(focus)
        except ValueError:
            raise DatasetError(f"{path}:{n}: not 'run_<n> <motor hex> <focus m>': {line[:80]!r}") from None
        if not (np.isfinite(f) and 0 < f <= 1000):
            raise DatasetError(f"{path}:{n}: focus distance {focus!r} is not a distance in metres")
        runs[r] = (code, f)
    if not runs:
        raise DatasetError(f"{path}: no runs")
    return runs


class ZEDD(Dataset):
    name = "zedd"
    conventions = CONVENTIONS

    def __init__(self, path: Path, split: str = "val", frames: list[int] | None = None, aperture: float = 2.8):
        if split not in SPLITS:
            raise DatasetError(f"{path}: ZEDD split {split!r} (one of {', '.join(SPLITS)})")
        if not any(abs(aperture - a) < 1e-6 for a in APERTURES):
            raise DatasetError(f"{path}: ZEDD aperture F{aperture:g} (one of {', '.join(f'F{a:g}' for a in APERTURES)})")
        self.path, self.split, self.aperture = Path(path), split, float(aperture)
        meta = self.path / "metadata.txt"
        if not meta.is_file():
            raise DatasetError(f"{self.path}: no metadata.txt (give the ZEDD folder that holds it and val/, test/)")
        self.runs = read_metadata(meta)
        order = sorted(self.runs, key=lambda r: self.runs[r][1])  # near to far
        self.run_order = [order[k] for k in select_frames(len(order), DEFAULT_FRAMES if frames is None and
                                                          len(order) == 9 else frames, str(meta))]
        folder = self.path / split
        self.scenes = sorted(p for p in folder.iterdir() if p.is_dir()) if folder.is_dir() else []
        if not self.scenes:
            raise DatasetError(f"{folder}: no scene folders")

    def __len__(self) -> int:
        return len(self.scenes)

    def describe(self) -> dict:
        return {**super().describe(), "path": str(self.path), "split": self.split, "aperture": self.aperture,
                "runs": self.run_order, "focus_m": [self.runs[r][1] for r in self.run_order]}

    def frame_path(self, scene: Path, run: int) -> Path:
        code = self.runs[run][0]
        return scene / "focus_stack" / f"img_run_{run}_motor_{code}_aperture_F{self.aperture:.1f}.jpg"

    def items(self):
        focus = np.array([self.runs[r][1] for r in self.run_order], np.float64)
        for scene in self.scenes:
            files = [self.frame_path(scene, r) for r in self.run_order]
            missing = [p for p in files if not p.is_file()]
            if missing:
                raise DatasetError(f"{missing[0]}: missing (ZEDD frame of run {self.run_order[files.index(missing[0])]} "
                                   f"at F{self.aperture:g})")
            gt = None
            depth = scene / "gt" / "depth.npy"
            if depth.is_file():
                try:
                    gt = np.load(depth, allow_pickle=False).astype(np.float32)
                except (OSError, ValueError) as e:
                    raise DatasetError(f"{depth}: not a readable .npy ({str(e)[:100]})") from None
                if gt.ndim != 2:
                    raise DatasetError(f"{depth}: shape {gt.shape}, a 2-D depth map expected")
                with np.errstate(invalid="ignore"):
                    ok = np.isfinite(gt) & (gt >= VALID_M[0]) & (gt <= VALID_M[1])
                gt = np.where(ok, gt, np.nan).astype(np.float32)
            yield Item(scene.name, [self.frame_loader(p) for p in files], focus, gt, None,
                       {"files": [p.name for p in files]})
