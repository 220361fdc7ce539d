"""The command line the phone calibration probes share (issue 33: `more_charts`, `tile_size`, `exact_tiles_order`):
--truth, --variants and --out, their one-line refusals before the truth is read, the log, and the result file that
records its own command."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def parser(doc: str, variants_default: str, variants_help: str | None = None) -> argparse.ArgumentParser:
    """An ArgumentParser described by doc's first line, with --truth, --variants and --out."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--truth", required=True, help="a render-truth map (aat-render-truth-map-v1; a repo path)")
    ap.add_argument("--variants", default=variants_default, help=variants_help)
    ap.add_argument("--out", required=True)
    return ap


def refuse_existing_out(ap, out: str) -> None:
    if Path(out).exists():
        ap.error(f"{out}: exists (choose another --out)")


def variants_of(ap, text: str, allowed: tuple) -> list[str]:
    """--variants (comma-separated) checked against allowed; none is an error too (nothing to run)."""
    variants = [v for v in text.split(",") if v]
    bad = [v for v in variants if v not in allowed]
    if bad:
        ap.error(f"--variants: {', '.join(bad)} not of {', '.join(allowed)}")
    if not variants:
        ap.error("nothing to run: --variants is empty")
    return variants


def load_truth(path: str, prog: str):
    """The render-truth map, or SystemExit with one line naming prog (before any render)."""
    from benchmarks.render_truth_map import load_or_exit

    return load_or_exit(path, prog)


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def write_result(out: str, prog: str, doc: str, truth: str, argv, rows: list, **extra) -> None:
    """{"what", "truth", **extra, "command", "rows"} written atomically to out; the command as typed
    (`python -m benchmarks.probes.PROG ARGS`)."""
    from aat_deploy.io.atomic import write_text_atomic

    args = argv if argv is not None else sys.argv[1:]
    write_text_atomic(out, json.dumps({"what": doc.split("\n")[0], "truth": truth, **extra,
                                       "command": f"python -m benchmarks.probes.{prog} " + " ".join(args),
                                       "rows": rows}, indent=1, default=float))
