"""The models and lenses the project ships, found wherever aat-dff runs from.

In a clone (editable install, or PYTHONPATH) they are the repository's `models/` and `lenses/`. A plain
`pip install .` copies them as data files of the distribution into `<prefix>/share/aat-dff/{models,lenses}`
(pyproject.toml, `[tool.setuptools.data-files]`), found through the distribution's file list, so a venv, a
`--user` install and a system install all work from any folder.

Commands take a shipped file by name: `--model rf50_dfvnet_aat` (or `models/rf50_dfvnet_aat.onnx` from any folder),
`aat-lens info canon_rf50mm_f1.8`. A path that exists always wins.

What a name finds is what users are meant to use: the depth models and the PSF surrogates (`psf_*`, listed apart:
they model a lens's blur, they estimate no depth) at the top of `models/`. The models kept to reproduce the
benchmarks' rows (thin-lens baselines, ablations, superseded models) sit in `models/reproduce/`: no name finds or
lists them, a path does (`models/reproduce/rf50_dfvnet_thin.onnx`, from any folder too).
"""

from __future__ import annotations

import importlib.metadata
import sys
from pathlib import Path

from . import DISTRIBUTION

KINDS = {"models": ".onnx", "lenses": ".json"}
SURROGATE_PREFIX = "psf_"  # models/psf_<lens>.onnx: a lens's PSF surrogate, not a depth model


def _checkout() -> Path | None:
    """The repository this package runs from, if it runs from one (not an installed copy)."""
    root = Path(__file__).resolve().parents[1]
    return root if (root / "pyproject.toml").is_file() and (root / "aat_deploy").is_dir() else None


def shipped_dir(kind: str) -> Path | None:
    """The folder of the shipped `kind` ("models" or "lenses"), or None if this install has none."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}")
    root = _checkout()
    if root is not None and (root / kind).is_dir():
        return root / kind
    try:
        dist = importlib.metadata.distribution(DISTRIBUTION)
        files = dist.files or []
    except importlib.metadata.PackageNotFoundError:
        files = []
    for f in files:
        parts = f.parts
        for i in range(len(parts) - 2):
            if parts[i:i + 3] == ("share", DISTRIBUTION, kind):
                return Path(dist.locate_file(Path(*parts[:i + 3]))).resolve()
    guess = Path(sys.prefix) / "share" / DISTRIBUTION / kind
    return guess if guess.is_dir() else None


def shipped_names(kind: str, surrogates: bool = False) -> list[str]:
    """The names resolve() finds: for "models" the depth models, or with surrogates=True the PSF surrogates
    (never what models/reproduce/ holds)."""
    d = shipped_dir(kind)
    names = sorted(p.stem for p in d.glob(f"*{KINDS[kind]}")) if d else []
    if kind != "models":
        return names
    return [n for n in names if n.startswith(SURROGATE_PREFIX) == surrogates]


def resolve(arg: str | Path, kind: str) -> Path:
    """`arg` if that path exists; else the shipped file it names: a bare name with or without its suffix
    (`rf50_dfvnet_aat`, the top of the folder only), or a path under `<kind>/` as written in the README
    (`models/rf50_dfvnet_aat.onnx`, `models/reproduce/rf50_dfvnet_thin.onnx`) from any folder; else `arg`
    unchanged (the caller reports it missing, with shipped_hint)."""
    p = Path(arg)
    if p.exists():
        return p
    if len(p.parts) == 1 or (len(p.parts) >= 2 and p.parts[0] == kind and ".." not in p.parts):
        d = shipped_dir(kind)
        if d is not None:
            rel = Path(*p.parts[1:]) if len(p.parts) >= 2 else p
            for cand in (d / rel, d / (str(rel) + KINDS[kind])):
                if cand.is_file():
                    return cand
    return p


# models users ask for by name that are not shipped yet, and what to run instead (said in the missing-file error)
NOT_YET_SHIPPED = {
    "dfv_aat": "the any-camera model dfv_aat is not shipped yet, as no net meets its targets (BENCHMARKS.md, \"The "
               "any-camera model\"); the best so far, for any stack size, runs by path: "
               "models/reproduce/dfv_aat_route_v12_v10.onnx",
}


def not_shipped_note(name: str | Path) -> str:
    """'; <what to run instead>' when `name` is a model users ask for that is not shipped yet, else ''."""
    note = NOT_YET_SHIPPED.get(Path(str(name)).name.removesuffix(KINDS["models"]))
    return f"; {note}" if note and not resolve(name, "models").is_file() else ""


def shipped_hint(kind: str) -> str:
    """' (shipped: a, b, ...)' listing what resolve() accepts by name, or ''; models: the depth models, then
    the PSF surrogates apart."""
    names = shipped_names(kind)
    if kind == "models":
        psf = shipped_names(kind, surrogates=True)
        if not names and not psf:
            return ""
        return (f" (shipped depth models, usable by name: {', '.join(names) or 'none'}"
                + (f"; PSF surrogates: {', '.join(psf)}" if psf else "") + ")")
    return f" (shipped {kind}, usable by name: {', '.join(names)})" if names else ""
