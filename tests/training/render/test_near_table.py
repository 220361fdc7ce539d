"""The torch simulator's focus table for a lens working nearer than the traced default (a phone lens)."""

from types import SimpleNamespace

import numpy as np

from aat_deploy.lens.io import load_lens
from aat_deploy.optics.focus_table import table_from_arrays
from aat_deploy.render import effects as fx
from training.render.simulator import Simulator, near_focus_table


def _source(near_m: float):
    d = np.linspace(0.01, 1.0 / near_m, 33)  # diopters, ascending
    table = table_from_arrays(d, 5.6 + 0.03 * d)
    return SimpleNamespace(numpy=SimpleNamespace(focus_table=lambda: table)), table


def test_a_surrogate_table_reaching_nearer_than_the_default_is_used():
    src, table = _source(0.05)
    assert near_focus_table(src) is table
    sim = Simulator(load_lens("lenses/cellphone_asphere.json"), src, fx.parse(["sensor_tilt"]))
    ctx = sim.context()
    assert ctx.focus_table() is table  # not traced: the default table stops at 0.2 m and refuses 0.07 m
    assert float(ctx.focus_table()(0.07)) > 5.6


def test_the_default_table_is_kept_for_lenses_working_from_0_2_m():
    src, _ = _source(0.2)
    assert near_focus_table(src) is None  # traced as always, so renders and their cache keys stay
    assert near_focus_table(None) is None
    assert near_focus_table(SimpleNamespace(numpy=SimpleNamespace(focus_table=lambda: None))) is None
