"""Lens-tolerance sensitivity tables, torch-free: which air gaps and elements a prescription has, the key that
names a table (`tolerance_<key>.json`, made by `scripts/lens_tolerance_table.py` through
`training.optics.tolerance`), reading a table, and interpolating its change of the best-focus surface (mm) over
field position and focus distance. The `lens_tolerance` effect renders with it; the tracer that fills it needs torch.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

_TABLES: dict = {}  # (path, mtime) -> table; (optics key, perturbation) -> traced map


def air_gaps(lens) -> list[int]:
    """Surface indices whose following thickness is an air gap inside the lens (not the back focus)."""
    return [i for i, s in enumerate(lens.surfaces[:-1]) if s.material == "air" and s.thickness_mm > 0]


def elements(lens) -> list[list[int]]:
    """Groups of consecutive surfaces with glass between them (a cemented group is one element): each group's
    surfaces from its front to its back."""
    out, cur = [], []
    for i, s in enumerate(lens.surfaces):
        if s.kind != "standard":
            continue
        if s.material != "air":
            cur.append(i)
        elif cur:
            out.append(cur + [i])
            cur = []
    return out


def optics_key(lens) -> str:
    """16 hex digits identifying the lens's optics and sensor size (not its pixels): a table serves any
    resolution of the same sensor."""
    d = lens.to_dict()
    key = {"surfaces": d["surfaces"], "stop": d["stop_index"], "wl": d["design_wavelength_nm"],
           "sensor_mm": [lens.sensor.width_mm, lens.sensor.height_mm]}
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def table_name(lens) -> str:
    return f"tolerance_{optics_key(lens)}.json"


def load_table(path: Path, lens) -> dict:
    """A sensitivity table (cached by path and mtime); ValueError naming the file if it is not this lens's."""
    path = Path(path)
    key = (str(path.resolve()), path.stat().st_mtime_ns)
    if key not in _TABLES:
        try:
            t = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: not a lens tolerance table ({e})") from None
        if t.get("format") != "aat-tolerance-v1":
            raise ValueError(f"{path}: not a lens tolerance table (format {t.get('format')!r})")
        _TABLES[key] = t
    t = _TABLES[key]
    if t["optics_key"] != optics_key(lens):
        raise ValueError(f"{path}: made for lens {t.get('lens')!r} ({t['optics_key']}), not {lens.name!r} "
                         f"({optics_key(lens)})")
    return t


def interpolate(dz: np.ndarray, diopters, fx, fy, x, y, focus_m) -> np.ndarray:
    """dz (F, ny, nx) on focus diopters (F,) x field fy (ny,) x fx (nx,): bilinear in the field, linear in
    diopters, clamped to the grid; at x, y (normalised field) and focus_m (m), broadcast."""
    x, y, f = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64),
                                  1.0 / np.asarray(focus_m, np.float64))
    fxa, fya, da = np.asarray(fx), np.asarray(fy), np.asarray(diopters)
    order = np.argsort(da)
    da, dz = da[order], np.asarray(dz)[order]

    def axis(v, g):
        u = np.interp(v, g, np.arange(len(g)))
        i = np.clip(np.floor(u).astype(np.intp), 0, max(len(g) - 2, 0))
        return i, np.minimum(i + 1, len(g) - 1), u - i

    i0, i1, ti = axis(x, fxa)
    j0, j1, tj = axis(y, fya)
    k0, k1, tk = axis(f, da)

    def at(k):
        return ((dz[k, j0, i0] * (1 - ti) + dz[k, j0, i1] * ti) * (1 - tj)
                + (dz[k, j1, i0] * (1 - ti) + dz[k, j1, i1] * ti) * tj)

    return at(k0) * (1 - tk) + at(k1) * tk
