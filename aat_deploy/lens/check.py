"""Is a lens sound enough to trace? `validate` names the first problem; `LensFileError` is what every lens-file
reader raises: one line with the file name (and line or surface) and the problem.

Plain lens data only (no optics): the readers in `aat_deploy.lens.io` and the chain's lens check use it.
"""

from __future__ import annotations

import math

from ..errors import AatError
from .materials import UnknownMaterialError, parse_material
from .schema import Lens


class LensFileError(AatError):
    """A lens file that cannot be read; the message names the file and the problem."""


def lens_file_error(path, msg: str) -> LensFileError:
    return LensFileError(f"{path}: {msg}")


def validate(lens: Lens, path="<lens>") -> None:
    """Check a lens for problems that would make tracing meaningless; raise LensFileError naming them."""
    n = len(lens.surfaces)
    if not 0 <= lens.stop_index < n:
        raise lens_file_error(path, f"stop_index {lens.stop_index} outside 0..{n - 1}")
    for i, s in enumerate(lens.surfaces):
        if not (s.semi_diameter_mm > 0 and math.isfinite(s.semi_diameter_mm)):
            raise lens_file_error(path, f"surface {i}: semi-diameter must be positive, got {s.semi_diameter_mm}")
        if not math.isfinite(s.thickness_mm):
            raise lens_file_error(path, f"surface {i}: thickness must be finite, got {s.thickness_mm}")
        if s.kind == "ideal" and not (s.focal_length_mm and math.isfinite(s.focal_length_mm)):
            raise lens_file_error(path, f"surface {i}: ideal surface needs a finite non-zero focal_length_mm")
        try:
            parse_material(s.material)
        except UnknownMaterialError as e:
            raise lens_file_error(path, f"surface {i}: {e}") from None
    sen = lens.sensor
    if min(sen.width_mm, sen.height_mm) <= 0 or min(sen.width_px, sen.height_px) <= 0:
        raise lens_file_error(path, "sensor size and resolution must be positive")
    px_w, px_h = sen.width_mm / sen.width_px, sen.height_mm / sen.height_px
    if abs(px_w - px_h) > 0.005 * px_w:
        raise lens_file_error(path, f"sensor pixels are not square ({px_w * 1e3:.2f} x {px_h * 1e3:.2f} um)")
