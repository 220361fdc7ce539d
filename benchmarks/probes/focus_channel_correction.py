"""Does the binning correction, made each channel's own under its floor (`anchors.PER_CHANNEL`), fit the focus better
than the channels' mean added to every channel (the code)? Issue 32, 2026-11-28, after "The focus twin's exposure"
(docs/diagnosis.md, "Not the whole of it on 3303": the binned sweep leaves the RAW development out, so the channels'
signals under their own floors are off by different amounts). A probe of development sets only (no scene of 3304 or
later, no noise seed 49-52); it chooses nothing.

The sets: every set of scenes 3303 and 2817 (where the exposure leaves the fitted full well unexplained: k 1.03,
fitted 6,200-6,700 e-) and of 3251 (where the exposure explains it: k 1.25), each rerun through the first-round focus
fit (`focus_start_invariance`) with the code (`--mode code`) and with the change (`--mode channel`) on this machine,
the two commands of a group one after the other (a run stopped by the clock leaves pairs); with `--exposure`, the same
with the floor at the capture's exposure (`ptc_exposure` against `ptc_exposure_channel`). Each pair: family, within
0.02 D with every frame determined, claimed-wrong (`focus_choice_nearest.scenes_moved`), the per-frame and corrected
errors, and the fitted full well.

    python -m benchmarks.probes.focus_channel_correction --plan [--exposure]
    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 python -m benchmarks.probes.focus_channel_correction --run --until HH:MM \\
        [--exposure]
    python -m benchmarks.probes.focus_channel_correction [--exposure] [--out results/focus_channel_correction.md]
        # neither --plan nor --run: the pairs' table (--modes BASE VAR: any two of the four modes' rows)
"""

from __future__ import annotations

import io
import sys
from contextlib import redirect_stdout

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks.probes import focus_dense_subset as ds

SCENES = ("scene3303", "scene2817", "scene3251")
PAIRS = {False: ("code", "channel"), True: ("ptc_exposure", "ptc_exposure_channel")}


def out_file(mode: str) -> str:
    return f"results/focus_channel_correction_{mode}.jsonl"


def plan() -> list[tuple[str, str, str]]:
    rows = ds.stored()
    return [("C", c, k) for c in SCENES for (cc, k) in sorted(rows) if cc == c]


def commands(exposure: bool) -> list[str]:
    """The two modes' commands, group by group (the base first)."""
    a, b = (ds.commands(plan(), mode=m, out_file=out_file(m)) for m in PAIRS[exposure])
    return [c for pair in zip(a, b) for c in pair]


def tally(base: list[dict], var: list[dict], names: tuple[str, str]) -> str:
    from benchmarks.probes.focus_choice_nearest import scenes_moved

    b = {(r["capture"], r["kind"]): r for r in base}
    v = {(r["capture"], r["kind"]): r for r in var}
    keys = [k for k in ((c, k) for _, c, k in plan()) if k in b and k in v]
    out = io.StringIO()
    with redirect_stdout(out):
        print(f"| set | {names[0]} | {names[1]} | per-frame max error (D) | fitted full well (e-) | outcome |\n"
              "|---|---|---|---|---|---|")

        def desc(z):
            und = int(np.sum(np.asarray(z["frames_undetermined"]))) if z["frames_undetermined"] else 0
            return (f"`{z['family']}` {z['corrected_max_err_d']:.4f} D" + (f", {und} undetermined" if und else "")
                    + (", claimed" if ds.marks(z)[2] else ""))

        for key in keys:
            x, y = ds.marks(b[key]), ds.marks(v[key])
            up = any(q > p for p, q in zip(x[:2], y[:2])) or (x[2] and not y[2])
            down = any(q < p for p, q in zip(x[:2], y[:2])) or (y[2] and not x[2])
            how = "better" if up and not down else "worse" if down and not up else "mixed" if up else ""
            pf = [np.nanmax(np.abs(np.asarray(z["frame_err_d"], np.float64))) for z in (b[key], v[key])]
            fw = [((z.get("focus_twin") or {}).get("noise") or {}).get("fitted_full_well_e") for z in (b[key], v[key])]
            print(f"| {key[0]} {key[1]} | {desc(b[key])} | {desc(v[key])} | {pf[0]:.4f} -> {pf[1]:.4f} | "
                  f"{fw[0]} -> {fw[1]} | {how} |")
        bb, vv = [b[k] for k in keys], [v[k] for k in keys]
        m = scenes_moved(bb, vv)
        sets = [s for x in m["scenes"].values() for s in x]
        n = lambda rs, i: sum(ds.marks(z)[i] for z in rs)  # noqa: E731
        err = [k for k in keys if k[1] != "none"]
        print(f"\n{len(keys)} sets ({len(err)} with an error): family right {n(bb, 0)} -> {n(vv, 0)}, within 0.02 D with "
              f"every frame determined {n(bb, 1)} -> {n(vv, 1)} of {len(err)}, claimed-wrong {n(bb, 2)} -> {n(vv, 2)}, "
              f"untouched blaming focus {sum(b[k]['family'] != 'none' for k in keys if k[1] == 'none')} -> "
              f"{sum(v[k]['family'] != 'none' for k in keys if k[1] == 'none')}; sets better "
              f"{sum(s.endswith('better') for s in sets)}, worse {sum(s.endswith('worse') for s in sets)}, mixed "
              f"{sum(s.endswith('mixed') for s in sets)}: {m['scenes']}")
        for c in SCENES:
            ks = [k for k in keys if k[0] == c]
            if not ks:
                continue
            d = np.array([v[k]["corrected_max_err_d"] - b[k]["corrected_max_err_d"] for k in ks if k[1] != "none"])
            fr = np.array([[np.nanmax(np.abs(np.asarray(z[k]["frame_err_d"], np.float64))) for z in (b, v)] for k in ks])
            print(f"\n{c}, {len(ks)} sets: the corrected focus's largest error per set with an error, median change "
                  f"{np.median(d):+.4f} D (smaller in {int((d < -5e-4).sum())}, larger in {int((d > 5e-4).sum())} of "
                  f"{len(d)}); the largest per-frame error, median {np.median(fr[:, 0]):.4f} -> {np.median(fr[:, 1]):.4f} "
                  f"D (smaller in {int((fr[:, 1] < fr[:, 0] - 5e-4).sum())}, larger in "
                  f"{int((fr[:, 1] > fr[:, 0] + 5e-4).sum())})")
        secs = [(b[k].get("seconds"), v[k].get("seconds")) for k in keys]
        print(f"\nthe fit, wall clock: mean {np.mean([s[0] for s in secs]):.0f} s -> {np.mean([s[1] for s in secs]):.0f} s")
        todo = [f"{c} {k}" for _, c, k in plan() if (c, k) not in set(keys)]
        print(f"\nnot run (both): {len(todo)} of {len(plan())}" + (f": {', '.join(todo)}" if todo else ""))
    return out.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = ds.subset_parser(__doc__, "13:25")
    ap.add_argument("--exposure", action="store_true", help="with the floor at the capture's exposure on both sides")
    ap.add_argument("--modes", nargs=2, choices=[m for x in PAIRS.values() for m in x], metavar=("BASE", "VAR"),
                    help="without --plan or --run: the table of these two modes' rows (e.g. code ptc_exposure_channel)")
    a = ap.parse_args(argv)
    if a.tally:  # the shared parser has it; this probe's tables read each mode's own file
        ap.error("--tally is not used here: the table pairs two modes' own files (give --modes BASE VAR, or neither)")
    cmds = commands(a.exposure)
    if a.run:
        ds.run(cmds, a.until, a.lock)
        return 0
    if a.plan:
        for s, c, k in plan():
            print(s, c, k)
        print(f"\n{len(plan())} sets")
        print("\n".join(cmds))
        return 0
    names = tuple(a.modes) if a.modes else PAIRS[a.exposure]
    files = [ds.ROOT / out_file(m) for m in names]
    for f in files:
        if not f.is_file():
            ap.error(f"{f}: no such results file (run first)")
    text = tally(*(ds.read([f]) for f in files), names)
    print(text)
    if a.out:
        write_text_atomic(a.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
