"""Do the phone's chart tiles reach the frame's corners, and what do tiles that do buy? (issue 33, part a: the map
0.47 D off beyond the farthest tile, field radius 0.920, on 1.5 % of the pixels.)

    OMP_NUM_THREADS=1 python -m benchmarks.probes.corner_tiles [--variants nominal,copy,copy_s2026_0,...] \
        [--out results/corner_tiles.json]        # 4 min with bench_calibrate's cellphone_near sweeps cached (1.5 min
                                                 # of renders per variant otherwise)

On the development sweeps of bench_calibrate's `cellphone_near` (the nominal lens, the hand-chosen copy and the three
declared random copies of seed 2026; no held-out scene), per variant:

- **why the tiles stop at radius 0.920**: every sweep's tile codes beyond radius 0.84 and at the four corner tiles
  (is it the chart's placement, the tiles' selection, or the grid?);
- **the fit on two tile grids**: `aat-calibrate fit`'s centred grid (floor(640 / 27) x floor(480 / 27) tiles, a
  9-10 px border never measured) and the grid spread from edge to edge (`peaks.TileGrid(to_edges=True)`, the
  outermost tiles flush with the borders, reaching radius 0.953), and the edge grid without its tiles beyond the
  centred grid's farthest radius (what moving the grid alone does): part a's map error over the 10 "inside"
  settings, overall, within and beyond the farthest tile's radius, by field radius, with the fit's order and family;
- **the corner tiles' bias**: each counted tile beyond radius 0.92 against the truth's in-focus object for the frame
  of its measured peak (`phone_map_budget`'s), and **ideal tiles** (the same tiles peaking where the truth has
  their object in focus): what perfect tiles reaching radius 0.953 would buy, no measurement in it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks import RESULTS

VARIANTS = ("nominal", "copy", "copy_s2026_0", "copy_s2026_1", "copy_s2026_2")
CENTRED_RADIUS = 0.921  # just beyond the centred grid's farthest tile centre on the phone's 640 x 480 (0.9198)
BINS = ((0.0, 0.66), (0.66, 0.84), (0.84, 0.9), (0.9, CENTRED_RADIUS), (CENTRED_RADIUS, 1.0))


def setup_of(variant: str):
    """(rig, LensSetup, bench_calibrate variant) of a development variant of cellphone_near."""
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import elements
    from benchmarks import bench_calibrate as B
    from benchmarks import calibrate_copies as C

    base = B.LENSES["cellphone_near"]
    rig = B.Rig(base)
    if variant in ("nominal", "copy"):
        return rig, base, variant
    seed, k = (int(v) for v in variant.removeprefix("copy_s").split("_"))
    copy = C.draw_copy(base, len(elements(load_lens(B.ROOT / base.lens))), seed, k)
    setup = C.copy_setup(base, seed, copy)
    return rig.with_setup(setup), setup, "copy"


def drop_beyond(ms: list, radius: float, aspect: float) -> list:
    """The measured sweeps with their counted tiles beyond field radius `radius` not counted."""
    from aat_deploy.calibrate.format import field_radius_of

    out = []
    for m in ms:
        x, y = m.peaks.grid.field()
        why = m.peaks.why.astype("<U16")  # (codes of one letter or none would truncate "beyond")
        why[(field_radius_of(x, y, aspect) > radius) & (why == "")] = "beyond"
        out.append(dataclasses.replace(m, peaks=dataclasses.replace(m.peaks, why=why)))
    return out


def tile_codes(ms: list, aspect: float) -> list[dict]:
    from aat_deploy.calibrate.format import field_radius_of

    out = []
    for m in ms:
        pk = m.peaks
        x, y = pk.grid.field()
        r = field_radius_of(x, y, aspect)
        ny, nx = pk.why.shape
        far = r >= 0.84
        out.append({"sweep": str(m.sweep.path), "grid": list(pk.grid.shape),
                    "farthest_tile_radius": round(float(r.max()), 4),
                    "farthest_counted_radius": round(float(r[pk.counted].max()), 4),
                    "codes_beyond_0.84": {str(k): int(v) for k, v in zip(*np.unique(pk.why[far], return_counts=True))},
                    "corner_tiles": [str(pk.why[i, j]) or "counted" for i, j in
                                     ((0, 0), (0, nx - 1), (ny - 1, 0), (ny - 1, nx - 1))]})
    return out


def map_row(rig, setup, variant, res) -> dict:
    from benchmarks import bench_calibrate as B

    e = B.map_errors(rig, res.calibration, B.effects_for(setup, variant), setup.inside())["calibration"]
    m = res.model
    return {"family": res.calibration.focus_error.family, "order": [m.degree, m.radial, m.low_focus_degree,
                                                                     m.focus_degree],
            "tiles": int(len(res.observations)), "outliers": next((w for w in res.warnings if "outliers" in w), ""),
            "rms_d": e["rms_d"], "within_tiles_rms_d": e["within_tiles_rms_d"],
            "beyond_tiles_rms_d": e["beyond_tiles_rms_d"], "beyond_tiles_share": e["beyond_tiles_share"],
            "tiles_radius_max": e["tiles_radius_max"], "radius_rms_d": e["radius_rms_d"]}


def corner_bias(rig, setup, variant, res) -> dict:
    """Counted tiles beyond CENTRED_RADIUS: object minus the truth's in-focus object at the measured peak (D); and
    part a with ideal tiles (every counted tile peaking where the truth has its object in focus), with and without
    those tiles."""
    from aat_deploy.calibrate.fit import held_beyond_tiles
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import fit_model
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import phone_map_budget as P

    eff = B.effects_for(setup, variant)
    scale = B.SCALE if any(e.startswith("focus_metadata") for e in eff) else 1.0
    res.sweeps_measured = res.measures
    t = P.tile_table(res, rig, eff, scale)
    ok = t["counted"]
    r = field_radius_of(t["x"], t["y"], rig.w / rig.h)
    bias = t["object_d"] - P.truth_at_reported(t["truth_f"], t["reported_d"], scale)
    corner = ok & (r > CENTRED_RADIUS) & np.isfinite(bias)
    out = {"corner_tiles": [{"sweep": int(t["sweep"][j]), "x": round(float(t["x"][j]), 3),
                             "y": round(float(t["y"][j]), 3), "object_d": round(float(t["object_d"][j]), 3),
                             "peak_reported_d": round(float(t["reported_d"][j]), 3),
                             "ideal_reported_d": round(float(t["ideal_d"][j]), 3), "bias_d": round(float(bias[j]), 3)}
                            for j in np.flatnonzero(corner)],
           "bias_by_radius": {f"{lo:g}-{hi:g}": {"n": int(m.sum()), "mean_d": float(np.mean(bias[m])),
                                                 "sd_d": float(np.std(bias[m]))}
                              for lo, hi in BINS for m in [ok & (r >= lo) & (r < hi) & np.isfinite(bias)] if m.any()}}
    for name, keep in (("ideal tiles, edge grid", ok & np.isfinite(t["ideal_d"])),
                       ("ideal tiles, without those beyond 0.921", ok & np.isfinite(t["ideal_d"]) & (r <= CENTRED_RADIUS))):
        obs = P.observations_of(t, keep, t["ideal_d"], rig.w / rig.h)
        fm = fit_model(obs)
        cal = dataclasses.replace(res.calibration, best_focus=held_beyond_tiles(fm.field, obs), focus_error=fm.focus)
        e = B.map_errors(rig, cal, eff, setup.inside())["calibration"]
        out[name] = {"order": [fm.degree, fm.radial, fm.low_focus_degree, fm.focus_degree], "family": fm.focus.family,
                     "rms_d": e["rms_d"], "within_tiles_rms_d": e["within_tiles_rms_d"],
                     "beyond_tiles_rms_d": e["beyond_tiles_rms_d"], "tiles_radius_max": e["tiles_radius_max"],
                     "radius_rms_d": e["radius_rms_d"]}
    return out


def run(variant: str, log) -> dict:
    from aat_deploy.calibrate.fit import fit_calibration
    from benchmarks import bench_calibrate as B

    rig, setup, v = setup_of(variant)
    sweeps = [B.sweep(rig, v, i, log) for i in range(len(setup.distances_m))]
    aspect = rig.w / rig.h
    out: dict = {}
    for grid in ("centred", "edges", "edges without tiles beyond 0.921"):
        ms = B.measures(rig, sweeps, v, tiles_to_edges=grid != "centred")
        if grid.startswith("edges without"):
            ms = drop_beyond(ms, CENTRED_RADIUS, aspect)
        res = fit_calibration(ms, n_boot=0)  # part a's map does not depend on the bootstrap
        out[grid] = map_row(rig, setup, v, res) | {"sweeps": tile_codes(ms, aspect)}
        if grid == "edges":
            out["edges"] |= corner_bias(rig, setup, v, res)
        row = out[grid]
        log(f"  {variant} {grid}: {row['family']} {row['order']}, {row['tiles']} tiles; map {row['rms_d']:.4f} D, "
            f"within {row['within_tiles_rms_d']:.3f} / beyond {row['beyond_tiles_rms_d']:.3f} D "
            f"({100 * row['beyond_tiles_share']:.1f} % beyond radius {row['tiles_radius_max']:.3f})")
    return out


def table(res: dict) -> str:
    lines = ["| variant | tiles | family, order (degree, radial, low / edge focus degree) | map RMS inside (D) | "
             "within / beyond the farthest tile (share beyond, its radius) | 0.84-0.9 | 0.9-1 |", "|---|---|---|---|---|---|---|"]
    for v, r in res["variants"].items():
        for grid in ("centred", "edges", "edges without tiles beyond 0.921"):
            row = r[grid]
            lines.append(f"| {v} | {grid} ({row['tiles']}) | {row['family']} {tuple(row['order'])} | "
                         f"{row['rms_d']:.4f} | {row['within_tiles_rms_d']:.3f} / {row['beyond_tiles_rms_d']:.3f} "
                         f"({100 * row['beyond_tiles_share']:.1f} %, {row['tiles_radius_max']:.3f}) | "
                         f"{row['radius_rms_d']['0.84-0.9']:.3f} | {row['radius_rms_d']['0.9-1']:.3f} |")
        for name in ("ideal tiles, edge grid", "ideal tiles, without those beyond 0.921"):
            row = r["edges"][name]
            lines.append(f"| {v} | {name} | {row['family']} {tuple(row['order'])} | {row['rms_d']:.4f} | "
                         f"{row['within_tiles_rms_d']:.3f} / {row['beyond_tiles_rms_d']:.3f} "
                         f"({row['tiles_radius_max']:.3f}) | {row['radius_rms_d']['0.84-0.9']:.3f} | "
                         f"{row['radius_rms_d']['0.9-1']:.3f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--out", default=str(RESULTS / "corner_tiles.json"))
    ap.add_argument("--force", action="store_true", help="overwrite --out")
    a = ap.parse_args(argv)
    out = Path(a.out)
    if out.exists() and not a.force:
        print(f"{out}: exists; give --force to overwrite it (nothing was run)", file=sys.stderr)
        return 2
    variants = a.variants.split(",")
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:  # before any variant is run: a typo late in the list would otherwise cost the runs before it
        print(f"corner_tiles: unknown variant {unknown[0]!r} (one of {', '.join(VARIANTS)})", file=sys.stderr)
        return 2
    log = lambda m: print(m, file=sys.stderr, flush=True)
    res = {"setup": "cellphone_near (development sweeps; no held-out scene)", "variants": {}}
    for v in variants:
        res["variants"][v] = run(v, log)
    from aat_deploy.io.atomic import write_text_atomic

    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps(res, indent=1) + "\n")
    print(table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
