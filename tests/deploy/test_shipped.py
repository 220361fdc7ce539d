"""What a name finds in models/: the depth models meant for use, the PSF surrogates listed apart, and never the
models kept in models/reproduce/ (found by path only, from any folder)."""

from __future__ import annotations

import os

import pytest
from conftest import ROOT

from aat_deploy.shipped import resolve, shipped_dir, shipped_hint, shipped_names


def test_names_list_depth_models_and_surrogates_apart_never_reproduce():
    depth, psf = shipped_names("models"), shipped_names("models", surrogates=True)
    assert "rf50_dfvnet_aat_field" in depth and "rf50_dfvnet_aat" in depth
    assert psf and all(n.startswith("psf_") for n in psf) and not any(n.startswith("psf_") for n in depth)
    reproduce = sorted(p.stem for p in (ROOT / "models" / "reproduce").glob("*.onnx"))
    assert "rf50_dfvnet_thin" in reproduce and "dff_dfvnet_aat" in reproduce
    assert not set(reproduce) & set(depth + psf)
    hint = shipped_hint("models")
    assert "rf50_dfvnet_aat_field" in hint and "PSF surrogates: psf_" in hint
    assert not any(n in hint.split("; PSF")[0].split(", ") for n in reproduce)
    assert "rf50_dfvnet_thin" not in hint


def test_reproduce_models_by_path_from_any_folder_not_by_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the README's relative paths, from elsewhere
    assert resolve("models/reproduce/rf50_dfvnet_thin.onnx", "models") == shipped_dir("models") / "reproduce" / \
        "rf50_dfvnet_thin.onnx"
    assert resolve("models/reproduce/rf50_dfvnet_thin", "models").is_file()  # suffix optional, as for names
    assert resolve("rf50_dfvnet_aat", "models") == shipped_dir("models") / "rf50_dfvnet_aat.onnx"
    assert not resolve("rf50_dfvnet_thin", "models").exists()  # a baseline is not found by its bare name
    assert not resolve("models/../models/rf50_dfvnet_aat.onnx", "models").exists()  # no climbing out


@pytest.mark.skipif(os.name == "nt", reason="paths with / only")
def test_an_existing_path_always_wins(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "models").mkdir()
    own = tmp_path / "models" / "rf50_dfvnet_aat.onnx"
    own.write_bytes(b"x")
    assert resolve("models/rf50_dfvnet_aat.onnx", "models") == own.relative_to(tmp_path)
