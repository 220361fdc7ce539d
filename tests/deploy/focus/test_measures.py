"""The focus measures' registry (aat_deploy.focus.measures.MEASURES): a new measure is one entry that the method's
configuration and its estimator take, with nothing else touched."""

from __future__ import annotations

import numpy as np
import pytest

from aat_deploy.focus import measures
from aat_deploy.focus.method import FocusConfig


def test_entries_and_their_exponents():
    assert set(measures.MEASURES) == {"lape", "sml", "mlap2", "tenengrad", "multiscale"}
    assert FocusConfig(measure="sml").tail_exponent == 0.5 and FocusConfig(measure="mlap2").tail_exponent == 1.0
    with pytest.raises(ValueError, match="unknown measure 'fog'.*lape"):
        FocusConfig(measure="fog")


def test_a_new_measure_is_one_entry(monkeypatch):
    def brightness(g, window_px, step, levels):  # not a good measure: it only has to be called
        return np.abs(g).astype(np.float32)

    monkeypatch.setitem(measures.MEASURES, "brightness", measures.FocusMeasure(brightness, tail_exponent=0.25))
    stack = np.random.default_rng(0).random((3, 3, 8, 8), dtype=np.float32)
    vol = measures.focus_volume(stack, "brightness")
    np.testing.assert_array_equal(vol, measures.grey(stack))
    assert FocusConfig(measure="brightness").tail_exponent == 0.25
