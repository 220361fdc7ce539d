"""benchmarks/anycam_val_baseline.py's paired ratios: a later net against the first and each against the classical
method, over the items both score, hand-computed."""

import numpy as np

from aat_deploy.metrics import MetricAccumulator
from benchmarks.anycam_val_baseline import paired_ratios


def test_paired_ratios_use_the_items_both_score():
    gt = np.full((4, 4), 2.0)
    focus = np.array([1.0, 3.0])
    accs = {k: MetricAccumulator(focus_range_mask=True) for k in ("Classical, per-pixel map", "v1", "v4")}
    for err_c, err_1, err_4 in ((0.4, 0.2, 0.1), (0.8, 0.4, 0.4), (0.6, 0.3, 0.15)):
        for k, e in zip(accs, (err_c, err_1, err_4)):
            accs[k].add(gt + e, gt, focus_m=focus)
    for acc in accs.values():  # an item with no pixel inside its focus range: left out of every ratio
        acc.add(gt, np.full((4, 4), 9.0), focus_m=focus)
    r = paired_ratios(accs, ["v1", "v4"])
    assert set(r) == {"v4 / v1", "v1 / Classical, per-pixel map", "v4 / Classical, per-pixel map"}
    assert np.isclose(r["v4 / v1"][0], (0.1 + 0.4 + 0.15) / (0.2 + 0.4 + 0.3))
    assert np.isclose(r["v1 / Classical, per-pixel map"][0], 0.5)
    lo, hi = r["v4 / v1"][1:]
    assert lo <= r["v4 / v1"][0] <= hi and hi <= 1.0 + 1e-12
