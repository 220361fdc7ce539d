"""Two any-camera models' bench_anycam results side by side, paired over the same test scenes.

    python -m benchmarks.probes.anycam_compare results/anycam_v9_s13800.json results/anycam_v1.json
        [--row "dfv_aat, lens map"] [--out OUT.json]

For every lens and protocol both files hold: each model's MAE (m, mean over the procedural scenes) in the row named
(by default the model given the lens's map), and A's MAE over B's, overall and in the outer field, paired over the
scenes with a 95 % bootstrap interval (`aat_deploy.eval.stats.paired_ratio`, as bench_anycam's own ratios); the
real RGB-D scenes one by one. Both files must hold the same scenes (the same --n and cache): bench_anycam renders them
from their seeds, so two runs of it agree. The stack-size and schedule tables (`--tables`, paper lens) both files hold
are compared the same way, row by row (A's MAE over B's, paired over the table's scenes).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def compare(a: dict, b: dict, row: str) -> list[dict]:
    """One entry per lens and protocol in both bench_anycam results (their "lenses" keys)."""
    from aat_deploy.eval.stats import paired_ratio
    from benchmarks.bench_anycam import CL_MAP

    out = []
    for lens in sorted(set(a["lenses"]) & set(b["lenses"])):
        for protocol in sorted(set(a["lenses"][lens]) & set(b["lenses"][lens])):
            pa, pb = (x["lenses"][lens][protocol]["per_image"].get(row) for x in (a, b))
            if pa is None or pb is None:
                continue
            if len(pa["procedural"]) != len(pb["procedural"]):
                raise SystemExit(f"{lens} {protocol}: {len(pa['procedural'])} scenes against "
                                 f"{len(pb['procedural'])}: not the same test set")
            # the same count can still be other scenes (another --n, cache or seed): the classical method does not
            # depend on the model, so its per-scene MAE must agree wherever both files hold it
            ca, cb = (x["lenses"][lens][protocol]["per_image"].get(CL_MAP) for x in (a, b))
            if ca and cb and not np.allclose([s["mae"] for s in ca["procedural"]],
                                             [s["mae"] for s in cb["procedural"]], rtol=1e-3, atol=1e-4):
                raise SystemExit(f"{lens} {protocol}: the classical method's per-scene MAE differs between the "
                                 "files: not the same test set")
            e = {"lens": lens, "protocol": protocol, "n": len(pa["procedural"]),
                 "a_mae": float(np.mean([s["mae"] for s in pa["procedural"]])),
                 "b_mae": float(np.mean([s["mae"] for s in pb["procedural"]])),
                 "a_over_b": [float(v) for v in paired_ratio(pa["procedural"], pb["procedural"])],
                 "a_over_b_outer": [float(v) for v in paired_ratio(pa["procedural"], pb["procedural"], "mae_outer")]}
            for real in ("middlebury", "nyu"):
                if pa.get(real) and pb.get(real):
                    e[f"{real}_a_over_b"] = float(pa[real][0]["mae"] / pb[real][0]["mae"])
            out.append(e)
    return out


def compare_tables(a: dict, b: dict, row: str) -> list[dict]:
    """One entry per row of the stack-size and schedule tables both results hold (bench_anycam --tables), in A's
    order: A's MAE over B's in `row`, paired over the table's scenes."""
    from aat_deploy.eval.stats import paired_ratio
    from benchmarks.bench_anycam import CL_MAP

    ta, tb = a.get("tables", {}), b.get("tables", {})
    out = []
    for table in [t for t in ta if t != "n" and t in tb]:
        for name in [r for r in ta[table] if r in tb[table]]:
            pa, pb = (x[table][name].get(row) for x in (ta, tb))
            if pa is None or pb is None:
                continue
            ca, cb = (x[table][name].get(CL_MAP) for x in (ta, tb))
            if len(pa["procedural"]) != len(pb["procedural"]) or (ca and cb and not np.allclose(
                    [s["mae"] for s in ca["procedural"]], [s["mae"] for s in cb["procedural"]], rtol=1e-3,
                    atol=1e-4)):
                raise SystemExit(f"table {table}, {name}: not the same scenes in both files")
            out.append({"table": table, "row": name, "n": len(pa["procedural"]),
                        "a_mae": float(np.mean([s["mae"] for s in pa["procedural"]])),
                        "b_mae": float(np.mean([s["mae"] for s in pb["procedural"]])),
                        "a_over_b": [float(v) for v in paired_ratio(pa["procedural"], pb["procedural"])]})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a", type=Path, help="bench_anycam results of model A")
    ap.add_argument("b", type=Path, help="bench_anycam results of model B")
    ap.add_argument("--row", default="dfv_aat, lens map", help="the method row to compare")
    ap.add_argument("--out", type=Path, help="JSON of the comparison")
    a = ap.parse_args(argv)
    for p in (a.a, a.b):
        if not p.is_file():
            ap.error(f"{p}: no such file")
    if a.out and a.out.exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    ra, rb = json.loads(a.a.read_text()), json.loads(a.b.read_text())
    rows, tables = compare(ra, rb, a.row), compare_tables(ra, rb, a.row)
    if not rows and not tables:
        ap.error(f"no lens and protocol or table row with the row {a.row!r} in both files")
    f = lambda v: f"{v[0]:.2f} [{v[1]:.2f}, {v[2]:.2f}]"  # noqa: E731
    print(f"#### {a.row}: A = {ra.get('model')}, B = {rb.get('model')}\n")
    print("| lens | protocol | scenes | A MAE (m) | B MAE (m) | A / B | A / B outer field | Middlebury A / B | NYU A / B |")
    print("|---|---|---|---|---|---|---|---|---|")
    for e in rows:
        real = [f"{e[k]:.2f}" if k in e else "–" for k in ("middlebury_a_over_b", "nyu_a_over_b")]
        print(f"| {e['lens']} | {e['protocol']} | {e['n']} | {e['a_mae']:.3f} | {e['b_mae']:.3f} | {f(e['a_over_b'])} "
              f"| {f(e['a_over_b_outer'])} | {real[0]} | {real[1]} |")
    if tables:
        print("\n| table | row | scenes | A MAE (m) | B MAE (m) | A / B |\n|---|---|---|---|---|---|")
        for e in tables:
            print(f"| {e['table']} | {e['row']} | {e['n']} | {e['a_mae']:.3f} | {e['b_mae']:.3f} | {f(e['a_over_b'])} |")
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(a.out, json.dumps({"a": str(a.a), "b": str(a.b), "row": a.row, "rows": rows,
                                             **({"tables": tables} if tables else {})}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
