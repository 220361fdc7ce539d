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
"""

from __future__ import annotations

import sys

from aat_deploy.io.atomic import write_text_atomic
from benchmarks.probes import focus_dense_subset as ds
from benchmarks.probes import focus_ptc_subset as ptc

OUT = "results/focus_exposure_subset.jsonl"
LABEL = "photon transfer, floor at the capture's exposure"


def main(argv: list[str] | None = None) -> int:
    ap = ds.subset_parser(__doc__, "10:20")
    a = ap.parse_args(argv)
    order = ptc.plan()
    cmds = ds.commands(order, mode="ptc_exposure", out_file=OUT)
    if a.run:
        ds.run(cmds, a.until, a.lock)
        return 0
    if a.plan:
        for s, c, k in order:
            print(s, c, k)
        print(f"\n{len(order)} sets")
        print("\n".join(cmds))
        return 0
    if not a.tally:
        ap.error("--plan or --tally")
    for f in a.tally:
        if not f.is_file():
            ap.error(f"--tally {f}: no such results file")
    text = ptc.tally(ds.read(a.tally), {(c, k): s for s, c, k in order}, label=LABEL)
    print(text)
    if a.out:
        write_text_atomic(a.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
