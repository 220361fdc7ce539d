"""Shared test helpers: paths to the repository's lenses and to ../shared/data (optional), the tiny DfF model;
float comparisons with stated relative tolerances; the strict numerics mode of the CI's second pass.

AAT_TEST_NUMERICS=strict (set by .ci/run for `pytest -m numerics`, with OMP_NUM_THREADS=1 and, on AVX-512 CPUs,
AVX2 kernels): torch runs only its deterministic algorithms, so that kernel-order differences between machines show
in CI rather than on a user's first `pytest`. Tests marked `numerics` compare floats from different kernels."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

try:
    import torch
except ImportError:  # the runtime's own tests need no torch
    torch = None

ROOT = Path(__file__).resolve().parents[1]
LENSES = ROOT / "lenses"
SHARED = ROOT.parent / "shared" / "data"
STRICT_NUMERICS = os.environ.get("AAT_TEST_NUMERICS", "") == "strict"

if torch is not None:
    torch.set_num_threads(1)  # 2-core machines: avoid OpenMP spin-waiting between tests (the strict pass too)
    if STRICT_NUMERICS:
        torch.use_deterministic_algorithms(True)  # an op without a deterministic kernel raises


def rel_err(actual, desired, scale=None) -> float:
    """max |actual - desired| / scale, scale = max |desired| unless given: the error of a float computation
    relative to the size of the values it works with. Rounding is relative to those, not to each element, so an
    element near 0 (a cancellation) gets the same absolute slack as the largest one."""
    a = np.asarray(actual.detach() if hasattr(actual, "detach") else actual, np.float64)
    d = np.asarray(desired.detach() if hasattr(desired, "detach") else desired, np.float64)
    assert a.shape == d.shape, (a.shape, d.shape)
    s = float(np.abs(d).max()) if scale is None else float(scale)
    return float(np.abs(a - d).max() / s)


def assert_close(actual, desired, rel: float, scale=None, what: str = "") -> None:
    """Fail unless rel_err(actual, desired, scale) <= rel; the message gives the measured value."""
    err = rel_err(actual, desired, scale)
    assert err <= rel, f"{what + ': ' if what else ''}relative difference {err:.2e} > {rel:.0e}"


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
