"""bench_calibrate with one of `exact_tiles_order`'s OPTIONS applied to the fit (issue 33; docs/calibration.md, "The
middle field's bias, and radial powers beyond rho^12"): the model's and the format's module constants changed for
the whole run, so that an option declared for adoption is scored on every lens as part a scores it.

    OMP_NUM_THREADS=1 python -m benchmarks.probes.patched_bench --option "radial to 20" -- \
        --lenses rf50,paper50,ef50 --parts map --boot 50 --out results/calibrate_map_radial20.json
"""

from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    from benchmarks import bench_calibrate as B
    from benchmarks.probes.exact_tiles_order import OPTIONS, edge_weight_patched, patched

    argv = list(sys.argv[1:] if argv is None else argv)
    rest = argv[argv.index("--") + 1:] if "--" in argv else []
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--option", required=True, help=f"of: {'; '.join(OPTIONS)}")
    a = ap.parse_args(argv[:argv.index("--")] if "--" in argv else argv)
    if a.option not in OPTIONS:
        ap.error(f"--option {a.option!r}: not of {'; '.join(OPTIONS)}")
    if not rest:
        ap.error("give bench_calibrate's arguments after --")
    with patched(OPTIONS[a.option]), edge_weight_patched(OPTIONS[a.option]):
        return B.main(rest)


if __name__ == "__main__":
    sys.exit(main())
