"""Every command of pyproject.toml behaves alike: --version, -q/--quiet (on every subcommand), the exit status
stated in --help, required positionals shown as required; without the train extra, the commands that need torch
say in one line how to install it."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
import textwrap
import tomllib

import pytest
from conftest import ROOT

from aat_deploy import DISTRIBUTION, __version__

SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


def _main(name: str):
    module, func = SCRIPTS[name].split(":")
    return getattr(importlib.import_module(module), func)


def _help(name: str, args: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as e:
        _main(name)([*args, "--help"])
    assert e.value.code == 0
    return " ".join(capsys.readouterr().out.split())  # argparse wraps lines: compare words


def _subcommands(text: str) -> list[str]:
    m = re.search(r"usage: \S+ .*?\{([a-z,-]+)\}", text)  # sub-commands, hyphenated ones too (focus-map)
    return m.group(1).split(",") if m else []


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_version_quiet_and_exit_status(name, capsys):
    with pytest.raises(SystemExit) as e:
        _main(name)(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"{name} {__version__} ({DISTRIBUTION})"
    top = _help(name, [], capsys)
    assert "exit status: 0 all done; 1 some capture or file failed" in top
    assert "2 usage error or nothing could be run" in top
    assert "see above" not in top
    subs = _subcommands(top)
    for args in ([[s] for s in subs] or [[]]):
        text = _help(name, args, capsys)
        assert "-q, --quiet" in text, f"{name} {' '.join(args)}: no -q/--quiet"
        assert "exit status: 0 all done" in text
        assert "see above" not in text


@pytest.mark.parametrize("name, positionals", [("aat-render", "RGB DEPTH"), ("aat-diagnose", "ROOT"),
                                                ("aat-infer", "CAPTURE_DIR [CAPTURE_DIR ...]"),
                                                ("aat-eval", "ROOT")])
def test_required_positionals_shown_as_required(name, positionals, capsys):
    usage = _help(name, [], capsys).split(" options:")[0]
    assert re.search(rf"(^|\s){re.escape(positionals)}(\s|$)", usage), usage
    assert f"[{positionals.split()[0]}]" not in usage


def test_list_effects_needs_no_other_argument(capsys):
    for name in ("aat-render", "aat-diagnose"):
        with pytest.raises(SystemExit) as e:
            _main(name)(["--list-effects"])
        assert e.value.code == 0 and "vignetting" in capsys.readouterr().out


BLOCK_TORCH = textwrap.dedent("""
    import sys
    class _NoTorch:  # as if the train extra were not installed
        def find_spec(self, name, path=None, target=None):
            if name == "torch" or name.startswith("torch."):
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None
    sys.meta_path.insert(0, _NoTorch())
    sys.modules.pop("torch", None)
""")


@pytest.mark.parametrize("name, args", [
    ("aat-train", ["--lens", "lenses/canon_ef50mm_f1.8.json", "--out", "{tmp}/run", "--preset", "tiny"]),
    ("aat-train", ["--config", "configs/dff_dfvnet_aat.json", "--out", "{tmp}/run2"]),
    ("aat-psf", ["fit", "--config", "configs/psf_rf50.json"]),
    ("aat-render", ["captures/sample_rf50/gt_aif.png", "captures/sample_rf50/gt_depth_m.npy", "--lens",
                    "lenses/canon_rf50mm_f1.8.json", "--focus-m", "1,2", "--out", "{tmp}/cap"]),
    ("aat-lens", ["spot", "lenses/canon_rf50mm_f1.8.json", "--field-deg", "10", "--focus-m", "2"]),
])
def test_commands_needing_torch_say_how_to_install_it(name, args, tmp_path):
    module, func = SCRIPTS[name].split(":")
    argv = [a.format(tmp=tmp_path) for a in args]
    code = BLOCK_TORCH + f"import {module} as m\nsys.exit(m.{func}({argv!r}))\n"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_WAIT_POLICY="PASSIVE")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env, cwd=ROOT)
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert f'pip install "{DISTRIBUTION}[train]"' in r.stderr and r.stderr.startswith(f"{name}: ")
    assert not any((tmp_path / p).exists() for p in ("run", "run2", "cap"))  # nothing written


def test_lens_info_runs_without_torch(tmp_path):
    code = BLOCK_TORCH + ("from training.cli.lens import main\n"
                          "sys.exit(main(['info', 'lenses/canon_rf50mm_f1.8.json', '--json']))\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env, cwd=ROOT)
    assert r.returncode == 0 and '"efl_mm"' in r.stdout, r.stderr[-1000:]
