"""Test helpers for the runtime: a tiny contract-following ONNX DfF model, synthetic capture folders, a PFM
writer and an interpreter without torch (`run_without_torch`).

The model is a classical depth-from-focus net with fixed weights (grey → Laplacian → local energy → softmax
over the stack → the contract's head), so its depth is meaningful on the synthetic stacks: near pixels are
sharpest in near-focused frames. Built with torch (tests may use torch; the runtime never does).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]  # the repository
XYZ_TO_SRGB = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])
LENS = "Test Lens 50mm f/1.8"
META = {"aat.kind": "dff", "aat.net": "aifnet", "aat.size": "small", "aat.simulator": "thin_lens",
        "aat.effects": [], "aat.lens_name": LENS, "aat.lens_hash": "0" * 16, "aat.focal_length_mm": 50.0,
        "aat.f_number": 1.8, "aat.sensor_mm": [34.56, 25.92], "aat.sensor_px": [64, 48], "aat.pixel_um": 540.0,
        "aat.focus_range_m": [0.5, 5.0], "aat.stack_min": 2, "aat.stack_max": 16, "aat.size_multiple": 8,
        "aat.input_normalisation": "percentile 99.5, clip [0, 1]", "aat.config_hash": "test",
        "aat.version": "0.1.0", "aat.distances": "metres from the sensor plane"}


def build_tiny_dff(path: Path, meta_over: dict | None = None, sharpness: float = 8.0) -> Path:
    """Export the tiny DfF model to `path` (opset 17, dynamic B, S, H, W) with aat metadata."""
    import onnx
    import torch
    from torch import nn

    class TinyDfF(nn.Module):
        def __init__(self):
            super().__init__()
            lap = torch.tensor([[0.0, 1.0, 0.0], [1.0, -4.0, 1.0], [0.0, 1.0, 0.0]])
            self.lap = nn.Conv2d(1, 1, 3, padding=1, bias=False, padding_mode="replicate")
            self.lap.weight.data[:] = lap
            self.pool = nn.AvgPool2d(5, stride=1, padding=2, count_include_pad=False)

        def forward(self, stack, focus_m):
            b, s = stack.shape[0], stack.shape[1]
            h, w = stack.shape[3], stack.shape[4]
            grey = stack.mean(2).reshape(b * s, 1, h, w)
            energy = self.pool(self.lap(grey) ** 2).reshape(b, s, h, w)
            logits = sharpness * energy / (energy.mean(1, keepdim=True) + 1e-6)
            p = torch.softmax(logits, 1)
            f = focus_m[:, :, None, None]
            depth = (p * f).sum(1)
            std = torch.sqrt(((p * (f - depth[:, None]) ** 2).sum(1)).clamp_min(0) + 1e-12)
            aif = (p[:, :, None] * stack).sum(1)
            return depth, aif, std

    torch.manual_seed(0)
    net = TinyDfF().eval()
    ex = (torch.rand(1, 3, 3, 16, 24), torch.tensor([[0.5, 1.0, 2.0]]))
    path = Path(path)
    torch.onnx.export(net, ex, str(path), dynamo=False, opset_version=17, input_names=["stack", "focus_m"],
                      output_names=["depth_m", "aif", "std_m"],
                      dynamic_axes={"stack": {0: "B", 1: "S", 3: "H", 4: "W"}, "focus_m": {0: "B", 1: "S"},
                                    "depth_m": {0: "B", 1: "H", 2: "W"}, "aif": {0: "B", 2: "H", 3: "W"},
                                    "std_m": {0: "B", 1: "H", 2: "W"}})
    m = onnx.load(str(path))
    meta = dict(META, **(meta_over or {}))
    del m.metadata_props[:]
    for k, v in meta.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v if isinstance(v, str) else json.dumps(v)
    onnx.save(m, str(path))
    return path


def synthetic_scene(h: int = 48, w: int = 64, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Textured linear RGB (h, w, 3) in [0.05, 0.9] and depth (h, w): left half 0.8 m, right half 3 m."""
    rng = np.random.default_rng(seed)
    tex = rng.uniform(0.05, 0.9, (h, w, 3)).astype(np.float32)
    depth = np.full((h, w), 3.0, np.float32)
    depth[:, : w // 2] = 0.8
    return tex, depth


def render_stack(tex: np.ndarray, depth: np.ndarray, focus_m: list[float], blur_px_per_diopter: float = 2.5
                 ) -> list[np.ndarray]:
    """Thin-lens-ish defocus: each depth layer blurred with sigma ∝ |1/d − 1/f| (diopters)."""
    frames = []
    for f in focus_m:
        out = np.zeros_like(tex)
        for d in np.unique(depth):
            sigma = blur_px_per_diopter * abs(1 / d - 1 / f)
            layer = cv2.GaussianBlur(tex, (0, 0), sigma) if sigma > 0.05 else tex
            out[depth == d] = layer[depth == d]
        frames.append(out)
    return frames


def mosaic(rgb: np.ndarray, black: int = 64, white: int = 4095, scale: float = 0.8) -> np.ndarray:
    """Linear RGB (h, w, 3) → RGGB Bayer uint16 DN."""
    h, w, _ = rgb.shape
    cfa = np.empty((h, w), np.float32)
    cfa[0::2, 0::2] = rgb[0::2, 0::2, 0]
    cfa[0::2, 1::2] = rgb[0::2, 1::2, 1]
    cfa[1::2, 0::2] = rgb[1::2, 0::2, 1]
    cfa[1::2, 1::2] = rgb[1::2, 1::2, 2]
    return np.clip(np.rint(black + cfa * scale * (white - black)), 0, white).astype(np.uint16)


def write_dng_capture(folder: Path, focus_m: list[float], *, h: int = 48, w: int = 64, lens: str = LENS,
                      focal_length_mm: float = 50.0, f_number: float = 1.8, gt: bool = True,
                      names: list[str] | None = None) -> Path:
    """A capture folder of DNG frames (EXIF SubjectDistance + XMP focus) written by the virtual camera's writer."""
    from aat_deploy.capture.dng import write_dng

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tex, depth = synthetic_scene(h, w)
    for i, (f, img) in enumerate(zip(focus_m, render_stack(tex, depth, focus_m))):
        name = names[i] if names else f"frame_{i:02d}.dng"
        write_dng(folder / name, mosaic(img), black_level=64, white_level=4095, color_matrix=XYZ_TO_SRGB,
                  subject_distance_m=f, focal_length_mm=focal_length_mm, f_number=f_number, make="aat",
                  model="virtual camera", lens_model=lens)
    if gt:
        np.save(folder / "gt_depth_m.npy", depth)
        cv2.imwrite(str(folder / "gt_depth_mm.png"), np.rint(depth * 1000).astype(np.uint16))
    return folder


def write_png_capture(folder: Path, focus_m: list[float], *, h: int = 48, w: int = 64, sidecar: bool = True,
                      bits: int = 16) -> Path:
    """A capture folder of sRGB PNG frames with a capture.json sidecar giving the focus distances."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tex, depth = synthetic_scene(h, w)
    from aat_deploy.io.color import linear_to_srgb

    frames = []
    for i, (f, img) in enumerate(zip(focus_m, render_stack(tex, depth, focus_m))):
        enc = linear_to_srgb(img)[..., ::-1]
        arr = np.rint(enc * 65535).astype(np.uint16) if bits == 16 else np.rint(enc * 255).astype(np.uint8)
        name = f"img_{i}.png"
        cv2.imwrite(str(folder / name), arr)
        frames.append({"file": name, "focus_m": f})
    if sidecar:
        (folder / "capture.json").write_text(json.dumps({"frames": frames}))
    return folder


def write_jpeg_capture(folder: Path, focus_m: list[float], *, h: int = 48, w: int = 64,
                       names: list[str] | None = None) -> Path:
    """A capture folder of 8-bit sRGB JPEG frames (quality 95; names default img_I.jpg, any name may be given, e.g.
    a JPEG misnamed .png) with a capture.json sidecar giving the focus distances."""
    from aat_deploy.io.color import linear_to_srgb

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tex, depth = synthetic_scene(h, w)
    frames = []
    for i, (f, img) in enumerate(zip(focus_m, render_stack(tex, depth, focus_m))):
        name = names[i] if names else f"img_{i}.jpg"
        enc = np.rint(linear_to_srgb(img)[..., ::-1] * 255).astype(np.uint8)
        (folder / name).write_bytes(cv2.imencode(".jpg", enc, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes())
        frames.append({"file": name, "focus_m": f})
    (folder / "capture.json").write_text(json.dumps({"frames": frames}))
    return folder


def claim_size(buf: bytes, w: int, h: int) -> bytes:
    """A JPEG, PNG or TIFF whose header claims w x h pixels, the data left as it was (a decompression bomb: a few
    hundred bytes that a decoder trusting its header would allocate gigabytes for)."""
    import struct
    import zlib

    b = bytearray(buf)
    if b[:2] == b"\xff\xd8":
        i = 2
        while b[i + 1] not in (0xC0, 0xC1, 0xC2):
            i += 2 + struct.unpack(">H", b[i + 2:i + 4])[0]
        struct.pack_into(">HH", b, i + 5, h, w)
    elif b[:4] == b"\x89PNG":
        struct.pack_into(">II", b, 16, w, h)
        struct.pack_into(">I", b, 29, zlib.crc32(bytes(b[12:29])))
    elif b[:4] in (b"II*\0", b"MM\0*"):
        e = "<" if b[:2] == b"II" else ">"
        (first,) = struct.unpack(e + "I", b[4:8])
        (n,) = struct.unpack(e + "H", b[first:first + 2])
        for k in range(n):
            at = first + 2 + 12 * k
            tag, typ = struct.unpack(e + "HH", b[at:at + 4])
            if tag in (256, 257):
                v = w if tag == 256 else h
                struct.pack_into(e + ("HH" if typ == 3 else "I"), b, at + 8, *((v, 0) if typ == 3 else (v,)))
    else:
        raise ValueError("not a JPEG, PNG or TIFF")
    return bytes(b)


def tree_hash(*roots: Path) -> dict[str, str]:
    """Every entry under the roots: file bytes (sha256), symlink targets, folders and special files by kind."""
    import hashlib

    out: dict[str, str] = {}
    for root in roots:
        for cur, dirs, files in os.walk(root):
            for name in dirs + files:
                p = Path(cur) / name
                if p.is_symlink():
                    out[str(p)] = "link:" + os.readlink(p)
                elif p.is_file():
                    out[str(p)] = hashlib.sha256(p.read_bytes()).hexdigest()
                else:
                    out[str(p)] = "dir" if p.is_dir() else "special"
        out[str(root)] = "root"
    return out


ENTRY_KINDS = ("jpeg", "png", "dng", "jpeg_named_png", "png_small", "cut_jpeg", "bomb", "garbage", "empty",
               "html", "nan_tiff", "link_out", "link_dup", "hardlink_dup", "dangling", "folder")
SIDECAR_KINDS = ("none", "list", "list_bom", "broken_json", "lists_missing")
GOOD_KINDS = {"jpeg", "png", "dng", "jpeg_named_png"}  # good frames, whatever their name
SKIPPED_UNLISTED = {"dangling", "folder"}  # not regular files: skipped with a warning unless capture.json lists them
FUZZ_FOCUS_M = (0.6, 0.9, 1.4, 2.2, 3.5, 5.0)


def fuzz_seeds(folder: Path) -> dict[str, list[bytes]]:
    """Good 48 x 64 frames of one scene at the focus distances FUZZ_FOCUS_M, as JPEG, PNG and DNG bytes (the DNGs
    carry their focus distance in EXIF), for random_capture."""
    folder = Path(folder)
    j = write_jpeg_capture(folder / "j", list(FUZZ_FOCUS_M))
    p = write_png_capture(folder / "p", list(FUZZ_FOCUS_M))
    d = write_dng_capture(folder / "d", list(FUZZ_FOCUS_M), gt=False)
    return {"jpeg": [(j / f"img_{i}.jpg").read_bytes() for i in range(len(FUZZ_FOCUS_M))],
            "png": [(p / f"img_{i}.png").read_bytes() for i in range(len(FUZZ_FOCUS_M))],
            "dng": [(d / f"frame_{i:02d}.dng").read_bytes() for i in range(len(FUZZ_FOCUS_M))]}


def random_capture(folder: Path, kinds: list[str], sidecar: str, seeds: dict[str, list[bytes]], outside: Path,
                   junk: bytes = b"\x00\x01junk") -> list[str]:
    """A capture folder with one entry per kind (ENTRY_KINDS: good frames of three formats, misnamed, cut, bombs,
    garbage, NaN, links out of the folder or to another frame, dangling links, folders named like frames) and a
    capture.json of the given kind (SIDECAR_KINDS). Entry i has the focus distance FUZZ_FOCUS_M[i]. `outside` is a
    folder beside it holding a good frame the links may point to (it must never be read). Returns the kinds as
    made (a link to another frame with no regular first frame to point at is made a good PNG)."""
    folder, outside = Path(folder), Path(outside)
    folder.mkdir(parents=True)
    outside.mkdir(parents=True, exist_ok=True)
    if not (outside / "secret.png").exists():
        (outside / "secret.png").write_bytes(seeds["png"][0])
    names, made = [], []
    for i, kind in enumerate(kinds):
        k = i % len(FUZZ_FOCUS_M)
        name = {"jpeg": f"f{i}.jpg", "dng": f"f{i}.dng", "nan_tiff": f"f{i}.tif"}.get(kind, f"f{i}.png")
        path = folder / name
        if kind in ("jpeg", "png", "dng"):
            path.write_bytes(seeds[kind][k])
        elif kind == "jpeg_named_png":
            path.write_bytes(seeds["jpeg"][k])
        elif kind == "png_small":
            img = cv2.imdecode(np.frombuffer(seeds["png"][k], np.uint8), cv2.IMREAD_UNCHANGED)
            path.write_bytes(cv2.imencode(".png", img[:24, :32])[1].tobytes())
        elif kind == "cut_jpeg":
            b = seeds["jpeg"][k]
            path.write_bytes(b[:len(b) // 3] + b"\xff\xd9")
        elif kind == "bomb":
            path.write_bytes(claim_size(seeds["jpeg"][k], 20000, 20000))
        elif kind == "garbage":
            path.write_bytes(junk)
        elif kind == "empty":
            path.write_bytes(b"")
        elif kind == "html":
            path.write_bytes(b"<html><body>a page saved under an image's name</body></html>")
        elif kind == "nan_tiff":
            img = np.full((48, 64, 3), 0.5, np.float32)
            img[7, 9] = np.nan
            cv2.imwrite(str(path), img)
        elif kind == "link_out":
            path.symlink_to(outside / "secret.png")
        elif kind in ("link_dup", "hardlink_dup"):
            first = names[0] if names else None
            if first is None or not (folder / first).is_file() or (folder / first).is_symlink():
                path.write_bytes(seeds["png"][k])
                kind = "png"
            elif kind == "link_dup":
                path.symlink_to(first)
            else:
                os.link(folder / first, path)
        elif kind == "dangling":
            path.symlink_to(folder / "gone.png")
        elif kind == "folder":
            path.mkdir()
        else:
            raise ValueError(kind)
        names.append(name)
        made.append(kind)
    frames = [{"file": n, "focus_m": FUZZ_FOCUS_M[i % len(FUZZ_FOCUS_M)]} for i, n in enumerate(names)]
    if sidecar == "lists_missing":
        frames.append({"file": "not_here.png", "focus_m": 9.0})
    text = json.dumps({"frames": frames}).encode()
    if sidecar in ("list", "lists_missing"):
        (folder / "capture.json").write_bytes(text)
    elif sidecar == "list_bom":
        (folder / "capture.json").write_bytes(b"\xef\xbb\xbf" + text)
    elif sidecar == "broken_json":
        (folder / "capture.json").write_bytes(text[: len(text) // 2])
    return made


def tiny_model_path(tmp_path_factory, name: str = "tiny_dff.onnx", **meta_over) -> Path:
    """Build the tiny model once per test session (per distinct name) and return its path."""
    path = tmp_path_factory.getbasetemp() / name
    if not path.exists():
        build_tiny_dff(path, meta_over or None)
    return path


def canon_jpeg(upper_raw: int, lower_raw: int, model: str = "Canon PowerShot S95") -> bytes:
    """A minimal JPEG (SOI, APP1 Exif, EOI; no pixels) whose Canon maker note has ShotInfo (0x0004) with
    FocusDistanceUpper = upper_raw and FocusDistanceLower = lower_raw (int16u, centimetres), laid out as Canon
    cameras write it: maker-note IFD offsets relative to the TIFF header. ExifTool reads it."""
    import struct

    def ifd(entries: list[tuple[int, int, int, bytes]], at: int) -> tuple[bytes, bytes]:
        """(IFD bytes, out-of-line data) for entries (tag, type, count, value bytes) placed at offset `at`."""
        data_at = at + 2 + 12 * len(entries) + 4
        head, data = struct.pack("<H", len(entries)), b""
        for tag, typ, count, value in entries:
            if len(value) <= 4:
                head += struct.pack("<HHI", tag, typ, count) + value.ljust(4, b"\0")
            else:
                head += struct.pack("<HHII", tag, typ, count, data_at + len(data))
                data += value + b"\0" * (len(value) % 2)
        return head + struct.pack("<I", 0), data

    make, mdl = b"Canon\0", model.encode() + b"\0"
    shot = [0] * 22
    shot[0], shot[19], shot[20] = 44, upper_raw, lower_raw
    shot_b = struct.pack("<22H", *shot)
    # layout: header | IFD0 (3 entries) + data | Exif IFD (1 entry) + data | maker-note IFD (1 entry) + data
    ifd0_len = 2 + 12 * 3 + 4 + len(make) + len(mdl) + (len(make) % 2) + (len(mdl) % 2)
    exif_at = 8 + ifd0_len
    mn_at = exif_at + 2 + 12 + 4
    mn, mn_data = ifd([(0x0004, 3, 22, shot_b)], mn_at)
    makernote = mn + mn_data
    exif, exif_data = ifd([(0x927C, 7, len(makernote), makernote)], exif_at)
    assert exif_at + len(exif) == mn_at  # the maker note is the Exif IFD's only out-of-line value
    ifd0, ifd0_data = ifd([(0x010F, 2, len(make), make), (0x0110, 2, len(mdl), mdl),
                           (0x8769, 4, 1, struct.pack("<I", exif_at))], 8)
    tiff = b"II*\0" + struct.pack("<I", 8) + ifd0 + ifd0_data + exif + exif_data
    app1 = b"Exif\0\0" + tiff
    return b"\xff\xd8" + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + b"\xff\xd9"


def write_pfm(path, img: np.ndarray) -> None:
    h, w = img.shape
    with open(path, "wb") as f:
        f.write(f"Pf\n{w} {h}\n-1.0\n".encode())
        f.write(np.ascontiguousarray(img[::-1], dtype="<f4").tobytes())


BLOCK_TORCH = textwrap.dedent("""
    import sys
    class _NoTorch:
        def find_spec(self, name, path=None, target=None):
            if name == "torch" or name.startswith("torch."):
                raise ImportError(f"torch is forbidden in the runtime (import {name})")
            return None
    sys.meta_path.insert(0, _NoTorch())
    sys.modules.pop("torch", None)
""")


def run_without_torch(code: str, tmp_path) -> subprocess.CompletedProcess:
    """Run `code` in a fresh interpreter where `import torch` raises (the runtime's own code from ROOT)."""
    script = tmp_path / "run.py"
    script.write_text(BLOCK_TORCH + textwrap.dedent(code))
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_WAIT_POLICY="PASSIVE")
    return subprocess.run([sys.executable, str(script)], check=False, capture_output=True, text=True, timeout=180,
                          env=env, cwd=tmp_path)
