"""lens_tolerance: the real lens differs from its prescription (manufacturing tolerance): one air gap longer or
shorter (`gap`: the surface before it, `gap_mm`), or one element decentred (`element`: its index among the lens's
glass groups, a cemented group moving as one; `decentre_x_mm`, `decentre_y_mm` in lens coordinates).

Traced through the real prescription (`training.optics.tolerance`, torch), the perturbation moves the lens's best-focus
surface: a gap changes the field curvature, a decentre tilts the focal surface and makes it asymmetric. The
effect renders that change as a per-field sensor shift (the camera focuses on the centre, so the axis term is
removed), with the nominal lens's PSFs at the shifted focus: the change of field curvature, not the change of
the PSFs' shape (the coma of a decentred element), is modelled.

The changes come from a sensitivity table, linear per unit perturbation on a grid of field positions and focus
distances: `tolerance_<key>.json` next to the lens's PSF surrogate (made with torch by
`scripts/lens_tolerance_table.py`; then the effect renders without torch, as `chromatic` does with its
per-wavelength surrogates), a given `table` file, or, with torch installed and no table, traced on first use.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from aat_deploy.render.effects import Effect, SimContext, register, torch_extension

_TABLES: dict = {}  # (path, mtime) -> table


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


@register
class LensTolerance(Effect):
    name = "lens_tolerance"
    description = ("the lens differs from its prescription: one air gap changed (gap = surface before it, gap_mm) "
                   "or one element decentred (element = glass group index, decentre_x_mm / decentre_y_mm), traced "
                   "through the prescription: field curvature changes and becomes asymmetric. table: 'auto' = "
                   "tolerance_<key>.json next to the lens's surrogate, else traced (torch); or a table file")
    order = 25
    defaults = {"gap": -1.0, "gap_mm": 0.0, "element": -1.0, "decentre_x_mm": 0.0, "decentre_y_mm": 0.0,
                "table": "auto"}

    def __init__(self, **params):
        super().__init__(**params)
        t = str(self.params["table"])
        if t != "auto" and not Path(t).is_file():
            raise ValueError(f"effect 'lens_tolerance': table {t}: no such file (table=auto|FILE)")

    @staticmethod
    def choices(lens) -> list[dict]:
        """Every single perturbation the lens allows, as settings with the amount left to fit: {"gap": i} per air
        gap and {"element": k} per glass group (decentred in x and y)."""
        return [{"gap": float(g)} for g in air_gaps(lens)] + [{"element": float(k)} for k in range(len(elements(lens)))]

    def perturbations(self) -> list[tuple[str, int, str, float]]:
        """(kind, index, axis, amount mm) of the non-zero perturbations."""
        p = self.params
        out = []
        if int(p["gap"]) >= 0 and float(p["gap_mm"]) != 0:
            out.append(("gap", int(p["gap"]), "", float(p["gap_mm"])))
        if int(p["element"]) >= 0:
            for axis, k in (("x", "decentre_x_mm"), ("y", "decentre_y_mm")):
                if float(p[k]) != 0:
                    out.append(("decentre", int(p["element"]), axis, float(p[k])))
        return out

    def _table_path(self, ctx: SimContext | None) -> Path | None:
        t = str(self.params["table"])
        if t != "auto":
            return Path(t)
        path = getattr(ctx.lens_source, "path", None) if ctx is not None else None
        if path is None:
            return None
        cand = Path(path).parent / table_name(ctx.lens)
        return cand if cand.is_file() else None

    @property
    def needs_torch(self) -> str:
        return "" if str(self.params["table"]) != "auto" or not self.perturbations() else \
            "it traces the perturbed lens (no tolerance table next to the lens's surrogate)"

    def torch_reason(self, ctx: SimContext) -> str:
        if not self.perturbations() or self._table_path(ctx) is not None:
            return ""
        return (f"it traces the perturbed lens (no {table_name(ctx.lens)} next to the lens's surrogate; "
                "scripts/lens_tolerance_table.py makes one)")

    def maps(self, ctx: SimContext) -> list[tuple[float, np.ndarray, list, list, list]]:
        """Per perturbation: (amount / unit, dz (F, ny, nx) per unit, diopters, field x, field y)."""
        path = self._table_path(ctx)
        out = []
        for kind, idx, axis, amount in self.perturbations():
            if path is not None:
                t = load_table(path, ctx.lens)
                match = [q for q in t["perturbations"] if q["kind"] == kind and
                         (q.get("surface") == idx if kind == "gap" else q.get("element") == idx and q["axis"] == axis)]
                if not match:
                    raise ValueError(f"effect 'lens_tolerance': {path} has no {kind} {idx}{axis} (air gaps after "
                                     f"surfaces {[q['surface'] for q in t['perturbations'] if q['kind'] == 'gap']})")
                out.append((amount / t["unit_mm"], np.asarray(match[0]["dz_mm"]), t["diopters"], t["field_x"],
                            t["field_y"]))
            else:
                out.append(_traced(ctx.lens, kind, idx, axis, amount))
        return out

    def sensor_shift_mm(self, ctx: SimContext) -> Callable | None:
        maps = self.maps(ctx)
        if not maps:
            return None

        def shift(x, y, focus_m):
            # the focal surface moving towards the lens is the sensor moving away from it
            return -sum(a * interpolate(dz, d, fx, fy, x, y, focus_m) for a, dz, d, fx, fy in maps)

        return shift


def _traced(lens, kind: str, idx: int, axis: str, amount: float):
    """The perturbation's map traced by the training package (no table; `training.optics.tolerance`, the
    declared extension `tolerance_tracer`: torch): (amount / unit, dz per unit, diopters, field x, field y)."""
    tracer = torch_extension("tolerance_tracer", f"effect 'lens_tolerance' without a table ({kind} {idx}{axis})")
    return tracer(lens, kind, idx, axis, amount)
