"""The README does what it says: its set-up is two commands (the main job, the tests; .ci/run runs the second
exactly as written), its Python example runs and prints what it claims, its picture is made by a script, and the
documents it links to exist."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import cv2
import pytest
from conftest import ROOT
from test_install import readme_commands

README = (ROOT / "README.md").read_text()


def test_setup_is_two_commands_and_ci_runs_the_tests_as_written():
    main_job, tests = readme_commands()
    assert main_job.startswith("pip install . && aat-infer captures/sample_rf50 ")  # runs in tests/test_install.py
    assert tests == 'pip install -e ".[train,dev,gt]" && python -m pytest -q'
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert tests in [ln.strip() for ln in ci], ".ci/run must run the README's test command exactly"


def test_python_example_runs(tmp_path):
    code = re.search(r"```python\n(.*?)```", README, re.S).group(1)
    (tmp_path / "captures").symlink_to(ROOT / "captures")  # the example's relative path, outputs stay in tmp
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_WAIT_POLICY="PASSIVE")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    m = re.match(r"\((\d+), (\d+)\) ([0-9.]+)", r.stdout)
    assert m and (m[1], m[2]) == ("640", "960"), r.stdout
    assert float(m[3]) == pytest.approx(49.5616023 / 0.0375, rel=1e-6)  # focal length mm / pixel pitch mm
    assert "(640, 960)" in code  # the comment says what it prints
    out = tmp_path / "aat_out" / "api_sample"
    assert (out / "depth_m.tif").is_file() and (out / "points.ply").is_file() and (out / "recording.rrd").is_file()


def test_picture_is_made_by_its_script(tmp_path):
    assert "![" in README and "docs/sample.png" in README and (ROOT / "docs" / "sample.png").is_file()
    assert "python -m scripts.make_readme_figure" in README
    out = tmp_path / "sample.png"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_WAIT_POLICY="PASSIVE")
    r = subprocess.run([sys.executable, "-m", "scripts.make_readme_figure", "--out", str(out)],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    made, shipped = cv2.imread(str(out)), cv2.imread(str(ROOT / "docs" / "sample.png"))
    assert made.shape == shipped.shape  # the shipped picture is this script's output at its defaults


def test_linked_documents_exist():
    for link in re.findall(r"\]\(([^)#]+)\)", README):
        if not link.startswith("http"):
            assert (ROOT / link).exists(), link
    for name in ("shooting.md", "contracts.md", "runtime.md", "training.md", "internals.md", "diagnosis.md"):
        assert f"docs/{name}" in README, name


def test_layout_table_matches_the_tree():
    """Every folder of the two packages has its row in the Layout table, every row names a folder that exists, and
    every file a package row names (`name.py`, `data/glasses.json`, `effects/`) is in that folder."""
    section = README.split("\n## Layout\n", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `([^`]+)/` \| (.*) \|$", section, re.M)
    folders = {f for f, _ in rows}
    assert all((ROOT / f).is_dir() for f in folders), [f for f in folders if not (ROOT / f).is_dir()]
    packages = {str(p.parent.relative_to(ROOT)) for pkg in ("aat_deploy", "training")
                for p in (ROOT / pkg).rglob("__init__.py") if "__pycache__" not in p.parts}
    packages -= {"training", "aat_deploy/render/effects"}  # the package root's only file; effects/ is named in its row
    assert packages <= folders, sorted(packages - folders)
    for folder, what in rows:
        if folder.split("/")[0] not in ("aat_deploy", "training"):
            continue
        for name in re.findall(r"`([\w/.]+\.(?:py|json)|\w+/)`", what):
            assert (ROOT / folder / name).exists(), f"README Layout: {folder}/{name} does not exist"
