"""Benchmarks: scripts that measure something and print a table for BENCHMARKS.md. Code only: what they write
(results, figures, run logs) lives under the repository's `results/` tree (superseded runs in `results/archive/`).

Run each from the repository root as a module, `python -m benchmarks.NAME [...]` (so that `aat_deploy`, `training`
and the benchmarks' shared helpers, e.g. `benchmarks.timing`, import from this checkout). Exploratory probes, which
choose nothing, are in `benchmarks/probes/`.
"""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"  # every benchmark's JSON results; figures in RESULTS / "figures"
FIGURES = RESULTS / "figures"
