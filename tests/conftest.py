"""Shared test helpers: paths to the repository's lenses and to ../shared/data (optional), the tiny DfF model."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
LENSES = ROOT / "lenses"
SHARED = ROOT.parent / "shared" / "data"

torch.set_num_threads(1)  # 2-core machines: avoid OpenMP spin-waiting between tests


@pytest.fixture
def shared_lenses() -> Path:
    d = SHARED / "lenses"
    if not d.is_dir():
        pytest.skip(f"{d} not present (a user's clone has no ../shared/data)")
    return d


@pytest.fixture(scope="session")
def model_path(tmp_path_factory) -> Path:
    """The tiny contract-following DfF model of deploy_fixtures, built once per session."""
    from deploy_fixtures import tiny_model_path

    return tiny_model_path(tmp_path_factory)
