"""Should the focus twin's full well be measured by photon transfer on the captures' RAW mosaics before the focus fit
(`fitters.FULL_WELL_BY_PHOTON_TRANSFER`, `aat_deploy/diagnose/photon.py`) instead of fitted with the focus against
the expected floor (`fitters.full_well_on_floor`)? Issue 32, 2026-11-28; docs/diagnosis.md, Limits, "The full well
by photon transfer": the rule below was committed before any set was rerun with it.

- The sets (development only: no scene of 3304 or later, no noise seed 49-52): dense anchoring's declared subset
  (`focus_dense_subset.plan`: H0 8 untouched copies, A1 9 sets the code gets wrong or claims wrongly, A2 20 with a
  frame undetermined over 0.02 D, H1 16 right sets, drawn with numpy seed 32), the 28 sets its probe ran
  (`focus_dense_subset.DONE_FILES`: P, the sets that showed the shared misfit, scene 3303's scales among them), and
  U, every other untouched copy of the universe's 25 scenes (17): 98 sets.
- Order: H0, A1, P, then A2 and H1 in dense anchoring's shuffled order, then U.
- Each set rerun through the first-round focus fit (`bench_diagnose_focus --fit-only`, `focus_start_invariance
  --mode ptc`) against its stored row rescored by the code (`bench_diagnose_focus.rescored`): better or worse in the
  family, in within 0.02 D with every frame determined, or in claimed-wrong (`focus_choice_nearest.scenes_moved`), per
  set and per scene, with a sign test over scenes.

    python -m benchmarks.probes.focus_ptc_subset --plan            # the sets, their order and the lane-B commands
    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 python -m benchmarks.probes.focus_ptc_subset --run --until 07:30
    python -m benchmarks.probes.focus_ptc_subset --tally results/focus_ptc_subset.jsonl [--out results/focus_ptc_subset.md]
"""

from __future__ import annotations

import io
import json
import sys
from contextlib import redirect_stdout

import numpy as np

from benchmarks.probes import focus_dense_subset as ds

OUT = "results/focus_ptc_subset.jsonl"


def plan() -> list[tuple[str, str, str]]:
    """[(stratum, capture, kind)] in the declared order."""
    dense = ds.plan()
    probe = sorted({(r["capture"], r["kind"]) for r in ds.read(ds.ROOT / "results" / f for f in ds.DONE_FILES)})
    head = [x for x in dense if x[0] in ("H0", "A1")]
    rest = [x for x in dense if x[0] not in ("H0", "A1")]
    seen = {(c, k) for _, c, k in dense} | set(probe)
    untouched = [("U", c, k) for c, k in sorted(ds.stored()) if k == "none" and (c, k) not in seen]
    return head + [("P", c, k) for c, k in probe] + rest + untouched


def tally(rerun: list[dict], strata: dict, label: str = "photon transfer") -> str:
    """The table of every rerun set against its stored row rescored, and the rule's counts."""
    from benchmarks import bench_diagnose_focus as bench
    from benchmarks.probes.focus_choice_nearest import scenes_moved

    rows = ds.stored()
    rerun = list({(r["capture"], r["kind"]): r for r in rerun}.values())
    base = {k: bench.rescored(rows[k], "code", on_estimates=True) for k in ((r["capture"], r["kind"]) for r in rerun)}
    out = io.StringIO()
    with redirect_stdout(out):
        for r in rerun:
            if abs(r["reported_max_err_d"] - rows[(r["capture"], r["kind"])]["reported_max_err_d"]) > 1e-6:
                raise SystemExit(f"{r['capture']} {r['kind']}: its reported focus is not the stored row's")
        print(f"| stratum | set | the code (stored, rescored) | {label} | full well (e-) fitted -> measured "
              "| per-frame max error (D) | s a fit | outcome |\n|---|---|---|---|---|---|---|---|")
        for r in sorted(rerun, key=lambda x: (strata.get((x["capture"], x["kind"]), "?"), x["capture"], x["kind"])):
            key = (r["capture"], r["kind"])
            b = base[key]
            x, y = ds.marks(b), ds.marks(r)
            up = any(v > u for u, v in zip(x[:2], y[:2])) or (x[2] and not y[2])
            down = any(v < u for u, v in zip(x[:2], y[:2])) or (y[2] and not x[2])
            how = "better" if up and not down else "worse" if down and not up else "mixed" if up else ""

            def desc(z):
                und = int(np.sum(np.asarray(z["frames_undetermined"]))) if z["frames_undetermined"] else 0
                return (f"`{z['family']}` {z['corrected_max_err_d']:.4f} D" + (f", {und} undetermined" if und else "")
                        + (", claimed" if ds.marks(z)[2] else ""))

            pf = [np.nanmax(np.abs(np.asarray(z["frame_err_d"], np.float64))) for z in (rows[key], r)]
            fw = [((z.get("focus_twin") or {}).get("noise") or {}).get("fitted_full_well_e") for z in (rows[key], r)]
            print(f"| {strata.get(key, '?')} | {r['capture']} {r['kind']} | {desc(b)} | {desc(r)} | {fw[0]} -> {fw[1]} "
                  f"| {pf[0]:.4f} -> {pf[1]:.4f} | {r.get('seconds')} | {how} |")
        m = scenes_moved(list(base.values()), rerun)
        sets = [s for v in m["scenes"].values() for s in v]
        n = lambda rs, i: sum(ds.marks(z)[i] for z in rs)  # noqa: E731
        err = [z for z in rerun if z["kind"] != "none"]
        un = [z for z in rerun if z["kind"] == "none"]
        worse_family = [f"{z['capture']} {z['kind']}" for z in rerun
                        if base[(z["capture"], z["kind"])]["family_ok"] and not z["family_ok"]]
        print(f"\n{len(rerun)} sets ({len(err)} with an error, {len(un)} untouched): family right "
              f"{n(base.values(), 0)} -> {n(rerun, 0)}, within 0.02 D with every frame determined "
              f"{n(base.values(), 1)} -> {n(rerun, 1)} of {len(err)}, claimed-wrong {n(base.values(), 2)} -> "
              f"{n(rerun, 2)}, untouched blaming focus "
              f"{sum(base[(z['capture'], 'none')]['family'] != 'none' for z in un)} -> "
              f"{sum(z['family'] != 'none' for z in un)} of {len(un)}; sets better {sum(s.endswith('better') for s in sets)}, "
              f"worse {sum(s.endswith('worse') for s in sets)}, mixed {sum(s.endswith('mixed') for s in sets)}; "
              f"worse in family: {worse_family or 'none'}; scenes better {m['scenes_better']}, worse {m['scenes_worse']} "
              f"(sign test p = {m['sign_test_p']}): {json.dumps(m['scenes'])}")
        d = np.array([r["corrected_max_err_d"] - base[(r["capture"], r["kind"])]["corrected_max_err_d"] for r in err])
        if d.size:
            print(f"\nthe corrected focus's largest error per set with an error: smaller in {int((d < -5e-4).sum())}, "
                  f"larger in {int((d > 5e-4).sum())} (by more than 0.0005 D) of {len(d)}; median change "
                  f"{np.median(d):+.4f} D")
        secs = [(r["seconds"], rows[(r["capture"], r["kind"])].get("seconds")) for r in rerun if r.get("seconds")]
        if secs:
            a, b = (np.array([s[i] for s in secs if s[1]], np.float64) for i in (0, 1))
            print(f"\nthe fit, wall clock: mean {np.mean([s[0] for s in secs]):.0f} s ({min(s[0] for s in secs):.0f}-"
                  f"{max(s[0] for s in secs):.0f} s, {len(secs)} sets); the stored rows' {np.mean(b):.0f} s on the same sets")
        todo = [f"{s} {c} {k}" for s, c, k in plan() if (c, k) not in base]
        print(f"\nnot run: {len(todo)} of {len(plan())}" + (f": {', '.join(todo)}" if todo else ""))
    return out.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = ds.subset_parser(__doc__, "07:30")
    a = ap.parse_args(argv)
    order = plan()
    cmds = ds.commands(order, mode="ptc", out_file=OUT)
    if a.run:
        ds.run(cmds, a.until, a.lock)
        return 0
    if a.plan:
        for s, c, k in order:
            print(s, c, k)
        print(f"\n{len(order)} sets: " + ", ".join(f"{s} {sum(x[0] == s for x in order)}"
                                                 for s in ("H0", "A1", "P", "A2", "H1", "U")))
        print("\n".join(cmds))
        return 0
    return ds.tally_out(ap, a, lambda rows: tally(rows, {(c, k): s for s, c, k in order}))


if __name__ == "__main__":
    sys.exit(main())
