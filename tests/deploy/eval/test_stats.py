"""The measurement vocabulary (aat_deploy.eval.stats) against hand-computed cases."""

import numpy as np
import pytest

from aat_deploy.eval.stats import (
    ZONES,
    bootstrap_mean,
    field_radius,
    fmt_interval,
    paired_diff,
    paired_ratio,
    summarise,
    zone_masks,
)


def test_field_radius_is_circular_over_the_half_diagonal():
    h, w = 640, 960  # 3:2
    r = field_radius(h, w)
    half_diag = np.hypot(w / 2, h / 2)
    assert r[0, 0] == pytest.approx(np.hypot(w / 2 - 0.5, h / 2 - 0.5) / half_diag)  # corner pixel centre
    assert r[h // 2, w // 2] == pytest.approx(np.hypot(0.5, 0.5) / half_diag)
    # the midpoints of the long (top) and short (left) edges: 0.55 and 0.83, not 0.71 both (an elliptical radius)
    assert r[0, w // 2] == pytest.approx(np.hypot(0.5, h / 2 - 0.5) / half_diag)
    assert r[0, w // 2] == pytest.approx(0.55, abs=0.01) and r[h // 2, 0] == pytest.approx(0.83, abs=0.01)
    assert np.allclose(r, r[::-1, ::-1], rtol=0, atol=1e-12)  # symmetric about the centre


def test_field_radius_on_the_sensor_in_mm():
    # a 4 x 6 frame spanning a 36 x 12 mm sensor: pixels 6 mm wide, 3 mm tall (not square)
    r = field_radius(4, 6, (36.0, 12.0))
    x_mm, y_mm = 15.0, 4.5  # the top-left pixel centre from the sensor centre
    assert r[0, 0] == pytest.approx(np.hypot(x_mm, y_mm) / np.hypot(18.0, 6.0))
    assert np.allclose(field_radius(64, 96, (36.0, 24.0)), field_radius(64, 96))  # square pixels: the same


def test_zones_partition_the_frame_at_the_project_thresholds():
    h, w = 64, 96
    m = zone_masks(h, w)
    assert tuple(m) == ZONES
    total = sum(v.astype(int) for v in m.values())
    assert (total == 1).all()
    r = field_radius(h, w)
    assert (r[m["centre"]] < 0.33).all() and (r[m["outer"]] > 0.66).all()
    assert not m["outer"][0, w // 2] and m["outer"][h // 2, 0]  # top edge midpoint 0.55: not outer; left 0.83


def test_bootstrap_mean_by_hand():
    m, lo, hi = bootstrap_mean([1.0, 3.0], [1.0, 1.0], 200)
    assert m == 2.0 and 1.0 <= lo <= hi <= 3.0
    assert bootstrap_mean([1.0, 3.0], [3.0, 1.0])[0] == pytest.approx(1.5)
    assert bootstrap_mean([4.0]) == (4.0, 4.0, 4.0)


def test_paired_ratio_of_proportional_scenes_has_no_spread():
    a = [{"mae": v} for v in (1.0, 2.0, 3.0, 4.0)]
    b = [{"mae": 2 * v} for v in (1.0, 2.0, 3.0, 4.0)]
    est, lo, hi = paired_ratio(a, b)
    # every resample keeps the pairs, so every resampled ratio is exactly 0.5
    assert est == pytest.approx(0.5) and lo == pytest.approx(0.5) and hi == pytest.approx(0.5)


def test_paired_ratio_is_ratio_of_means_not_mean_of_ratios():
    a = [{"mae": 1.0}, {"mae": 1.0}]
    b = [{"mae": 1.0}, {"mae": 3.0}]
    est, lo, hi = paired_ratio(a, b)
    assert est == pytest.approx(2.0 / 4.0)  # mean of ratios would be 2/3
    assert lo == pytest.approx(1 / 3) and hi == pytest.approx(1.0)  # the extremes: both scenes drawn the same


def test_one_scene_has_no_interval():
    est, lo, hi = paired_ratio([{"mae": 1.0}], [{"mae": 4.0}])
    assert est == 0.25 and np.isnan(lo) and np.isnan(hi)


def test_summarise_ignores_missing_values_and_brackets_the_mean():
    per = [{"mae": float(i), "psnr": float("nan")} for i in range(1, 6)]
    out = summarise(per)
    m, lo, hi = out["mae"]
    assert m == pytest.approx(3.0) and 1.0 <= lo < m < hi <= 5.0
    assert all(np.isnan(out["psnr"]))
    assert set(summarise(per, ["mae"])) == {"mae"}


def test_paired_diff_of_a_constant_offset_has_no_spread():
    a = [{"psnr": v + 0.5} for v in (20.0, 25.0, 30.0)]
    b = [{"psnr": v} for v in (20.0, 25.0, 30.0)]
    assert paired_diff(a, b) == pytest.approx([0.5, 0.5, 0.5])


def test_paired_diff_skips_scenes_without_a_value_and_brackets_the_mean():
    a = [{"psnr": x} for x in (21.0, 22.0, float("nan"), 30.0)]
    b = [{"psnr": x} for x in (20.0, 20.0, 25.0, 27.0)]
    est, lo, hi = paired_diff(a, b)  # differences 1, 2, 3 (the NaN scene left out)
    assert est == pytest.approx(2.0) and 1.0 <= lo < est < hi <= 3.0
    assert np.isnan(paired_diff(a[:1], b[:1])[1])  # one scene: no interval


def test_fmt_interval():
    assert fmt_interval([0.25, 0.2, 0.3]) == "0.250 [0.200, 0.300]"
    assert fmt_interval([0.25, 0.25, 0.25], 2) == "0.25"
    assert fmt_interval([0.25, float("nan"), float("nan")]) == "0.250"
    assert fmt_interval([float("nan")] * 3) == "–"


def test_nested_paired_ratio_by_hand_and_its_two_levels():
    from aat_deploy.eval.stats import nested_paired_ratio, paired_ratio

    a = [[{"mae": 1.0}, {"mae": 3.0}], [{"mae": 2.0}, {"mae": 6.0}]]
    b = [[{"mae": 2.0}, {"mae": 2.0}], [{"mae": 4.0}, {"mae": 4.0}]]
    r = nested_paired_ratio(a, b, n_boot=500)
    assert r[0] == pytest.approx(12.0 / 12.0) and r[1] <= r[0] <= r[2]
    # one group: the point estimate is paired_ratio's and the interval resamples scenes only
    one = nested_paired_ratio(a[:1], b[:1], n_boot=2000)
    assert one[0] == pytest.approx(paired_ratio(a[0], b[0])[0])
    # groups that differ widen the interval beyond the one that resamples scenes alone (pooled as one group)
    rng = np.random.default_rng(0)
    groups_a = [[{"mae": float(v)} for v in rng.normal(m, 0.05, 20)] for m in (0.5, 1.0, 1.5)]
    groups_b = [[{"mae": 1.0} for _ in range(20)] for _ in range(3)]
    nested = nested_paired_ratio(groups_a, groups_b, n_boot=1000)
    flat = paired_ratio(sum(groups_a, []), sum(groups_b, []), n_boot=1000)
    assert nested[0] == pytest.approx(flat[0])
    assert nested[2] - nested[1] > 3 * (flat[2] - flat[1])
    with pytest.raises(ValueError, match="same scenes"):
        nested_paired_ratio(a, [b[0][:1], b[1]])


def test_nested_paired_ratio_crossed_keeps_a_scene_hard_for_every_group():
    """Groups that share their scenes (every lens copy renders the same held-out scenes): a scene where the ratio
    differs in every group moves every group at once, so the crossed interval is wider than drawing the scenes anew
    per group, and the point estimate is the same."""
    from aat_deploy.eval.stats import nested_paired_ratio

    rng = np.random.default_rng(1)
    scene = rng.normal(1.0, 0.3, 15)  # each scene's own ratio, common to the groups
    a = [[{"mae": float(s * (1 + rng.normal(0, 0.01)))} for s in scene] for _ in range(6)]
    b = [[{"mae": 1.0} for _ in scene] for _ in range(6)]
    crossed = nested_paired_ratio(a, b, crossed=True, n_boot=1000)
    nested = nested_paired_ratio(a, b, n_boot=1000)
    assert crossed[0] == nested[0]
    assert crossed[2] - crossed[1] > 1.8 * (nested[2] - nested[1])
    with pytest.raises(ValueError, match="crossed"):
        nested_paired_ratio([a[0], a[1][:3]], [b[0], b[1][:3]], crossed=True)
