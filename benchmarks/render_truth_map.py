"""A render-consistent truth map: `render_truth`'s points (where the runtime's measure peaks in the benchmark's own
renders of flat planes, per field-radius annulus) as a map on their own grid (issue 33; docs/calibration.md,
"A render-consistent truth map").

    python -m benchmarks.render_truth_map results/render_truth_b64_17p.json \
        --out results/render_truth_map_cellphone.json [--force]

Format `aat-render-truth-map-v1` (JSON; every diopter is 1/m with distances from the sensor plane):
- `radius`: the annuli's mid radii (R,), normalised field radius (0 centre, 1 sensor corner), ascending;
  `radius_edges` (R + 1,);
- `annuli`: R entries, each `{"r", "frame_d", "object_d", "se_object_d", "se_frame_d", "n_draws"}`: the points
  of that annulus, `frame_d` (the frame focus where the measure peaked for the plane, ascending, at least 2) and
  `object_d` (the plane, 1/Z): in a frame focused at frame_d, at radius r, the object object_d is in focus;
- `extrapolation`: `base_map` (a best-focus map, repository-relative path) and its `sha256`: where no point holds
  the truth, it is the base map plus the render's correction held (below);
- `source`: the probe's setup, draws, result file and the command.

Evaluation (`RenderTruthMap.object_d(radius, frame_d)`): per annulus, object_d interpolated linearly over frame_d
between its points (no resampling); between annuli linear in r; below the first annulus's mid radius the first
annulus. Outside an annulus's frame range the truth is the base map at (r_k, F) plus the correction (the points'
object minus the base map) at the nearest end point; beyond the last annulus's mid radius, the base map at (r, F)
plus the last annulus's correction at F. `measured(radius, frame_d)` is False there (extrapolated).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks import ROOT

FORMAT = "aat-render-truth-map-v1"
UNITS = ("radius: normalised field radius (0 centre, 1 sensor corner), as lenses/best_focus/; diopters: 1/m, "
         "distances from the sensor plane; frame_d: the frame's focus (the renderer's focus setting), object_d: "
         "the plane in best focus (where the runtime's focus measure peaks)")


class TruthMapError(ValueError):
    """A render-truth map is malformed (message: one line)."""


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def build(probe: dict, probe_path: str, base_map: str, command: str) -> dict:
    """The map from a `render_truth` result (its rows: object_d, r, ok, peak_frame_d, se_*): per annulus the ok
    points sorted by peak frame (a point whose frame equals another's within 1e-6 D is dropped)."""
    rows = [q for q in probe["rows"] if q["ok"] and q["peak_frame_d"] is not None]
    edges = [float(v) for v in probe["setup"]["r_edges"]]
    mids = [0.5 * (a + b) for a, b in zip(edges[:-1], edges[1:])]
    annuli = []
    for r in mids:
        qs = sorted((q for q in rows if abs(q["r"] - r) < 1e-9), key=lambda q: q["peak_frame_d"])
        keep = []
        for q in qs:
            if keep and q["peak_frame_d"] - keep[-1]["peak_frame_d"] < 1e-6:
                continue
            keep.append(q)
        annuli.append({"r": r, "frame_d": [round(q["peak_frame_d"], 6) for q in keep],
                       "object_d": [float(q["object_d"]) for q in keep],
                       "se_object_d": [q["se_object_d"] for q in keep],
                       "se_frame_d": [q["se_peak_frame_d"] for q in keep],
                       "n_draws": [int(q["n_draws"]) for q in keep]})
    base = ROOT / base_map
    out = {"format": FORMAT, "units": UNITS, "lens": probe["setup"]["lens"], "radius": mids, "radius_edges": edges,
           "annuli": annuli,
           "extrapolation": {"base_map": base_map, "sha256": _sha256(base),
                             "rule": "outside an annulus's frame range: the base map plus the correction at the "
                                     "nearest point; beyond the last annulus's mid radius: the base map plus the last "
                                     "annulus's correction at the frame"},
           "source": {"probe": "benchmarks.probes.render_truth", "result": probe_path, "setup": probe["setup"],
                      "setup_key": probe.get("setup_key"), "objects_d": probe.get("objects_d"),
                      "boot": probe.get("boot"), "command": command}}
    # the points' bootstrap SE (object D) by field radius, every point of the map (the probe's summary counts only
    # those in part a's range)
    bins = ((0.0, 0.33), (0.33, 0.66), (0.66, 0.84), (0.84, 0.95))
    se = {}
    for lo, hi in (*bins, (0.0, 0.95)):
        v = np.array([x for a in annuli if lo <= a["r"] < hi for x in a["se_object_d"] if x is not None], float)
        se[f"{lo:g}-{hi:g}"] = None if not v.size else {"points": int(v.size), "se_rms_d": float(np.sqrt(np.mean(
            v ** 2))), "se_max_d": float(v.max())}
    out["se_by_radius"] = se
    out["interpolation_check"] = interpolation_check(annuli, bins)
    validate(out, "built map")
    return out


def interpolation_check(annuli: list[dict], bins) -> dict:
    """How well the map's linear reading interpolates: each interior point predicted without it, from its two
    neighbours in frame focus (same annulus: twice the spacing) and from the neighbouring annuli at its frame (twice
    the radial spacing), RMS and max of prediction minus point (object D) by field radius. For a smooth surface a
    chord's error grows as the spacing squared, so the map's own (at half that spacing) is about a quarter of the
    part not due to the points' SE (which enters about 1.2 x)."""
    f_res, r_res = {b: [] for b in bins}, {b: [] for b in bins}
    for k, a in enumerate(annuli):
        f, o = np.asarray(a["frame_d"]), np.asarray(a["object_d"])
        b = next((b for b in bins if b[0] <= a["r"] < b[1]), None)
        if b is None:
            continue
        for j in range(1, len(f) - 1):
            f_res[b].append(o[j - 1] + (o[j + 1] - o[j - 1]) * (f[j] - f[j - 1]) / (f[j + 1] - f[j - 1]) - o[j])
        if 0 < k < len(annuli) - 1:
            lo, hi = annuli[k - 1], annuli[k + 1]
            t = (a["r"] - lo["r"]) / (hi["r"] - lo["r"])
            for fj, oj in zip(f, o):
                if lo["frame_d"][0] <= fj <= lo["frame_d"][-1] and hi["frame_d"][0] <= fj <= hi["frame_d"][-1]:
                    p = (1 - t) * np.interp(fj, lo["frame_d"], lo["object_d"]) + t * np.interp(fj, hi["frame_d"],
                                                                                            hi["object_d"])
                    r_res[b].append(p - oj)

    def agg(v):
        v = np.asarray(v, float)
        return None if not v.size else {"points": int(v.size), "rms_d": float(np.sqrt(np.mean(v ** 2))),
                                         "max_d": float(np.abs(v).max())}

    return {"what": "leave-one-out: each interior point predicted from its neighbours at twice the spacing "
                    "(prediction minus point, object D)",
            "along_focus": {f"{lo:g}-{hi:g}": agg(f_res[(lo, hi)]) for lo, hi in bins},
            "along_radius": {f"{lo:g}-{hi:g}": agg(r_res[(lo, hi)]) for lo, hi in bins}}


def validate(d, source: str) -> None:
    """TruthMapError (one line naming `source`) unless d is a well-formed `aat-render-truth-map-v1`."""
    def bad(why):
        raise TruthMapError(f"{source}: not a valid {FORMAT} ({why})")

    if not isinstance(d, dict) or d.get("format") != FORMAT:
        bad(f"format {d.get('format') if isinstance(d, dict) else type(d).__name__!r}")
    for k in ("radius", "annuli", "extrapolation"):
        if k not in d:
            bad(f"no {k!r}")
    try:
        r = np.asarray(d["radius"], np.float64)
    except (TypeError, ValueError):
        bad("radius not numbers")
    if r.ndim != 1 or r.size < 2 or not np.isfinite(r).all() or np.any(np.diff(r) <= 0) or r[0] < 0 or r[-1] > 1:
        bad("radius must be at least 2 ascending values in [0, 1]")
    if not isinstance(d["annuli"], list) or len(d["annuli"]) != r.size:
        bad(f"annuli must be a list of {r.size} entries, one per radius")
    for k, a in enumerate(d["annuli"]):
        try:
            f, o = np.asarray(a["frame_d"], np.float64), np.asarray(a["object_d"], np.float64)
        except (KeyError, TypeError, ValueError):
            bad(f"annulus {k}: frame_d and object_d must be lists of numbers")
        if f.ndim != 1 or f.shape != o.shape or f.size < 2:
            bad(f"annulus {k}: frame_d and object_d must be equal-length lists of at least 2")
        if not (np.isfinite(f).all() and np.isfinite(o).all()) or np.any(np.diff(f) <= 0) or np.any(o <= 0):
            bad(f"annulus {k}: frame_d must ascend, values be finite and object_d > 0")
    ex = d["extrapolation"]
    if not isinstance(ex, dict) or not isinstance(ex.get("base_map"), str):
        bad("extrapolation.base_map must name a best-focus map")


class RenderTruthMap:
    """A loaded `aat-render-truth-map-v1` (see the module's docstring) with its base map for extrapolation."""

    def __init__(self, d: dict, source: str = "render-truth map"):
        from aat_deploy.focus.bestfocus import BestFocusError, load_json

        validate(d, source)
        self.source = source
        self.radius = np.asarray(d["radius"], np.float64)
        self.frame = [np.asarray(a["frame_d"], np.float64) for a in d["annuli"]]
        self.object = [np.asarray(a["object_d"], np.float64) for a in d["annuli"]]
        base = ROOT / d["extrapolation"]["base_map"]
        try:
            self.base = load_json(base)
        except (BestFocusError, OSError) as e:
            raise TruthMapError(f"{source}: its base map: {str(e).splitlines()[0]}") from None
        sha = d["extrapolation"].get("sha256")
        if sha and _sha256(base) != sha:
            raise TruthMapError(f"{source}: its base map {d['extrapolation']['base_map']} changed since the map was "
                                "made (sha256 differs)")
        self.meta = {k: d.get(k) for k in ("lens", "source", "extrapolation")}

    def _base(self, radius: np.ndarray, frame_d: np.ndarray) -> np.ndarray:
        """The base map's in-focus object (D) at per-point radius and frame focus (N,), bilinear as `Rig.truth`."""
        b = self.base
        shift = b.shift_diopters(calibrated=True)  # (Rb, F)
        rr = b.radius ** 2
        r2 = np.clip(radius, 0.0, b.radius[-1]) ** 2
        i = np.clip(np.searchsorted(rr, r2) - 1, 0, len(rr) - 2)
        t = np.clip((r2 - rr[i]) / (rr[i + 1] - rr[i]), 0, 1)
        out = np.empty(radius.shape)
        for j in np.unique(i):  # only the base radii the points need
            m = i == j
            lo = np.interp(frame_d[m], b.focus_diopters, shift[j])
            hi = np.interp(frame_d[m], b.focus_diopters, shift[j + 1])
            out[m] = lo * (1 - t[m]) + hi * t[m]
        return out + frame_d

    def _annulus(self, k: int, frame_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Annulus k's truth at frame_d (N,) and whether it is between its points."""
        f, o = self.frame[k], self.object[k]
        val = np.interp(frame_d, f, o)
        inside = (frame_d >= f[0]) & (frame_d <= f[-1])
        if not inside.all():
            rk = np.full(frame_d.shape, self.radius[k])
            for end, m in ((0, frame_d < f[0]), (-1, frame_d > f[-1])):
                if m.any():
                    corr = o[end] - self._base(rk[:1], f[[end]])[0]
                    val[m] = self._base(rk[m], frame_d[m]) + corr
        return val, inside

    def evaluate(self, radius, frame_d) -> tuple[np.ndarray, np.ndarray]:
        """(object_d, measured) at points (N,): the in-focus object (D) at field radius `radius` in a frame focused
        at `frame_d` (D), and False where it is extrapolated (no points bracket it)."""
        radius = np.asarray(radius, np.float64).ravel()
        frame_d = np.asarray(frame_d, np.float64).ravel()
        if radius.shape != frame_d.shape:
            radius, frame_d = np.broadcast_arrays(radius, frame_d)
            radius, frame_d = radius.ravel(), frame_d.ravel()
        out = np.empty(radius.shape)
        meas = np.zeros(radius.shape, bool)
        R = self.radius
        k = np.clip(np.searchsorted(R, radius) - 1, 0, R.size - 2)
        for j in np.unique(k):
            m = k == j
            a, ia = self._annulus(j, frame_d[m])
            b, ib = self._annulus(j + 1, frame_d[m])
            t = np.clip((radius[m] - R[j]) / (R[j + 1] - R[j]), 0, 1)
            out[m] = a * (1 - t) + b * t
            meas[m] = (ia | (t >= 1)) & (ib | (t <= 0))
        far = radius > R[-1]
        if far.any():  # beyond the last annulus: its correction held along the radius
            last, _ = self._annulus(R.size - 1, frame_d[far])
            corr = last - self._base(np.full(far.sum(), R[-1]), frame_d[far])
            out[far] = self._base(radius[far], frame_d[far]) + corr
            meas[far] = False
        return out, meas

    def object_d(self, radius, frame_d) -> np.ndarray:
        return self.evaluate(radius, frame_d)[0]


def load(path: str | Path) -> RenderTruthMap:
    """TruthMapError (one line) for a missing, unreadable or malformed file; a relative path is the repository's."""
    name, path = str(path), (Path(path) if Path(path).is_absolute() else ROOT / path)
    try:
        d = json.loads(path.read_text())
    except OSError as e:
        raise TruthMapError(f"{name}: cannot read ({e.strerror or e})") from None
    except ValueError as e:
        raise TruthMapError(f"{name}: not JSON ({str(e).splitlines()[0]})") from None
    return RenderTruthMap(d, name)


def load_or_exit(path: str | Path, prog: str) -> RenderTruthMap:
    """`load`, or SystemExit with one line naming the program and its --truth (the probes' check before any render)."""
    try:
        return load(path)
    except TruthMapError as e:
        raise SystemExit(f"{prog}: --truth {e}") from None


def main(argv=None) -> int:
    from aat_deploy.io.atomic import write_text_atomic

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("probe", help="a benchmarks.probes.render_truth result (JSON)")
    ap.add_argument("--base-map", default=None, help="the best-focus map for extrapolation (repository-relative; "
                    "default the probe's setup's fmap)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--force", action="store_true", help="overwrite an existing --out")
    a = ap.parse_args(argv)
    if Path(a.out).exists() and not a.force:
        ap.error(f"{a.out}: exists (give --force to overwrite)")
    try:
        probe = json.loads(Path(a.probe).read_text())
    except OSError as e:
        ap.error(f"{a.probe}: cannot read ({e.strerror or e})")
    except ValueError as e:
        ap.error(f"{a.probe}: not JSON ({str(e).splitlines()[0]})")
    if not (isinstance(probe, dict) and isinstance(probe.get("rows"), list) and isinstance(probe.get("setup"), dict)
            and "r_edges" in probe["setup"] and "lens" in probe["setup"]):
        ap.error(f"{a.probe}: not a benchmarks.probes.render_truth result (no rows, or no setup with r_edges and lens)")
    base = a.base_map or probe["setup"].get("fmap")
    if not base or not (ROOT / base).is_file():
        ap.error(f"{a.probe}: no base map {base!r} in the repository (give --base-map)")
    cmd = "python -m benchmarks.render_truth_map " + " ".join(argv if argv is not None else sys.argv[1:])
    try:
        out = build(probe, a.probe, base, cmd)
    except TruthMapError as e:
        raise SystemExit(str(e)) from None
    except (KeyError, TypeError, ValueError) as e:
        raise SystemExit(f"{a.probe}: a row is not a render_truth point ({type(e).__name__}: {e})") from None
    write_text_atomic(a.out, json.dumps(out, indent=1))
    n = [len(x["frame_d"]) for x in out["annuli"]]
    print(f"{a.out}: {len(n)} annuli, {sum(n)} points ({min(n)}-{max(n)} per annulus); SE (object D) by radius: "
          + "; ".join(f"{k} {v['se_rms_d']:.4f} RMS, {v['se_max_d']:.4f} max ({v['points']})"
                      for k, v in out["se_by_radius"].items() if v))
    for k in ("along_focus", "along_radius"):
        print(f"leave-one-out {k.replace('_', ' ')} (twice the spacing), RMS / max by radius: " + "; ".join(
            f"{b} {v['rms_d']:.4f} / {v['max_d']:.3f}" for b, v in out["interpolation_check"][k].items() if v))
    return 0


if __name__ == "__main__":
    sys.exit(main())
