"""The linter .ci/run runs, here too, so that a targeted `pytest tests/test_lint.py` catches what CI would: ruff with
the project's rules (pyproject.toml [tool.ruff]: pyflakes, unused imports and names, undefined names, import
order)."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest
from conftest import ROOT


def _ruff() -> list[str]:
    exe = shutil.which("ruff")
    if exe:
        return [exe]
    r = subprocess.run([sys.executable, "-m", "ruff", "--version"], capture_output=True)
    if r.returncode != 0:
        pytest.skip("ruff is not installed (the dev extra: pip install -e '.[dev]')")
    return [sys.executable, "-m", "ruff"]


def test_the_rules_catch_an_unused_import_and_name(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\n\ndef f():\n    x = 1\n    return undefined_name\n")
    r = subprocess.run([*_ruff(), "check", "--config", str(ROOT / "pyproject.toml"), "--no-cache",
                        "--output-format", "concise", str(bad)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    assert {"F401", "F841", "F821"} <= {w for w in r.stdout.split() if w[:1] == "F" and w[1:].isdigit()}, r.stdout


def test_the_rules_catch_unsorted_imports(tmp_path):
    bad = tmp_path / "unsorted.py"
    bad.write_text("import sys\nimport json\n\nprint(json, sys)\n")
    r = subprocess.run([*_ruff(), "check", "--config", str(ROOT / "pyproject.toml"), "--no-cache",
                        "--output-format", "concise", str(bad)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and "I001" in r.stdout, r.stdout


def test_the_tree_is_clean():
    r = subprocess.run([*_ruff(), "check", "--no-cache", "--output-format", "concise", "."], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, "ruff check . (fix with `ruff check --fix .`):\n" + r.stdout[-3000:] + r.stderr[-500:]
