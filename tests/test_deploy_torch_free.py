"""The runtime never imports torch: run it in a fresh interpreter where `import torch` raises."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

from conftest import ROOT
from deploy_fixtures import tiny_model_path, write_dng_capture

BLOCK_TORCH = textwrap.dedent("""
    import sys
    class _NoTorch:
        def find_spec(self, name, path=None, target=None):
            if name == "torch" or name.startswith("torch."):
                raise ImportError(f"torch is forbidden in the runtime (import {name})")
            return None
    sys.meta_path.insert(0, _NoTorch())
    sys.modules.pop("torch", None)
""")


def _run(code: str, tmp_path) -> subprocess.CompletedProcess:
    script = tmp_path / "run.py"
    script.write_text(BLOCK_TORCH + textwrap.dedent(code))
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_WAIT_POLICY="PASSIVE")
    return subprocess.run([sys.executable, str(script)], check=False, capture_output=True, text=True, timeout=180,
                          env=env, cwd=tmp_path)


def test_blocker_works(tmp_path):
    r = _run("import torch\n", tmp_path)
    assert r.returncode != 0 and "forbidden" in r.stderr


def test_runtime_runs_without_torch(tmp_path, tmp_path_factory):
    model = tiny_model_path(tmp_path_factory)
    cap = write_dng_capture(tmp_path / "cap", [0.7, 1.0, 1.6, 3.0])
    out = tmp_path / "out"
    r = _run(f"""
        import json, pkgutil, importlib, sys
        import aat_deploy
        for m in pkgutil.walk_packages(aat_deploy.__path__, "aat_deploy."):
            importlib.import_module(m.name)
        from aat_deploy.cli import infer, capture, view
        rc = infer.main([{str(cap)!r}, "--model", {str(model)!r}, "--out", {str(out)!r}, "--threads", "1", "-q"])
        assert rc == 0, rc
        rc = capture.main(["inspect", {str(cap)!r}, "--json"])
        assert rc == 0, rc
        print(json.dumps({{"torch_loaded": any(k == "torch" or k.startswith("torch.") for k in sys.modules)}}))
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(r.stdout.strip().splitlines()[-1]) == {"torch_loaded": False}
    assert (out / "depth_m.npy").is_file() and (out / "recording.rrd").is_file()
