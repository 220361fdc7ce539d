"""`aat-diagnose`: where a DfF model's sim-to-real gap lies, which unmodelled effect causes it, and how far it
shrinks once that effect is simulated (method: docs/diagnosis.md).

    aat-diagnose ROOT --model M.onnx [--lens LENS] [--psf PSF.onnx] --out DIR [--retrain-steps N] [--force]
                 [--calibration CAM.json] [--max-megapixels MP] [--allow-outside-links]
    aat-diagnose --list-effects

Runs without torch (twins from the exported PSF surrogate); only --retrain-steps needs the train extra.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from .common import (
    add_list_option,
    add_reader_options,
    check_reader_options,
    parser,
    print_effects,
    run_guarded,
    threads_option,
)


def build_parser() -> argparse.ArgumentParser:
    p = parser("aat-diagnose", __doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_list_option(p, "--list-effects", print_effects, "list the registered effects and exit")
    p.add_argument("root", metavar="ROOT", help="a capture folder with ground truth, or a folder of them")
    p.add_argument("--model", required=True, help="the DfF model (.onnx) to diagnose")
    p.add_argument("--out", required=True, help="report folder (diagnosis.json, report.md, PNGs, diagnosis.rrd; "
                   "corrected_focus/<capture>/capture.json only when the diagnosis names a focus-metadata error "
                   "that its focus fit measured: otherwise the fit's distances are in the report, marked not "
                   "recommended, and no capture.json is written)")
    p.add_argument("--lens", help="lens file the model was trained for (default: found in lenses/ by name)")
    p.add_argument("--psf", help="PSF surrogate (.onnx) of that lens (default: found in models/; else ray tracing)")
    p.add_argument("--effects", help="only try these registered effects (comma-separated; default all)")
    p.add_argument("--calibration", help="camera calibration (aat-calibrate fit): the captures' reported focus is "
                   "corrected by its reported-focus error before the diagnosis")
    p.add_argument("--retrain-steps", type=int, default=0,
                   help="fine-tune the model with the named effects for this many steps and score it (needs aat-train)")
    p.add_argument("--torch-free", action="store_true",
                   help="never use the training simulator, even if torch is installed (torch-only effects are skipped)")
    p.add_argument("--threads", type=int, default=2, help="onnxruntime threads")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--force", action="store_true", help="replace an existing --out folder")
    add_reader_options(p)
    return p


def main(argv: list[str] | None = None) -> int:
    """The command; Ctrl-C or SIGTERM at any point is one line and exit status 130/143 (common.run_guarded)."""
    return run_guarded("aat-diagnose", _main, argv)


def _main(argv: list[str] | None) -> int:
    ap = build_parser()
    a = ap.parse_args(argv)
    check_reader_options(ap, a)
    a.threads = threads_option("aat-diagnose", ap, a.threads)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from aat_deploy.diagnose.session import DiagnoseError, run
    from aat_deploy.shipped import resolve

    a.model = str(resolve(a.model, "models"))
    a.lens = str(resolve(a.lens, "lenses")) if a.lens else None
    a.psf = str(resolve(a.psf, "models")) if a.psf else None
    from aat_deploy.errors import OutputError
    from aat_deploy.io.guard import check_output_dir

    out = Path(a.out)
    try:  # before any work: the report folder may be replaced, so it must never hold or sit in an input
        check_output_dir(out, [a.root, a.model, *(p for p in (a.lens, a.psf, a.calibration) if p)], a.force,
                         tool="aat-diagnose", nest_ok=[a.root])
    except OutputError as e:
        print(f"aat-diagnose: error: {e}", file=sys.stderr)
        return 2
    try:
        res = run(a.root, a.model, out, lens=a.lens, psf=a.psf, effects=a.effects, retrain_steps=a.retrain_steps,
                  threads=a.threads, seed=a.seed, force=a.force, quiet=a.quiet,
                  torch_free=a.torch_free, calibration=a.calibration, max_megapixels=a.max_megapixels,
                  allow_outside_links=a.allow_outside_links)
    except DiagnoseError as e:
        print(f"aat-diagnose: error: {e}", file=sys.stderr)
        return 1
    causes = [e for e in res["ranked_effects"] if e.get("explains_gap")]
    u = res.get("unexplained_share")
    print(f"gap {'significant' if res['gap_significant'] else 'not significant'}; {res['verdict'].replace('_', ' ')}"
          + "".join(f"; {e['effect']} ({e['share_shown']:.0%} of the gap)" for e in causes)
          + (f"; unexplained {u['shown']:.0%}" if u else "")
          + (f"; corrected focus distances in {out / 'corrected_focus'}"
             if (res.get("focus") or {}).get("corrected_recommended") else "")
          + f"; report in {out / 'report.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
