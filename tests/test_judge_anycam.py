"""scripts/judge_anycam.sh refuses what it cannot run, in one line, before any heavy command."""

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "judge_anycam.sh"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, timeout=60)


def test_usage_without_label():
    r = run("models/x.onnx")
    assert r.returncode == 2 and r.stderr.strip().startswith("usage: scripts/judge_anycam.sh")


def test_missing_model_named(tmp_path):
    missing = tmp_path / "nope.onnx"
    r = run(str(missing), "lbl")
    assert r.returncode == 2
    assert r.stderr.strip() == f"{missing}: no such model"
    assert not (ROOT / "results" / "anycam_lbl.json").exists()


def test_script_parses():
    assert subprocess.run(["bash", "-n", str(SCRIPT)]).returncode == 0
