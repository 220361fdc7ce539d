"""aat-eval over the shipped captures: the shipped RF50 DfF models (AAT vs thin lens) in one table.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_eval [--root captures] [--out DIR] [--threads 2]
                                                            [--models NAME ...]

Runs `aat_deploy.eval.run.evaluate` exactly as `aat-eval ROOT --compare M1 M2 ...` does (metric depth, no
alignment) and prints the overall Markdown table (mean over the captures every model scored) with the wall-clock
time of the batch. The full output (per-capture tables, maps, plots, eval.rrd) stays in --out.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# paths under models/ (the baselines in models/reproduce/)
MODELS = ("rf50_dfvnet_aat_field", "rf50_dfvnet_aat", "reproduce/rf50_dfvnet_thin", "reproduce/rf50_aifnet_aat",
          "reproduce/rf50_aifnet_thin")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", type=Path, default=ROOT / "captures")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--models", nargs="+", default=list(MODELS), help="names under models/ (default: the RF50 ones)")
    args = ap.parse_args()
    from aat_deploy.eval.run import EvalOptions, evaluate

    out = args.out or Path(tempfile.mkdtemp(prefix="bench_eval_")) / "eval"
    rep = evaluate(args.root, [ROOT / "models" / f"{m}.onnx" for m in args.models], out,
                   EvalOptions(force=True, quiet=True), threads=args.threads)
    md = (out / "metrics.md").read_text().splitlines()
    start = next(i for i, ln in enumerate(md) if ln.startswith("## Overall"))
    end = next(i for i, ln in enumerate(md) if ln.startswith("## Per capture"))
    print("\n".join(md[start:end]).strip())
    print(f"\n{len(rep['captures'])} capture(s), {len(args.models)} models, {rep['seconds']:.1f} s "
          f"({args.threads} threads); failed: {rep['failed'] or 'none'}; full output in {out}")


if __name__ == "__main__":
    main()
