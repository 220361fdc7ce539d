"""Ground-truth depth of a capture folder: finding it, reading it, checking it, and bringing it to the model's
sensor geometry exactly as the frames are brought there.

Files (docs/contracts.md, "Ground truth"), first found wins:
- `gt.json` = {"depth": "gt_scan.tif", "scale_to_m": 1.0, "mask": "gt_mask.png"} (every key optional): names the
  depth file, the factor that turns its values into metres, and a validity mask;
- `gt_depth_m.npy`, `gt_depth_m.pfm`, `gt_depth_m.tif` / `.tiff`: float depth in metres (scale 1);
- `gt_depth_mm.png`: 16-bit depth in millimetres (scale 0.001).
`gt_mask.png` (non-zero = valid) is used when present and gt.json names no other mask.
Depth is in metres from the sensor plane along the optical axis; 0, negative, NaN and inf are invalid.

Resampling: the frames are centre-cropped to the model's sensor aspect and resized to `aat.sensor_px`
(`aat_deploy.infer.geometry.fit_to_sensor`). The ground truth covers the frames' field of view (same aspect ratio,
any size); each output pixel takes the ground-truth sample under its centre (nearest, never blended).
"""

from __future__ import annotations

import math
import tokenize
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..capture.containers import container_of
from ..capture.imagefile import FRAME_EXTENSIONS, check_pixels, claimed_size
from ..errors import CaptureError
from ..io.files import check_inside, file_kind, load_json, member_path, read_input_bytes

GT_JSON = "gt.json"
DEFAULT_FILES = (("gt_depth_m.npy", 1.0), ("gt_depth_m.pfm", 1.0), ("gt_depth_m.tif", 1.0),
                 ("gt_depth_m.tiff", 1.0), ("gt_depth_mm.png", 0.001))
DEFAULT_MASK = "gt_mask.png"
UNITS_FACTOR = 10.0  # median depth beyond this factor outside the model's focus range = wrong units
ASPECT_TOLERANCE = 0.01
FEW_VALID = 0.05
# what reading a damaged depth file raises: np.load parses a .npy header with Python's tokenizer (SyntaxError,
# TokenError) and gives EOFError on an empty file; OpenCV raises cv2.error
READ_ERRORS = (OSError, ValueError, EOFError, SyntaxError, tokenize.TokenError, cv2.error)


class GTError(CaptureError):
    """Ground truth that cannot be used (unreadable, wrong size, no valid pixel, wrong units)."""


@dataclass
class GTSource:
    """Where a capture's ground truth is: the depth file, its scale to metres and an optional mask file."""

    depth: Path
    scale_to_m: float
    mask: Path | None = None
    aif: Path | None = None

    def describe(self) -> dict:
        return {"depth": self.depth.name, "scale_to_m": self.scale_to_m,
                "mask": self.mask.name if self.mask else None, "aif": self.aif.name if self.aif else None}


@dataclass
class GroundTruth:
    """depth_m (H, W) float32 metres from the sensor plane, NaN = invalid (mask applied); source; notes."""

    depth_m: np.ndarray
    source: GTSource
    warnings: list[str] = field(default_factory=list)

    @property
    def valid_fraction(self) -> float:
        return float(np.isfinite(self.depth_m).mean())


def has_ground_truth(folder: Path) -> bool:
    """True if the folder holds a gt.json or one of the default depth files."""
    return (folder / GT_JSON).is_file() or any((folder / n).is_file() for n, _ in DEFAULT_FILES)


def find_gt(folder: str | Path, allow_outside_links: bool = False) -> GTSource | None:
    """The capture folder's ground-truth files (see the module doc), or None. GTError for a bad gt.json, or for a
    ground-truth file that is a link leading out of the folder (unless allow_outside_links)."""
    folder = Path(folder)
    src = _find_gt(folder, allow_outside_links)
    if src is not None:
        for p in (src.depth, src.mask, src.aif):
            if p is not None:
                check_inside(folder, p, allow_outside_links, GTError)
    return src


def _find_gt(folder: Path, allow_outside_links: bool) -> GTSource | None:
    aif = folder / "gt_aif.png"
    aif = aif if aif.is_file() else None
    spec: dict = {}
    jpath = folder / GT_JSON
    if jpath.is_file():
        check_inside(folder, jpath, allow_outside_links, GTError)
        spec = load_json(jpath, GTError)
        if not isinstance(spec, dict) or set(spec) - {"depth", "scale_to_m", "mask", "note"}:
            raise GTError(f'{jpath}: expected {{"depth": FILE, "scale_to_m": S, "mask": FILE}} (all optional), '
                          f"got {spec if not isinstance(spec, dict) else sorted(spec)}")
    depth, scale = None, None
    if "depth" in spec:
        name = spec["depth"]
        depth = member_path(folder, name)
        if depth is None:
            raise GTError(f"{jpath}: depth file {name!r} is not inside the capture folder (relative names only, "
                          "no '..')")
        if (kind := file_kind(depth)) is not None:
            raise GTError(f"{jpath}: depth file {name!r} " + ("does not exist" if kind == "missing" else f"is {kind}"))
        if depth.suffix.lower() in FRAME_EXTENSIONS and not depth.name.startswith("gt_"):
            raise GTError(f"{jpath}: name the depth file gt_*{depth.suffix} so it is not taken for a frame")
        scale = 0.001 if depth.suffix.lower() == ".png" else 1.0
    else:
        for name, s in DEFAULT_FILES:
            if (folder / name).is_file():
                depth, scale = folder / name, s
                break
    if depth is None:
        if spec:
            raise GTError(f"{jpath}: names no depth file and none of {', '.join(n for n, _ in DEFAULT_FILES)} exists")
        return None
    if "scale_to_m" in spec:
        s = spec["scale_to_m"]
        try:
            ok = isinstance(s, (int, float)) and not isinstance(s, bool) and math.isfinite(float(s)) and s > 0
        except OverflowError:
            ok = False
        if not ok:
            raise GTError(f"{jpath}: scale_to_m must be a positive number, got {str(s)[:40]!r}")
        scale = float(s)
    mask = None
    if "mask" in spec:
        mask = member_path(folder, spec["mask"])
        if mask is None:
            raise GTError(f"{jpath}: mask file {str(spec['mask'])[:80]!r} is not inside the capture folder "
                          "(relative names only, no '..')")
        if file_kind(mask) is not None:
            raise GTError(f"{jpath}: mask file {spec['mask']!r} does not exist or is not a file")
    elif (folder / DEFAULT_MASK).is_file():
        mask = folder / DEFAULT_MASK
    return GTSource(depth, scale, mask, aif)


def read_pfm(path: Path) -> np.ndarray:
    """A greyscale PFM ("Pf") as float32 (H, W), top row first (PFM stores the bottom row first)."""
    with open(path, "rb") as f:
        kind = f.readline().strip()
        if kind not in (b"Pf", b"PF"):
            raise GTError(f"{path}: not a PFM file (header {kind[:8]!r})")
        dims = f.readline().split()
        if len(dims) != 2:
            raise GTError(f"{path}: not a PFM file (size line {b' '.join(dims)[:20]!r})")
        scale = float(f.readline().strip())
        w, h = int(dims[0]), int(dims[1])
        if w <= 0 or h <= 0 or not math.isfinite(scale) or scale == 0:
            raise GTError(f"{path}: not a PFM file (size {w}x{h}, scale {scale})")
        ch = 3 if kind == b"PF" else 1
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    if data.size != w * h * ch:
        raise GTError(f"{path}: truncated PFM ({data.size} values, expected {w * h * ch})")
    img = data.reshape(h, w, ch)[::-1, :, 0]
    if ch == 3:
        raise GTError(f"{path}: colour PFM; depth needs one channel (Pf)")
    return np.ascontiguousarray(img, dtype=np.float32)


def _npy_checked(path: Path, limit: float | None) -> np.ndarray:
    """np.load after its header's shape is checked against the pixel limit and the file's length (a header can
    claim 200000 x 200000 and make numpy allocate that before reading a byte)."""
    with open(path, "rb") as f:
        version = np.lib.format.read_magic(f)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read_header(f)
        data_at = f.tell()
    if len(shape) >= 2:
        check_pixels(path, (int(np.prod(shape[1:], dtype=np.float64)), int(shape[0])), limit, GTError)
    n = int(np.prod(shape, dtype=np.float64))
    if not dtype.hasobject and path.stat().st_size < data_at + n * dtype.itemsize:
        raise GTError(f"{path}: truncated .npy (its header claims {' x '.join(map(str, shape))} {dtype} values)")
    return np.load(path, allow_pickle=False)


def _image_checked(path: Path, limit: float | None) -> np.ndarray:
    """A PNG or TIFF depth/mask image (any bit depth, unchanged), its header size checked before decoding."""
    try:
        buf = read_input_bytes(path)
    except CaptureError as e:
        raise GTError(str(e)) from None
    c = container_of(buf)
    kind = {"png": "png", "tiff": "tiff", "bigtiff": "tiff"}.get(c)
    if kind is None:
        raise GTError(f"{path}: not a PNG or TIFF image (content: {c})")
    size = claimed_size(buf, kind)
    if size is None:
        raise GTError(f"{path}: damaged {kind.upper()} header (no image size in it)")
    check_pixels(path, size, limit, GTError)
    arr = cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_UNCHANGED)
    if arr is None:
        raise GTError(f"{path}: not a readable image")
    return arr


def read_depth_file(path: Path, max_megapixels: float | None = None) -> np.ndarray:
    """Raw values (H, W) float64 of a depth file (.npy, .pfm, .tif/.tiff, .png). GTError naming it otherwise,
    including a header claiming more pixels than the limit (aat_deploy.capture.imagefile), before decoding."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            arr = _npy_checked(path, max_megapixels)
        elif suffix == ".pfm":
            arr = read_pfm(path)
        elif suffix in (".tif", ".tiff", ".png"):
            arr = _image_checked(path, max_megapixels)
            if suffix == ".png" and arr.dtype != np.uint16:
                raise GTError(f"{path}: a depth PNG must be 16-bit (millimetres), this one is {arr.dtype}")
        else:
            raise GTError(f"{path}: unknown depth format {suffix!r} (expected .npy, .pfm, .tif, .tiff or .png)")
    except GTError:
        raise
    except READ_ERRORS as e:
        raise GTError(f"{path}: unreadable ({str(e).splitlines()[0][:120] if str(e) else type(e).__name__})") from None
    arr = np.asarray(arr)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim != 2:
        raise GTError(f"{path}: depth must be one channel (H, W), got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise GTError(f"{path}: depth must be numbers, got {arr.dtype}")
    return arr.astype(np.float64)


def load_ground_truth(src: GTSource, max_megapixels: float | None = None) -> GroundTruth:
    """Read the depth (× scale_to_m) and mask; invalid pixels become NaN. GTError if nothing is valid, or for a
    header claiming more pixels than the limit (aat_deploy.capture.imagefile)."""
    raw = read_depth_file(src.depth, max_megapixels)
    with np.errstate(invalid="ignore"):
        d = raw * src.scale_to_m
        d = np.where(np.isfinite(d) & (d > 0), d, np.nan).astype(np.float32)
    warnings = []
    if src.mask is not None:
        m = _image_checked(src.mask, max_megapixels)
        if m.ndim == 3:
            m = m.max(axis=2)
        if m.shape != d.shape:
            raise GTError(f"{src.mask}: mask is {m.shape[1]}x{m.shape[0]} px, the depth {src.depth.name} is "
                          f"{d.shape[1]}x{d.shape[0]}")
        d[m == 0] = np.nan
    n_ok = int(np.isfinite(d).sum())
    if n_ok == 0:
        why = "all 0, negative, NaN or inf" + (f", or masked out by {src.mask.name}" if src.mask else "")
        raise GTError(f"{src.depth}: no valid ground-truth pixel ({why})")
    frac = n_ok / d.size
    if frac < FEW_VALID:
        warnings.append(f"{src.depth}: only {100 * frac:.1f} % of the ground-truth pixels are valid")
    return GroundTruth(d, src, warnings)


def units_problem(median_m: float, focus_range_m: tuple[float, float], path: Path | str, scale: float) -> str | None:
    """Why a ground truth with this median valid depth (metres) is in the wrong units for a model focused over
    focus_range_m, or None: more than UNITS_FACTOR outside the range is usually millimetres in a metres file or
    metres in a mm PNG. The message names the file and the scale_to_m to state."""
    near, far = focus_range_m
    med = median_m
    if med > UNITS_FACTOR * far:
        guess = 1000 if med > 100 * far else 100 if med > 30 * far else 10
        unit = {1000: "millimetres", 100: "centimetres", 10: "decimetres"}[guess]
        return (f"{path}: median ground-truth depth {med:.4g} m is {med / far:.0f}x the model's far focus "
                f"{far:g} m: wrong units? ({unit} read with scale_to_m {scale:g}; if so state "
                f'"scale_to_m": {scale / guess:g} in {GT_JSON})')
    if med < near / UNITS_FACTOR:
        return (f"{path}: median ground-truth depth {med:.4g} m is below a tenth of the model's near focus "
                f"{near:g} m: wrong units? (values read with scale_to_m {scale:g}; state the right "
                f'"scale_to_m" in {GT_JSON})')
    return None


def check_units(gt: GroundTruth, focus_range_m: tuple[float, float]) -> None:
    """GTError if the ground truth's median valid depth says wrong units (see units_problem)."""
    why = units_problem(float(np.nanmedian(gt.depth_m)), focus_range_m, gt.source.depth, gt.source.scale_to_m)
    if why is not None:
        raise GTError(why)


def sensor_sample_index(n_out: int, crop0: int, crop_len: int, n_frame: int, n_gt: int) -> np.ndarray:
    """Indices (n_out,) into a ground-truth axis of n_gt samples for the output pixels of one axis.

    Output pixel j covers frame pixels crop0 + [j, j+1)·crop_len/n_out; its centre, in frame pixels, is scaled
    to the ground truth's sampling (n_gt/n_frame) and floored: the sample whose cell holds the centre."""
    centre = crop0 + (np.arange(n_out) + 0.5) * (crop_len / n_out)
    idx = np.floor(centre * (n_gt / n_frame)).astype(np.int64)
    return np.clip(idx, 0, n_gt - 1)


def check_aspect(gt_hw: tuple[int, int], frame_wh: tuple[int, int], path: Path | str = "ground truth") -> None:
    """GTError (naming `path`) unless a ground truth of (H, W) covers frames of frame_wh = (W, H) px: the same
    aspect ratio within ASPECT_TOLERANCE (any size)."""
    fw, fh = frame_wh
    gh, gw = gt_hw
    if abs((gw / gh) / (fw / fh) - 1) > ASPECT_TOLERANCE:
        raise GTError(f"{path}: ground truth is {gw}x{gh} px, the frames are {fw}x{fh} px: a different aspect "
                      "ratio (it must cover the frames' field of view)")


def to_sensor(gt: np.ndarray, frame_wh: tuple[int, int], crop_xywh: tuple[int, int, int, int],
              out_wh: tuple[int, int], path: Path | str = "ground truth") -> np.ndarray:
    """Bring a ground-truth map (Hg, Wg) covering the frames' field of view to the model's sensor (h, w).

    frame_wh: (W, H) of the frames; crop_xywh: the frames' centre crop (frame pixels, from fit_to_sensor);
    out_wh: (w, h) = aat.sensor_px. Nearest sampling: no value is ever blended with a neighbour.
    GTError (naming `path`) if the ground truth's aspect ratio is not the frames'."""
    check_aspect(gt.shape[:2], frame_wh, path)
    fw, fh = frame_wh
    gh, gw = gt.shape[:2]
    x0, y0, cw, ch = crop_xywh
    ow, oh = out_wh
    cols = sensor_sample_index(ow, x0, cw, fw, gw)
    rows = sensor_sample_index(oh, y0, ch, fh, gh)
    return np.ascontiguousarray(gt[rows[:, None], cols[None, :]])
