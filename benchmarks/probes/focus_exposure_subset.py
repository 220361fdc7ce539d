"""Should the focus twin's expected floor be put at the capture's exposure, with the full well measured by photon
transfer (`fitters.FULL_WELL_BY_PHOTON_TRANSFER` and `fitters.FLOOR_AT_CAPTURE_EXPOSURE` both on) instead of the full
well fitted against the floor (the code)? Issue 32, 2026-11-28; docs/diagnosis.md, Limits, "The focus twin's
exposure": the rule there was committed before any set was rerun with the change.

The sets and their order are `focus_ptc_subset`'s (98 development sets: H0, A1, P, A2, H1, U; no scene of 3304 or
later, no noise seed 49-52), each rerun through the first-round focus fit (`bench_diagnose_focus --fit-only`,
`focus_start_invariance --mode ptc_exposure`) and tallied against its stored row rescored by the code as
`focus_ptc_subset --tally` does.

    python -m benchmarks.probes.focus_exposure_subset --plan
    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 python -m benchmarks.probes.focus_exposure_subset --run --until 10:20
    python -m benchmarks.probes.focus_exposure_subset --tally results/focus_exposure_subset.jsonl \\
        [--out results/focus_exposure_subset.md]

The reproducibility check (the second declaration, docs/diagnosis.md: a new machine renders the captures again):
`--check` with `--plan` or `--run` gives or runs the commands of REPRO_SETS, sets already in OUT, into REPRO_OUT
instead; with `--tally REPRO_OUT` it compares their rows with OUT's (`compare`).

    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 python -m benchmarks.probes.focus_exposure_subset --check --run --until HH:MM
    python -m benchmarks.probes.focus_exposure_subset --check --tally results/focus_exposure_subset_repro.jsonl \\
        [--out results/focus_exposure_subset_repro.md]
"""

from __future__ import annotations

import io
import sys
from contextlib import redirect_stdout

import numpy as np

from benchmarks.probes import focus_dense_subset as ds
from benchmarks.probes import focus_ptc_subset as ptc

OUT = "results/focus_exposure_subset.jsonl"
LABEL = "photon transfer, floor at the capture's exposure"
# the reproducibility check: one set of each of the two rounds whose captures the untouched copies still to run need,
# already in OUT, rerun into REPRO_OUT; it reproduces if the family and the frames left out are the same and every
# frame's estimate is within TOL_D of the stored row's
REPRO_SETS = (("scene3045", "scale_0.95"), ("scene3251", "quantised"))
REPRO_OUT = "results/focus_exposure_subset_repro.jsonl"
TOL_D = 0.002


def compare(rerun: list[dict], stored: list[dict], sets=REPRO_SETS, tol_d: float = TOL_D) -> str:
    """Each of `sets` rerun against its stored row: the family, the frames left out (NaN in `frame_err_d`) and
    undetermined, every frame's estimate within `tol_d` diopters; a set not rerun does not reproduce."""
    new = {(r["capture"], r["kind"]): r for r in rerun}
    old = {(r["capture"], r["kind"]): r for r in stored}
    ok = 0
    out = io.StringIO()
    with redirect_stdout(out):
        print("| set | family, stored -> rerun | frames left out, undetermined | largest estimate change (D) | corrected "
              "max error (D) | full well by photon transfer (e-) | exposure ratio | s a fit | reproduces |\n"
              "|---|---|---|---|---|---|---|---|---|")
        for key in sets:
            a, b = old[key], new.get(key)
            if b is None:
                print(f"| {key[0]} {key[1]} | `{a['family']}` -> not run | | | | | | | no |")
                continue
            ea, eb = (np.asarray(z["frame_err_d"], np.float64) for z in (a, b))
            same_out = bool(np.array_equal(np.isnan(ea), np.isnan(eb)))
            same_und = a["frames_undetermined"] == b["frames_undetermined"]
            d = float(np.nanmax(np.abs(eb - ea))) if same_out else float("nan")
            yes = a["family"] == b["family"] and same_out and same_und and d <= tol_d
            ok += yes
            pt = [z["focus_twin"]["noise"].get("photon_transfer", {}).get("full_well_e") for z in (a, b)]
            k = [z["focus_twin"]["noise"].get("capture_exposure", {}).get("exposure_ratio") for z in (a, b)]
            print(f"| {key[0]} {key[1]} | `{a['family']}` -> `{b['family']}` | "
                  f"{'same' if same_out and same_und else 'differ'} | {d:.4f} | {a['corrected_max_err_d']:.4f} -> "
                  f"{b['corrected_max_err_d']:.4f} | {pt[0]:.1f} -> {pt[1]:.1f} | {k[0]} -> {k[1]} | "
                  f"{a.get('seconds')} -> {b.get('seconds')} | {'yes' if yes else 'no'} |")
        print(f"\nreproduced: {ok} of {len(sets)} (the same family and frames left out, every frame's estimate within "
              f"{tol_d} D of the stored row's)")
    return out.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = ds.subset_parser(__doc__, "10:20")
    ap.add_argument("--check", action="store_true", help="the reproducibility check's sets (REPRO_SETS) instead")
    a = ap.parse_args(argv)
    order = ptc.plan()
    if a.check:
        order = [x for x in order if (x[1], x[2]) in REPRO_SETS]
    cmds = ds.commands(order, mode="ptc_exposure", out_file=REPRO_OUT if a.check else OUT)
    if a.run:
        ds.run(cmds, a.until, a.lock)
        return 0
    if a.plan:
        for s, c, k in order:
            print(s, c, k)
        print(f"\n{len(order)} sets")
        print("\n".join(cmds))
        return 0
    if a.check:
        return ds.tally_out(ap, a, lambda rows: compare(rows, ds.read([ds.ROOT / OUT])))
    return ds.tally_out(ap, a, lambda rows: ptc.tally(rows, {(c, k): s for s, c, k in order}, label=LABEL))


if __name__ == "__main__":
    sys.exit(main())
