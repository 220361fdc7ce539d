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


def test_dry_run_passes_the_models_own_size_and_tile_and_only_flags_the_targets_have():
    """An edge-padded model (aat.size small_replicate, aat.tile_px 0): every dfv_aat row runs whole frames and the
    speed row times a net of its size; each flag of each printed command is one its target script defines."""
    import os
    import re

    model = ROOT / "models" / "reproduce" / "dfv_aat_pad_replicate.onnx"
    r = subprocess.run(["bash", str(SCRIPT), str(model), "lbl"], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "DRY": "1"})
    assert r.returncode == 0, r.stderr
    cmds = [c for c in r.stdout.splitlines() if c.startswith("python -m ")]
    assert len(cmds) == 11  # tiles probe, 4 + 2 lens rows, 2 tables, speed, gallery
    runtime = [c for c in cmds if "bench_runtime" in c]
    assert len(runtime) == 1 and "--anycam-size small_replicate" in runtime[0] and "--tile 0" in runtime[0]
    assert all("--tile 0" in c for c in cmds if "bench_anycam" in c)
    for c in cmds:
        module = c.split()[2]
        src = (ROOT / (module.replace(".", "/") + ".py")).read_text()
        for flag in re.findall(r"(?<=\s)--[a-z][a-z0-9-]*", c):
            assert f'"{flag}"' in src, f"{module} has no {flag}"
    assert not (ROOT / "results" / "anycam_lbl.json").exists()
