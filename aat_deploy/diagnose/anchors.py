"""The binning correction of the focus sweep, anchored where the frames were really focused (docs/diagnosis.md,
"Focus errors"; issue 32).

The sweep is rendered binned, and a binned render cannot reproduce a nearly sharp PSF's sub-pixel phases; the
correction is the difference between the binned full-resolution twin and the binned render, known only at the
focus distances the full-resolution twin was rendered at (its *anchors*) and interpolated in focus between them
(`fitters.binning_correction`). Anchored at the twin's own frames (the reported focus) it is exact there and
wrong in between, where it changes fastest (near focus): a frame truly focused 0.05 D from its reported value
was pulled back towards it by up to 0.05 D (capture 2029 of `benchmarks/bench_diagnose_focus.py`). So, once the
frames' focus is estimated, the full-resolution twin is rendered there too and the correction interpolated over
both anchor sets (`reanchored_sweep`).

**Dense anchoring** (`DENSE_ANCHORS`, off; issue 32, after the eleventh round): the correction changes fastest near
focus, so interpolated between anchors 0.01 D or more apart it is still off around the truth, and the error grows with
how far the reported focus is from it (a part of the twin misfit that depends on the metadata). On, anchor sets are
added at the estimates +- 1 to DENSE_STEPS steps of DENSE_STEP_D, then at the new estimates while some estimate lies
REANCHOR_AGAIN_D or more from every anchor (at most REANCHOR_ROUNDS more sets), when some frame's first estimate lies
DENSE_MOVED_D or more from its reported focus (0: always). Each anchor set is one full-resolution optical render per
capture. Off: on a declared subset of the development sets it was not better (3 sets better, 1 worse in family;
docs/diagnosis.md, Limits, "Dense anchoring measured").

The full-resolution curves are the twin's without the effects that act frame by frame (exposure, misalignment),
as the sweep is: a fitted exposure in the chain would otherwise enter the correction as focus. When the sweep
carries the noise by its expectation (`noisefloor`), both renders leave the noise out: the correction is the
noiseless measure's, added under the floor.
"""

from __future__ import annotations

import numpy as np

from aat_deploy.diagnose import focusfit as ff
from aat_deploy.diagnose import noisefloor
from aat_deploy.diagnose.binned import bin_frames
from aat_deploy.diagnose.compare import focus_curves
from aat_deploy.infer.normalise import normalise_stack

REANCHOR_D = 0.01  # re-anchor when some frame's estimate is this far (diopters) from the twin's focus
DENSE_ANCHORS = False  # anchor sets around the estimates too (module docstring; off: not measured better)
DENSE_STEP_D = 0.01  # their spacing (diopters) ...
DENSE_STEPS = 2  # ... and how many either side of the estimates (0: only re-anchored until settled)
DENSE_MOVED_D = 0.0  # only when some frame's first estimate lies this far (diopters) from its reported focus
REANCHOR_AGAIN_D = 0.003  # then anchored at the estimates again while one lies this far from every anchor ...
REANCHOR_ROUNDS = 3  # ... at most this many more times
# whether, when the sweep carries the noise by its expectation (`noisefloor`), the correction is each channel's own
# (n, R, K, C), added to that channel's noiseless measure under its floor, instead of their mean added to every
# channel: the binned sweep leaves the RAW development out, so its channels' signals are off by different amounts,
# which the mean of logs hides without noise but not under each channel's floor (issue 32, docs/diagnosis.md, "Not the
# whole of it on 3303"). Off: a probe of development sets, not declared
PER_CHANNEL = False


def _curves(stack: np.ndarray, factor: int = 1, per_channel: bool = False) -> np.ndarray:
    c = focus_curves(normalise_stack(bin_frames(np.clip(stack, 0, None), factor)), ff.FIT_GRID)
    return c if per_channel else c.mean(-1)


def anchor_deltas(state, chain: list, focus_m: list[np.ndarray],
                  per_channel: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per capture, (focus (S,) diopters, delta (R, S)): the binned full-resolution twin's curves minus the binned
    render's, both with `chain` at the focus distances focus_m (S,) metres; per_channel: each channel's, (R, S, C).
    The optics are cached by the renderers (keyed by the focus's bits): at the twin's own focus, given as the twin has
    it (`true_focus`, not the inverse of its diopters), this costs no new optical render."""
    out = []
    for i, (c, cb, a, ab, f) in enumerate(zip(state.caps, state.caps_b, state.aifs, state.aifs_b, focus_m)):
        full = state.twins.linear(c, a, chain, state.seed + i, focus_true_m=f)
        own = state.tb.linear(cb, ab, chain, state.seed + i, focus_true_m=f)
        # the full-resolution twin is normalised as a stack, then binned, as `fitters.fit_curves` does
        full_curves = focus_curves(normalise_stack(bin_frames(normalise_stack(np.clip(full, 0, None)), state.factor)),
                                   ff.FIT_GRID)
        full_curves = full_curves if per_channel else full_curves.mean(-1)
        out.append((1.0 / np.asarray(f, np.float64), full_curves - _curves(own, per_channel=per_channel)))
    return out


def correction(grid: np.ndarray, anchors: list[list[tuple[np.ndarray, np.ndarray]]]) -> np.ndarray:
    """(n, R, K) the correction over the sweep's grid, interpolated in focus over every anchor set of each capture
    (flat beyond the outermost anchors); (n, R, K, C) from per-channel deltas (R, S, C)."""
    out = []
    for sets in anchors:
        d = np.concatenate([s[0] for s in sets])
        delta = np.concatenate([s[1] for s in sets], axis=1)
        order = np.argsort(d)
        if delta.ndim == 3:
            out.append(np.stack([np.stack([np.interp(grid, d[order], row[order, c]) for c in range(delta.shape[2])], -1)
                                 for row in delta]))
        else:
            out.append(np.stack([np.interp(grid, d[order], row[order]) for row in delta]))
    return np.stack(out)


def _at(est: np.ndarray, s_n: list[int], grid_d: np.ndarray) -> list[np.ndarray]:
    """(S,) metres per capture: the estimates (n, S) diopters, clipped to the sweep's grid."""
    return [1.0 / np.clip(est[i, :s], grid_d[0], grid_d[-1]) for i, s in enumerate(s_n)]


def densely_anchored(state, raw: ff.SweepData, chain: list, anchors: list, data: ff.SweepData, estimate,
                     rep: dict) -> ff.SweepData:
    """`data` (the sweep corrected over `anchors`, every capture's anchor sets, extended in place) with anchor sets
    at the estimates +- 1 to DENSE_STEPS steps of DENSE_STEP_D, then at the new estimates while some estimate lies
    REANCHOR_AGAIN_D or more from every anchor of its capture, at most REANCHOR_ROUNDS more times. rep gets where."""
    s_n = [len(c.focus_m) for c in state.caps]
    per = PER_CHANNEL and raw.floor_c is not None

    def add(*ests):
        extra = [anchor_deltas(state, chain, _at(e, s_n, raw.grid_d), per_channel=per) for e in ests]
        for x in extra:
            for a, y in zip(anchors, x):
                a.append(y)
        return raw.with_correction(correction(raw.grid_d, anchors)), extra[-1]

    if DENSE_STEPS > 0:
        est = np.asarray(estimate(data), np.float64)
        data, _ = add(*[est + j * DENSE_STEP_D for k in range(1, DENSE_STEPS + 1) for j in (-k, k)])
        rep["dense_anchors_d"] = DENSE_STEP_D
    for k in range(REANCHOR_ROUNDS):
        est = np.asarray(estimate(data), np.float64)
        far = max(float(np.max(np.min(np.abs(est[i, :s][:, None] - np.concatenate([x[0] for x in anchors[i]])),
                                      axis=1))) for i, s in enumerate(s_n))
        if far < REANCHOR_AGAIN_D:
            break
        data, extra = add(est)
        rep[f"reanchored_{k + 2}_d"] = [x[0].round(4).tolist() for x in extra]
    return data


def reanchored_sweep(state, raw: ff.SweepData, estimate) -> tuple[ff.SweepData, dict]:
    """`raw`, the focus sweep without its binning correction (`fitters.focus_sweep(state, correct=False)`), with the
    correction anchored at the twin's own focus and, when some frame's estimate
    lies REANCHOR_D or more from it, at the estimates too (`estimate(sweep) -> (n, S)` diopters: the per-frame
    focus); with DENSE_ANCHORS, around them too (`densely_anchored`) when some estimate lies DENSE_MOVED_D or more
    from it. Returns the sweep and a report (where it was anchored; `moved_d`: per capture, the first estimates'
    largest distance from the twin's focus)."""
    chain = [e for e in state.chain if not state.tb.has_stack_hook(e)]
    if raw.floor_c is not None:  # the sweep carries the noise by its expectation: correct the noiseless measure
        chain = noisefloor.quiet(chain)
    per = PER_CHANNEL and raw.floor_c is not None  # each channel's own correction under its floor
    s_n = [len(c.focus_m) for c in state.caps]
    base = [raw.base_d[i, :s] for i, s in enumerate(s_n)]
    own = [np.asarray(state.twins.true_focus(c, state.chain, state.seed + i), np.float64).ravel()
           for i, c in enumerate(state.caps)]  # the full-resolution twin's own focus, bit for bit (its render cached)
    anchors = [[a] for a in anchor_deltas(state, chain, own, per_channel=per)]
    data = raw.with_correction(correction(raw.grid_d, anchors))
    est = np.asarray(estimate(data), np.float64)
    moved = [float(np.max(np.abs(est[i, :s] - base[i]))) for i, s in enumerate(s_n)]
    rep = {"anchors_d": [b.round(4).tolist() for b in base], "moved_d": [round(m, 4) for m in moved]}
    if max(moved) >= REANCHOR_D:
        extra = anchor_deltas(state, chain, _at(est, s_n, raw.grid_d), per_channel=per)
        anchors = [a + [x] for a, x in zip(anchors, extra)]
        data = raw.with_correction(correction(raw.grid_d, anchors))
        rep["reanchored_d"] = [x[0].round(4).tolist() for x in extra]
    if DENSE_ANCHORS and max(moved) >= DENSE_MOVED_D:
        data = densely_anchored(state, raw, chain, anchors, data, estimate, rep)
    return data, rep
