"""A plain (not editable) `pip install .` from a clean copy of the repository into a fresh venv: the README's first
command works as written, and the installed commands find the shipped models and lenses from any folder.

The venv sees the packages of the environment running the tests (numpy, onnxruntime, rerun, torch, ... are not
downloaded again), wherever they live: the system's site-packages, or the user's own virtualenv (issue 37: a venv
made with only --system-site-packages from a virtualenv's python sees the base interpreter's packages, not the
virtualenv's, so torch installed there was invisible). aat-dff itself is the venv's own copy: the test checks that
the code and the data come from the venv, not the clone.
About half a minute (venv, wheel build, two runs on the shipped sample)."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import site
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import pytest
from conftest import ROOT


def readme_commands() -> list[str]:
    """The README's set-up: the two commands of its first bash block (the main job, the tests)."""
    block = re.search(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    return [re.sub(r"\s+#.*$", "", ln).strip() for ln in block.strip().splitlines()]


def _clean_copy(dst):
    """The files a fresh clone has (tracked, plus new files not ignored), as they are in the work tree."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: cannot tell which files a clone has")
    names = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, check=True).stdout.split(b"\0")
    for n in filter(None, names):
        src = ROOT / os.fsdecode(n)
        if src.is_file():
            (dst / os.fsdecode(n)).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst / os.fsdecode(n))


def _see_this_environment(venv):
    """Let `venv` see what this interpreter sees, after its own packages: its site directories as .pth lines (a
    .pth line adds the folder only; the .pth files inside it, such as an editable install's finder, are not run,
    so the clone is not imported through the user's editable install)."""
    ask = "import sysconfig, json; print(json.dumps(sysconfig.get_paths()['purelib']))"
    inner = json.loads(subprocess.run([str(venv / "bin" / "python"), "-c", ask], capture_output=True, text=True,
                                      check=True).stdout)
    user = [site.getusersitepackages()] if site.ENABLE_USER_SITE else []
    outer = dict.fromkeys(p for p in (*site.getsitepackages(), *user, sysconfig.get_paths()["purelib"],
                                      sysconfig.get_paths()["platlib"]) if os.path.isdir(p))
    (Path(inner) / "_aat_test_outer_environment.pth").write_text("".join(f"{p}\n" for p in outer))


def test_plain_install_runs_the_readme_from_a_clean_copy(tmp_path):
    clone, venv, elsewhere = tmp_path / "clone", tmp_path / "venv", tmp_path / "elsewhere"
    clone.mkdir()
    elsewhere.mkdir()
    _clean_copy(clone)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    _see_this_environment(venv)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.update(PATH=f"{venv / 'bin'}:{env.get('PATH', '')}", VIRTUAL_ENV=str(venv), OMP_WAIT_POLICY="PASSIVE",
               PIP_DISABLE_PIP_VERSION_CHECK="1")
    run = lambda cmd, cwd: subprocess.run(cmd, shell=isinstance(cmd, str), cwd=cwd, env=env, capture_output=True,
                                          text=True, timeout=600)

    main_job = readme_commands()[0]
    assert main_job.startswith("pip install . && aat-infer "), main_job  # plain install, then the main job
    r = run(["bash", "-c", main_job], clone)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    out = re.search(r"--out (\S+)", main_job).group(1)
    summary = json.loads((clone / out / "summary.json").read_text())
    assert summary["model"]["path"].startswith(str(venv / "share" / "aat-dff" / "models"))

    py = venv / "bin" / "python"
    code = "import aat_deploy, training, importlib.metadata as m; print(aat_deploy.__file__); " \
           "print(training.__file__); print(m.version('aat-dff'))"
    r = run([str(py), "-c", code], elsewhere)
    site = str(venv / "lib")
    lines = r.stdout.split()
    assert r.returncode == 0 and lines[0].startswith(site) and lines[1].startswith(site), r.stdout + r.stderr
    assert not (venv / "lib").joinpath("aat_deploy").exists()  # sanity: the package sits in site-packages
    # the extensions the training side declares come from the installed metadata (no pyproject.toml there)
    code = ("import json; from aat_deploy import extensions as x\n"
            "try:\n    got = x.load('best_focus_tracer').__module__\n"
            "except x.ExtensionUnavailable as e:\n    got = 'unavailable: ' + str(e)\n"
            "print(json.dumps([x.declared(), got]))")
    r = run([str(py), "-c", code], elsewhere)
    assert r.returncode == 0, r.stderr[-2000:]
    declared, module = json.loads(r.stdout)
    with open(clone / "pyproject.toml", "rb") as f:  # every extension pyproject.toml declares, as installed
        expected = tomllib.load(f)["project"]["entry-points"]["aat_deploy.extensions"]
    assert declared == expected and "torch_twin_renderer" in declared, declared
    if importlib.util.find_spec("torch") is not None:  # torch where the tests run: the venv sees it too
        assert module == "training.optics.field_focus", module
    else:  # the runtime alone: a one-line reason, not a None
        assert module == ("unavailable: extension 'best_focus_tracer' (training.optics.field_focus:"
                          "coarse_best_focus_map) needs torch: pip install 'aat-dff[train]'"), module

    # from another folder: the model by the README's relative name and by its bare name, a lens by name
    r = run(["aat-infer", str(clone / "captures" / "sample_rf50"), "--model", "models/reproduce/dff_dfvnet_thin.onnx",
             "--out", "o", "-q", "--no-recording"], elsewhere)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (elsewhere / "o" / "points.ply").is_file()
    # the classical method with a shipped lens by name: its best-focus map is shipped beside it
    r = run(["aat-infer", str(clone / "captures" / "sample_rf50"), "--method", "focus", "--lens", "canon_rf50mm_f1.8",
             "--out", "f", "-q", "--no-recording"], elsewhere)
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((elsewhere / "f" / "summary.json").read_text())
    assert summary["model"]["mapping"] == "aberration_aware", summary["model"]
    assert summary["model"]["best_focus_map"].startswith(str(venv / "share" / "aat-dff" / "lenses" / "best_focus"))
    r = run(["aat-lens", "info", "canon_rf50mm_f1.8", "--json"], elsewhere)
    assert r.returncode == 0 and json.loads(r.stdout)["efl_mm"] > 0, r.stderr[-2000:]
    r = run(["aat-infer", str(clone / "captures" / "sample_rf50"), "--model", "no_such_model", "--out", "x"],
            elsewhere)
    assert r.returncode == 2 and "rf50_dfvnet_aat_field" in r.stderr  # the error names what is shipped
    r = run(["aat-capture", "--version"], elsewhere)
    assert r.stdout.strip().endswith("(aat-dff)")
