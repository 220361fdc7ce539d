"""Two runs of bench_calibrate's random copies (`--copies`), paired scene by scene: A's depth over B's.

    python -m benchmarks.probes.copies_compare results/calibrate_copies_cellphone_near_blend.json \
        results/calibrate_copies_cellphone_near_preblend.json [--lens cellphone_near] [--mapping calibration] \
        [--out OUT.json]

Two runs of the same copies (the same seed, scenes and distribution) that differ in the calibration's code render
the same held-out stacks through each copy, so their depth can be compared scene by scene: for every copy both
hold, the mapping's (by default the calibration's) mean MAE in A over B's, overall, in the outer field and in
diopters, with a paired 95 % bootstrap interval (`aat_deploy.eval.stats.paired_ratio`); pooled over the copies
with bench_calibrate's crossed two-level bootstrap (`nested_paired_ratio(crossed=True)`, as
`benchmarks.calibrate_copies.pooled`). The two runs' stacks are checked to be the same: the prescription map's and
the thin lens's per-scene MAEs, which no calibration enters, must agree (to 1e-9 m). --out is refused if it exists.
Two runs of the hand-chosen copy (`--parts ...,depth` without `--copies`: the files' `depth`, no `copies`) are paired
the same way, its scenes alone (`compare_copy`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ZONES = ("mae", "mae_outer", "mae_d")
FIXED = ("prescription map", "thin lens")  # mappings no calibration enters: the same in both runs if the stacks are


def _same_stacks(sx: dict, sy: dict, what: str) -> None:
    for m in FIXED:
        same = len(sx[m]) == len(sy[m]) and all(
            p["scene"] == q["scene"] and all(abs(p[z] - q[z]) <= 1e-9 for z in ZONES) for p, q in zip(sx[m], sy[m]))
        if not same:
            raise SystemExit(f"copies_compare: {what}: the {m}'s per-scene MAEs differ: not the same held-out stacks")


def compare_copy(a: dict, b: dict, lens: str, mapping: str = "calibration") -> dict:
    """The hand-chosen copy's depth (bench_calibrate's `depth`) in A over B's, paired scene by scene."""
    from aat_deploy.eval.stats import paired_ratio

    da, db = (x.get("depth", {}).get(lens) for x in (a, b))
    if da is None or db is None:
        raise SystemExit(f"copies_compare: {lens}'s hand-chosen copy's depth is not in both files")
    sx, sy = da["per_scene"], db["per_scene"]
    if mapping not in sx or mapping not in sy:
        raise SystemExit(f"copies_compare: the copy: no mapping {mapping!r}")
    _same_stacks(sx, sy, "the copy")
    row = {"copy": "hand-chosen", "scenes": len(sx[mapping])}
    for z in ZONES:
        row[f"a/b {z}"] = [float(v) for v in paired_ratio(sx[mapping], sy[mapping], z)]
    return {"lens": lens, "mapping": mapping, "copies": [row]}


def compare(a: dict, b: dict, lens: str, mapping: str = "calibration") -> dict:
    """A's mapping over B's, per copy and pooled; SystemExit (one line) when the runs are not of the same copies."""
    from aat_deploy.eval.stats import nested_paired_ratio, paired_ratio

    ca, cb = (x.get("copies", {}).get(lens) for x in (a, b))
    if ca is None or cb is None:
        raise SystemExit(f"copies_compare: {lens}'s copies are not in both files")
    for k in ("seed", "n", "distribution"):
        if ca[k] != cb[k]:
            raise SystemExit(f"copies_compare: {lens}: {k} {ca[k]} against {cb[k]}: not the same copies")
    by_b = {c["index"]: c for c in cb["copies"] if c.get("depth")}
    pairs = [(c, by_b[c["index"]]) for c in ca["copies"] if c.get("depth") and c["index"] in by_b]
    if not pairs:
        raise SystemExit(f"copies_compare: {lens}: no copy scored in both files")
    rows, pa, pb = [], [], []
    for x, y in pairs:
        sx, sy = x["depth"]["per_scene"], y["depth"]["per_scene"]
        if mapping not in sx or mapping not in sy:
            raise SystemExit(f"copies_compare: copy {x['index']}: no mapping {mapping!r}")
        _same_stacks(sx, sy, f"copy {x['index']}")
        row = {"copy": x["index"], "scenes": len(sx[mapping]),
               "map_rms_inside_d": [c["map"]["inside"]["calibration"]["rms_d"] for c in (x, y)]}
        for z in ZONES:
            row[f"a/b {z}"] = [float(v) for v in paired_ratio(sx[mapping], sy[mapping], z)]
        rows.append(row)
        pa.append(sx[mapping])
        pb.append(sy[mapping])
    pooled = {f"a/b {z}": [float(v) for v in nested_paired_ratio(pa, pb, z, crossed=True)] for z in ZONES}
    return {"lens": lens, "mapping": mapping, "copies": rows, "pooled": pooled}


def table(res: dict) -> str:
    from aat_deploy.eval.stats import fmt_interval as fmt

    lines = ["| copy | map RMS inside, A / B (D) | A / B, MAE | outer | MAE in D |", "|---|---|---|---|---|"]
    for r in res["copies"]:
        ma, mb = r.get("map_rms_inside_d", (float("nan"),) * 2)
        lines.append(f"| {r['copy']} | {ma:.4f} / {mb:.4f} | " + " | ".join(fmt(r[f"a/b {z}"]) for z in ZONES) + " |")
    if "pooled" in res:
        lines.append(f"| pooled, {len(res['copies'])} copies | | "
                     + " | ".join(fmt(res["pooled"][f"a/b {z}"]) for z in ZONES) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--lens", default="cellphone_near")
    ap.add_argument("--mapping", default="calibration")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    if args.out and Path(args.out).exists():
        print(f"copies_compare: {args.out} exists: give another --out", file=sys.stderr)
        return 2
    for f in (args.a, args.b):
        if not Path(f).is_file():
            print(f"copies_compare: {f}: no such results file", file=sys.stderr)
            return 2
    a, b = (json.loads(Path(f).read_text()) for f in (args.a, args.b))
    res = (compare if "copies" in a or "copies" in b else compare_copy)(a, b, args.lens, args.mapping)
    res["a"], res["b"] = args.a, args.b
    print(f"{args.mapping}: A = {args.a}, B = {args.b}\n\n{table(res)}")
    if args.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(Path(args.out), json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
