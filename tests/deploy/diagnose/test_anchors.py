"""The binning correction's anchors (`aat_deploy/diagnose/anchors.py`) on a synthetic correction: a known function of
focus, sharp near each region's focus, stands in for the full-resolution renders (`anchor_deltas`), and the per-frame
estimate errs by the correction's error at the true focus (what a misinterpolated correction does to the fit)."""

from types import SimpleNamespace

import numpy as np
import pytest

from aat_deploy.diagnose import anchors as A

GRID = np.arange(1.0, 3.0001, 0.06)  # the sweep's grid, diopters
BASE = np.array([1.5, 1.9, 2.3])  # reported focus (diopters); the twin's own frames
TRUE = BASE - 0.07  # the true focus: the metadata 0.07 D off
PEAKS = np.array([1.44, 1.82, 2.25, 1.6])  # each region's sharpest focus (diopters)


def delta(f_d):
    """(R, S) the binning correction at focus f_d (S,): a narrow bump (0.03 D) around each region's focus."""
    return 0.8 * np.exp(-(((np.asarray(f_d)[None, :] - PEAKS[:, None]) / 0.03) ** 2))


def per_channel_delta(f_d):
    """(R, S, C): the channels' own corrections, the mean's bump scaled by 0.5, 1 and 1.5 (their mean: `delta`)."""
    return delta(f_d)[..., None] * np.array([0.5, 1.0, 1.5])


def make(monkeypatch):
    """(state, raw sweep, estimate, the anchor_deltas calls' focus in diopters) with anchor_deltas faked."""
    calls = []

    def fake_deltas(state, chain, focus_m, per_channel=False):
        calls.append([1.0 / np.asarray(f, np.float64) for f in focus_m])
        return [(1.0 / np.asarray(f, np.float64), (per_channel_delta if per_channel else delta)(1.0 / np.asarray(f, np.float64)))
                for f in focus_m]

    monkeypatch.setattr(A, "anchor_deltas", fake_deltas)
    cap = SimpleNamespace(focus_m=1.0 / BASE, name="c")
    state = SimpleNamespace(caps=[cap], chain=[], seed=0, tb=SimpleNamespace(has_stack_hook=lambda e: False),
                            twins=SimpleNamespace(true_focus=lambda c, chain, seed: 1.0 / BASE))
    raw = SimpleNamespace(grid_d=GRID, base_d=BASE[None, :], floor_c=None,
                          with_correction=lambda corr: SimpleNamespace(corr=corr))

    def estimate(data):
        """(1, S): the truth, moved by the correction's mean error (log units) at the truth, 0.1 D per log unit."""
        corr = data.corr[0] if data.corr.ndim == 3 else data.corr[0].mean(-1)  # per channel: their mean
        got = np.stack([np.interp(TRUE, GRID, row) for row in corr])
        return (TRUE + 0.1 * (got - delta(TRUE)).mean(0))[None, :]

    return state, raw, estimate, calls


@pytest.fixture
def setup(monkeypatch):
    return make(monkeypatch)


def test_dense_anchoring_off_anchors_at_the_reported_focus_and_the_estimates_only(setup, monkeypatch):
    state, raw, estimate, calls = setup
    monkeypatch.setattr(A, "DENSE_ANCHORS", False)
    data, rep = A.reanchored_sweep(state, raw, estimate)
    assert len(calls) == 2 and np.allclose(calls[0][0], BASE)  # the twin's own focus, then the first estimates
    assert "dense_anchors_d" not in rep and not any(k.startswith("reanchored_2") for k in rep)
    assert rep["moved_d"][0] >= A.REANCHOR_D and np.allclose(rep["reanchored_d"][0], calls[1][0], atol=1e-4)


def test_dense_anchoring_brings_the_estimates_to_the_truth(setup, monkeypatch):
    state, raw, estimate, calls = setup
    monkeypatch.setattr(A, "DENSE_ANCHORS", False)
    plain = estimate(A.reanchored_sweep(state, raw, estimate)[0])[0]
    calls.clear()
    monkeypatch.setattr(A, "DENSE_ANCHORS", True)
    data, rep = A.reanchored_sweep(state, raw, estimate)
    dense = estimate(data)[0]
    assert np.abs(plain - TRUE).max() > 0.01  # anchored where the estimates were, the fit is still misled ...
    assert np.abs(dense - TRUE).max() < 0.7 * np.abs(plain - TRUE).max()  # ... anchored densely around them less
    # the dense sets straddle the estimates after the ordinary re-anchoring, 1 and 2 steps either side
    est = estimate(SimpleNamespace(corr=A.correction(GRID, [[(c[0], delta(c[0])) for c in calls[:2]]])))[0]
    steps = [c[0] - est for c in calls[2:6]]
    assert np.allclose(steps, [[j * A.DENSE_STEP_D] * 3 for j in (-1, 1, -2, 2)])
    assert rep["dense_anchors_d"] == A.DENSE_STEP_D
    # then re-anchored until every estimate lies within REANCHOR_AGAIN_D of an anchor, at most REANCHOR_ROUNDS times
    anchored = np.concatenate([c[0] for c in calls])
    assert np.abs(dense[:, None] - anchored[None, :]).min(1).max() < A.REANCHOR_AGAIN_D or \
        len(calls) == 6 + A.REANCHOR_ROUNDS


def test_dense_anchoring_only_past_its_trigger(setup, monkeypatch):
    state, raw, estimate, calls = setup
    monkeypatch.setattr(A, "DENSE_ANCHORS", True)
    monkeypatch.setattr(A, "DENSE_MOVED_D", 0.2)  # the first estimates move 0.07 D: not triggered
    _, rep = A.reanchored_sweep(state, raw, estimate)
    assert len(calls) == 2 and "dense_anchors_d" not in rep
    monkeypatch.setattr(A, "DENSE_MOVED_D", 0.05)
    calls.clear()
    _, rep = A.reanchored_sweep(state, raw, estimate)
    assert len(calls) > 6 and rep["dense_anchors_d"] == A.DENSE_STEP_D


@pytest.mark.parametrize("floor", [False, True])
def test_per_channel_correction_only_under_a_floor_and_only_when_asked(setup, monkeypatch, floor):
    """`PER_CHANNEL`: each channel's own correction (n, R, K, C), interpolated per channel as the mean's is, goes to
    `with_correction` only when the sweep carries an expected floor (without one the channel mean is all the twin has);
    off, the channel mean (n, R, K) as before."""
    state, raw, estimate, calls = setup
    raw.floor_c = np.ones(1) if floor else None
    monkeypatch.setattr(A, "PER_CHANNEL", False)
    off, _ = A.reanchored_sweep(state, raw, estimate)
    assert off.corr.shape == (1, len(PEAKS), len(GRID))
    monkeypatch.setattr(A, "PER_CHANNEL", True)
    on, _ = A.reanchored_sweep(state, raw, estimate)
    if not floor:
        assert np.array_equal(on.corr, off.corr)
        return
    assert on.corr.shape == (1, len(PEAKS), len(GRID), 3)
    assert np.allclose(on.corr.mean(-1), off.corr)  # the channels' mean is the plain correction ...
    assert np.allclose(on.corr[..., 0], 0.5 * off.corr) and np.allclose(on.corr[..., 2], 1.5 * off.corr)  # ... each its own


def test_sweep_takes_a_per_channel_correction_under_each_channels_floor():
    """`SweepData.with_correction` with (n, R, K, C): each channel's noiseless measure moves by its own delta under
    its own floor (with equal deltas the same as the (n, R, K) one); without a floor, their mean is added."""
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose.noisefloor import compose

    rng = np.random.default_rng(3)
    n, r, k, s, c = 1, 4, len(GRID), 3, 3
    sig = rng.normal(-3, 1, (n, r, k, c))
    floor = np.exp(rng.normal(-4, 0.5, (n, r, k, c)))
    cap = rng.normal(-3, 1, (n, r, s))
    rep = np.broadcast_to(BASE, (n, s)).copy()
    xy = np.zeros((r, 2))
    d = ff.SweepData(GRID, compose(sig, floor), cap, rep, rep.copy(), xy, signal_c=sig, floor_c=floor)
    one = rng.normal(0, 0.3, (n, r, k))
    assert np.allclose(d.with_correction(np.repeat(one[..., None], c, -1)).twin, d.with_correction(one).twin)
    per = rng.normal(0, 0.3, (n, r, k, c))
    got = d.with_correction(per)
    assert np.allclose(got.twin, compose(sig + per, floor)) and np.allclose(got.signal_c, sig + per)
    assert not np.allclose(got.twin, d.with_correction(per.mean(-1)).twin)  # the floor tells the channels apart
    plain = ff.SweepData(GRID, sig.mean(-1), cap, rep, rep.copy(), xy)
    assert np.allclose(plain.with_correction(per).twin, sig.mean(-1) + per.mean(-1))
