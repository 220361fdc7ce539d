"""The runtime is the ground floor: `aat_deploy` never imports `training` (nor torch), nothing imports in a cycle
and no library module imports a command-line module (scripts/import_graph.py reads the imports), and every
`aat_deploy` module imports in an interpreter where `training` and `torch` cannot be imported. What the runtime
gets from the torch side comes through the extensions the training package declares (`aat_deploy.extensions`)."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import textwrap

from conftest import LENSES, ROOT

BLOCK = textwrap.dedent("""
    import sys
    class _Block:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("torch", "training"):
                raise ImportError(f"blocked in the runtime: {name}")
            return None
    sys.meta_path.insert(0, _Block())
""")


def _import_graph():
    """scripts/import_graph.py as a module."""
    if "import_graph" not in sys.modules:
        spec = importlib.util.spec_from_file_location("import_graph", ROOT / "scripts" / "import_graph.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules["import_graph"] = mod  # its dataclass looks its module up
        spec.loader.exec_module(mod)
    return sys.modules["import_graph"]


def test_import_graph_has_no_cycle_no_cli_import_and_no_arrow_down_from_the_runtime():
    r = _import_graph().report(ROOT)
    assert r["cycles"] == []
    assert [(e.src, e.dst) for e in r["library_to_cli"]] == []
    assert [(e.src, e.dst) for e in r["deploy_to_training"]] == []
    assert r["modules"] > 100 and len(r["training_to_deploy"]) > 50  # the reader sees the tree


def test_import_graph_finds_what_it_is_meant_to(tmp_path):
    """The reader on a made-up tree: a lazy arrow, a cycle through a relative `from . import mod`, a library module
    importing a CLI module (which closes a second cycle through the lazy arrow)."""
    files = {
        "aat_deploy/__init__.py": "", "aat_deploy/a.py": "def f():\n    from training.b import g\n",
        "aat_deploy/c.py": "from . import d\n", "aat_deploy/d.py": "from aat_deploy import c\n",
        "training/__init__.py": "", "training/b.py": "from training.cli import run\n",
        "training/cli/__init__.py": "", "training/cli/run.py": "import aat_deploy.a\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    r = _import_graph().report(tmp_path)
    assert [(e.src, e.dst, e.lazy) for e in r["deploy_to_training"]] == [("aat_deploy.a", "training.b", True)]
    assert r["cycles"] == [["aat_deploy.a", "training.b", "training.cli.run"], ["aat_deploy.c", "aat_deploy.d"]]
    assert [(e.src, e.dst) for e in r["library_to_cli"]] == [("training.b", "training.cli.run")]


def test_import_graph_finds_folders_that_import_each_other(tmp_path):
    """No module cycle, but the folders `p` and `q` import each other (the shape of the old lens <-> optics pair);
    a subfolder is its own folder, so `p -> p.sub` alone is no pair."""
    files = {
        "aat_deploy/__init__.py": "", "aat_deploy/p/__init__.py": "", "aat_deploy/q/__init__.py": "",
        "aat_deploy/p/schema.py": "", "aat_deploy/p/reader.py": "from ..q.tool import f\n",
        "aat_deploy/q/tool.py": "from aat_deploy.p.schema import X\n",
        "aat_deploy/p/sub/__init__.py": "", "aat_deploy/p/user.py": "import aat_deploy.p.sub\n",
        "training/__init__.py": "",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    r = _import_graph().report(tmp_path)
    assert r["cycles"] == []
    assert [(a, b, [(e.src, e.dst) for e in ab], [(e.src, e.dst) for e in ba]) for a, b, ab, ba in r["folder_pairs"]] \
        == [("aat_deploy.p", "aat_deploy.q", [("aat_deploy.p.reader", "aat_deploy.q.tool")],
             [("aat_deploy.q.tool", "aat_deploy.p.schema")])]


# Folders that still import each other (issue 36's phase B takes these apart); the list may shrink, never grow.
KNOWN_FOLDER_PAIRS = {  # ("aat_deploy", X): the top level holds both the API (above X) and errors (below it)
    ("aat_deploy", "aat_deploy.anycam"), ("aat_deploy", "aat_deploy.capture"), ("aat_deploy", "aat_deploy.focus"),
    ("aat_deploy", "aat_deploy.infer"), ("aat_deploy", "aat_deploy.io"), ("aat_deploy", "aat_deploy.optics"),
    ("aat_deploy.calibrate", "aat_deploy.focus"), ("aat_deploy.capture", "aat_deploy.render.effects"),
    ("aat_deploy.render", "aat_deploy.render.effects"), ("training.data", "training.render"),
    ("training.nets", "training.train"), ("training.optics", "training.psf"),
}


def test_no_new_folders_import_each_other():
    pairs = {(a, b) for a, b, _, _ in _import_graph().report(ROOT)["folder_pairs"]}
    assert ("aat_deploy.lens", "aat_deploy.optics") not in pairs  # lens files sit above optics (aat_deploy/lens/io)
    assert pairs - KNOWN_FOLDER_PAIRS == set(), "new folders importing each other: python -m scripts.import_graph"


def test_every_runtime_module_imports_without_training_and_torch(tmp_path):
    """With `training` and `torch` unimportable every aat_deploy module imports; the
    torch-optional path (tracing a best-focus map for a lens that has none) says in one line what is missing."""
    lens_copy = tmp_path / "lenses" / "rf50_copy.json"
    lens_copy.parent.mkdir()
    shutil.copy(LENSES / "canon_rf50mm_f1.8.json", lens_copy)
    code = BLOCK + textwrap.dedent(f"""
        import importlib, json, pkgutil, sys
        import aat_deploy
        failed = {{}}
        for m in pkgutil.walk_packages(aat_deploy.__path__, "aat_deploy."):
            try:
                importlib.import_module(m.name)
            except ImportError as e:
                failed[m.name] = str(e)
        from aat_deploy import extensions
        from aat_deploy.focus.bestfocus import BestFocusError, for_lens
        try:
            for_lens({str(lens_copy)!r})
            err = None
        except BestFocusError as e:
            err = str(e)
        try:
            extensions.load("best_focus_tracer")
            unavailable = None
        except extensions.ExtensionUnavailable as e:
            unavailable = str(e)
        print(json.dumps({{"failed": failed, "tracer": repr(extensions.load("best_focus_tracer", optional=True)),
                           "unavailable": unavailable,
                           "declared": extensions.declared(), "error": err,
                           "loaded": sorted(k for k in sys.modules if k.split(".")[0] in ("torch", "training"))}}))
    """)
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_WAIT_POLICY="PASSIVE")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["failed"] == {}
    assert out["loaded"] == []
    assert out["declared"] == {"best_focus_tracer": "training.optics.field_focus:coarse_best_focus_map",
                               "real_ray_focus_table": "training.psf.geometry:focus_table",
                               "chromatic_tracer": "training.render.chromatic_trace:ThreeWavelengths",
                               "tolerance_tracer": "training.optics.tolerance:traced_perturbation",
                               "torch_twin_renderer": "training.render.torch_twin:torch_twin_renderer"}
    assert out["tracer"] == "None"  # optional: the caller has a torch-free fallback
    # without `optional` a declared extension that cannot load is one line saying why, not a None that fails later
    assert out["unavailable"] == ("extension 'best_focus_tracer' (training.optics.field_focus:coarse_best_focus_map) "
                                  "needs torch: pip install 'aat-dff[train]'")
    err = out["error"]
    assert err and "\n" not in err and "rf50_copy.json" in err and "torch is not installed" in err


def test_declared_extension_loads_with_the_train_extra():
    import pytest

    pytest.importorskip("torch")
    from aat_deploy import extensions
    from training.optics.field_focus import coarse_best_focus_map

    assert extensions.load("best_focus_tracer") is coarse_best_focus_map
    assert all(extensions.load(name) is not None for name in extensions.declared())  # every declaration resolves
    assert extensions.load("no_such_extension", optional=True) is None
    with pytest.raises(extensions.ExtensionUnavailable, match=r"^extension 'no_such_extension' is not declared "
                                                               r"by this install \(declared: best_focus_tracer, "):
        extensions.load("no_such_extension")
