"""benchmarks/ holds code only and runs as `python -m benchmarks.NAME`, scripts/ as `python -m scripts.NAME`: no
module edits sys.path to find the repository or its siblings, each imports as part of its package, the docs show
them run that way, and what the benchmarks write lives under results/ (issue 36)."""

from __future__ import annotations

import ast
import importlib
import re
import subprocess
import sys

import pytest
from conftest import ROOT

MODULES = sorted(".".join(p.relative_to(ROOT).with_suffix("").parts) for p in (ROOT / "benchmarks").rglob("*.py")
                 if p.name != "__init__.py")
SCRIPTS = sorted(f"scripts.{p.stem}" for p in (ROOT / "scripts").glob("*.py") if p.name != "__init__.py")


def _path_edits(source: str) -> list[int]:
    """Lines that call sys.path.insert / append."""
    return [n.lineno for n in ast.walk(ast.parse(source)) if isinstance(n, ast.Call)
            and isinstance(n.func, ast.Attribute) and n.func.attr in ("insert", "append")
            and ast.unparse(n.func.value) == "sys.path"]


def test_the_detector_finds_a_path_edit():
    assert _path_edits("import sys\nsys.path.insert(0, 'x')\nsys.path.append('y')\nl = []\nl.insert(0, 1)\n") == [2, 3]


def test_no_benchmark_edits_sys_path_except_to_read_the_tests_tolerances():
    bad = {}
    for p in (ROOT / "benchmarks").rglob("*.py"):
        src = p.read_text().splitlines()
        # bench_numerics imports the tolerances tests/ state (conftest, test_twin ...): its one edit adds tests/ dirs
        lines = [n for n in _path_edits("\n".join(src))
                 if not (p.name == "bench_numerics.py" and "ROOT / d" in src[n - 1])]
        if lines:
            bad[str(p.relative_to(ROOT))] = lines
    assert not bad, f"sys.path edits in benchmarks/ (run them as python -m benchmarks.NAME instead): {bad}"


def test_benchmarks_holds_code_only():
    other = [str(p.relative_to(ROOT)) for p in (ROOT / "benchmarks").rglob("*")
             if p.is_file() and p.suffix not in (".py", ".pyc") and "__pycache__" not in p.parts]
    assert not other, f"results and figures belong under results/, not benchmarks/: {other[:10]}"


@pytest.mark.parametrize("name", MODULES)
def test_every_benchmark_imports_as_a_module(name):
    importlib.import_module(name)  # module level only: every benchmark parses its arguments in main()


def test_a_benchmark_runs_with_python_m_from_the_root():
    r = subprocess.run([sys.executable, "-m", "benchmarks.bench_calibrate", "--help"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "usage:" in r.stdout, r.stderr[-2000:]


def test_no_script_edits_sys_path():
    bad = {str(p.relative_to(ROOT)): lines for p in (ROOT / "scripts").rglob("*.py")
           if (lines := _path_edits(p.read_text()))}
    assert not bad, f"sys.path edits in scripts/ (run them as python -m scripts.NAME instead): {bad}"


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_script_imports_as_a_module(name):
    importlib.import_module(name)  # module level only: the work runs under `if __name__ == "__main__"`


def test_a_script_runs_with_python_m_from_the_root():
    r = subprocess.run([sys.executable, "-m", "scripts.import_graph", "--help"], cwd=ROOT, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and "usage:" in r.stdout, r.stderr[-2000:]


def test_docs_and_shell_scripts_run_python_scripts_as_modules():
    """No `python scripts/NAME.py` (nor benchmarks/) left in a doc, a docstring or a shell script: the way they
    run is `python -m scripts.NAME`."""
    as_file = re.compile(r"(python3?|torchrun[^\n`]*?) +(scripts|benchmarks)/\w+\.py")
    skip = {"cache", ".git", "archive", "__pycache__", ".hypothesis"}
    bad = []
    for p in ROOT.rglob("*"):
        if (p.suffix in (".md", ".py", ".sh", ".sbatch") and p.is_file() and not skip & set(p.relative_to(ROOT).parts)
                and p.name != "test_benchmarks_layout.py"):
            bad += [f"{p.relative_to(ROOT)}: {m.group(0)}" for m in as_file.finditer(p.read_text(errors="replace"))]
    assert not bad, f"run these as python -m PACKAGE.NAME: {bad[:10]}"


def test_finished_training_logs_are_compressed_and_read_as_they_are():
    """results/training/<run>/: a finished run (train_summary.json) keeps its log gzip-compressed, and
    scripts.plot_training_curves reads it (training and validation rows) without unpacking."""
    from scripts.plot_training_curves import read_log

    runs = sorted(p.parent for p in (ROOT / "results" / "training").glob("*/train_summary.json"))
    assert runs
    for run in runs:
        assert not (run / "log.jsonl").exists() and (run / "log.jsonl.gz").is_file(), run.name
        train, val = read_log(run)
        assert train and val, run.name
