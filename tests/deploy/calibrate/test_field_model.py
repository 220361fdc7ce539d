"""The calibration's smooth model (`aat_deploy.calibrate.model`) on hand-made tile observations with a known truth
(no rendering): a phone lens's field curvature, round and steep at the edge, must not leak into the reported
focus's error, and the stored monomials must be the functions fitted."""

from __future__ import annotations

import numpy as np
import pytest

from aat_deploy.calibrate.model import FieldBasis, Observations, fit_all, fit_model
from benchmarks.probes.family_split import ASPECT, constant_vif, phone_observations, rho2, truth  # the phone's tiles


def map_error(fit, bias_d: float) -> np.ndarray:
    """Model minus truth (D) over the field inside radius 0.9, frames truly focused at 6-14 D."""
    x, y = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 31))
    keep = rho2(x, y) < 0.81
    out = []
    for t in np.linspace(6, 14, 5):
        out.append((fit.predict(x, y, np.full(x.shape, t + bias_d)) - truth(x, y, t))[keep])
    return np.concatenate(out)


def test_a_steep_round_field_does_not_become_a_focus_offset():
    """No reported-focus error, tiles 0.05 D noisy: the fit keeps the frame centre within 0.03 D of the truth (an
    offset, if chosen, within 0.03 D of zero) and the map within 0.04 D RMS inside radius 0.9. With monomials only
    (the model before the radial powers, as cross-validation chose it on the phone's sweeps) the map is over 1 D
    off, and the offset family takes the field's misfit (+1.46 D here): the criterion of the cells' mean residuals
    alone chose it (the centre 1.47 D off); with the tiles' pattern within the cells (`model.bic`) none wins."""
    obs = phone_observations()
    fit = fit_model(obs)
    assert fit.radial > 0
    assert abs(fit.focus.bias_d) < 0.03 and abs(fit.focus.scale - 1) < 0.003, fit.focus
    assert abs(float(fit.predict(0.0, 0.0, 10.0) - truth(0.0, 0.0, 10.0))) < 0.03
    err = map_error(fit, 0.0)
    assert float(np.sqrt(np.mean(err ** 2))) < 0.04, float(np.sqrt(np.mean(err ** 2)))
    mono = fit_model(obs, radial=0)
    assert float(np.sqrt(np.mean(map_error(mono, 0.0) ** 2))) > 1.0
    leak = fit_all(obs, mono.degree, mono.focus_degree, radial=0)["offset"]
    assert leak[0].bias_d > 0.3 and mono.focus.family == "none"


def test_an_offset_is_recovered_under_a_steep_round_field():
    """A reported focus 0.5 D off: the offset family, 0.5 within 0.04 D, the map within 0.04 D RMS."""
    for seed in (0, 1):
        fit = fit_model(phone_observations(bias_d=0.5, seed=seed))
        assert fit.focus.family == "offset" and abs(fit.focus.bias_d - 0.5) < 0.04, (seed, fit.focus)
        assert float(np.sqrt(np.mean(map_error(fit, 0.5) ** 2))) < 0.04


def test_field_basis_stores_the_functions_it_fits():
    """The radial powers expanded into monomials (the calibration file's FieldPoly) are rho^2m of the frame's
    aspect: the stored polynomial equals the fitted functions' sum."""
    fb = FieldBasis(2, 12, ASPECT)
    assert fb.powers() == [4, 6, 8, 10, 12] and fb.size == 5 + 5
    rng = np.random.default_rng(3)
    c = rng.normal(size=(fb.size, 2))
    fp = fb.field_poly(c, (5.0, 15.0))
    x, y = rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50)
    cols = fb.columns(x, y)
    np.testing.assert_allclose(cols[:, 5:], np.stack([rho2(x, y) ** m for m in (2, 3, 4, 5, 6)], 1), rtol=1e-12)
    want = cols @ c[:, 0] - cols @ c[:, 1]  # at tau = -1: P0 - P1
    np.testing.assert_allclose(fp(x, y, [5.0])[0], want, rtol=1e-9, atol=1e-12)
    assert FieldBasis(6, 6).powers() == [] and FieldBasis(6, 8).powers() == [8]


def test_a_fit_the_file_cannot_store_is_no_fit():
    """Tiles only in a thin ring at the edge, alternating by hundreds of diopters: only cancelling high radial powers
    follow them, with coefficients beyond the format's bound. That order is then not fitted (None: cross-validation
    and the bootstrap skip it) instead of stopping the calibration with an error."""
    from aat_deploy.calibrate.model import fit_family

    rng = np.random.default_rng(0)
    ang, rad = rng.uniform(0, 2 * np.pi, 400), rng.choice([0.85, 0.9, 0.95], 400)
    a2 = ASPECT ** 2 / (1 + ASPECT ** 2)
    x, y = rad * np.cos(ang) / np.sqrt(a2), rad * np.sin(ang) / np.sqrt(1 - a2)
    ok = (np.abs(x) <= 1) & (np.abs(y) <= 1)
    x, y, rad = x[ok], y[ok], rad[ok]
    rep = np.full(len(x), 10.0)
    obs = Observations(x, y, rep, rep + np.where(rad == 0.9, 500.0, -500.0), np.zeros(len(x), int),
                       np.zeros(len(x), int), aspect=ASPECT)
    assert fit_family(obs, "none", 2, 0, radial=12) is None
    assert fit_family(obs, "none", 2, 0, radial=0) is not None


def test_the_offset_is_nearly_collinear_with_the_radial_powers():
    """Why the family is weakly split from the field term at phone scale: over the phone charts' tiles a constant is
    nearly in the span of the radial powers (the field term is zero only at the centre), so the tiles know the
    offset several times less well than with monomials only; with precise tiles (0.05 D) a 0.18 D offset (the
    measure's own on the phone's axis) is still found (as an offset, or inside a monotone curve)."""
    obs = phone_observations()
    assert constant_vif(obs, 2, 12) > 5 * constant_vif(obs, 2, 0)
    fit = fit_model(phone_observations(bias_d=0.18, noise_d=0.05))
    assert fit.focus.family in ("offset", "monotone"), fit.focus
    assert abs(float(fit.predict(0.0, 0.0, 10.18) - truth(0.0, 0.0, 10.0))) < 0.04


def test_a_small_offset_is_told_from_the_field_term_at_a_phones_tile_scatter():
    """The measure's own 0.18 D on the phone's axis, tiles 0.15 D noisy (the phone's inside radius 0.66): the offset
    family, within 0.05 D, the frame centre within 0.05 D, on every seed; without an offset, none. With the BIC
    over the cells' mean residuals alone (the criterion before) a near-constant was taken by the radial powers
    and none was chosen on all four seeds, the centre 0.18 D off (benchmarks/probes/family_split.py)."""
    for seed in range(4):
        fit = fit_model(phone_observations(bias_d=0.18, noise_d=0.15, seed=seed))
        assert fit.focus.family == "offset" and abs(fit.focus.bias_d - 0.18) < 0.05, (seed, fit.focus)
        assert abs(float(fit.predict(0.0, 0.0, 10.18) - truth(0.0, 0.0, 10.0))) < 0.05
        none = fit_model(phone_observations(bias_d=0.0, noise_d=0.15, seed=seed))
        assert none.focus.family == "none", (seed, none.focus)


def test_the_fits_solve_at_one_blas_thread(monkeypatch):
    """The model's many small least-squares solves run numpy's BLAS at one thread (`machine.one_blas_thread`):
    threaded, each waited at every step for any process holding a core, and the test above took 30 minutes in CI
    beside a training run (3 s a fit on one thread, 50 s on two with one core held). The limit is lifted after."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from aat_deploy.calibrate.model import bootstrap, fit_family

    def blas_threads():
        return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}

    if not blas_threads():
        pytest.skip("numpy here has no BLAS that threadpoolctl can set")
    seen = []
    lstsq = np.linalg.lstsq

    def spy(*a, **k):
        seen.append(blas_threads())
        return lstsq(*a, **k)

    monkeypatch.setattr(np.linalg, "lstsq", spy)
    obs = phone_observations()
    with threadpool_limits(limits=2, user_api="blas"):  # a 2-core machine's default, whatever runs this
        fit = fit_model(obs, degree=2, focus_degree=1, radial=None)  # the radial order by cross-validation
        bootstrap(obs, fit, n_boot=2)
        fit_family(obs, "offset", 2, 1, radial=12)
        assert blas_threads() == {2}
    assert len(seen) > 20 and all(s == {1} for s in seen), seen


def test_bic_weighs_the_pattern_within_a_frames_cell():
    """Two fits whose cells' mean residuals are the same: the one whose tiles scatter more about their cell's mean
    (a pattern across the field the model left) has the higher BIC; a common error of one cell's tiles (its
    frame's focus error) enters only through the cells' means."""
    from aat_deploy.calibrate.model import bic

    rng = np.random.default_rng(0)
    n = 400
    cell = np.repeat(np.arange(20), 20)
    obs = Observations(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n, int), cell)
    base = rng.normal(0, 0.1, n)
    base -= np.bincount(cell, base)[cell] / 20  # zero cell means
    frame = rng.normal(0, 0.05, 20)[cell]
    assert bic(obs, frame + 1.2 * base, 1) > bic(obs, frame + base, 1) + 50
    assert bic(obs, 1.5 * frame + base, 1) > bic(obs, frame + base, 1)
    assert bic(obs, frame + base, 2) > bic(obs, frame + base, 1)  # a parameter costs log(cells)


def test_the_field_term_is_held_beyond_the_farthest_tile():
    """Tiles of the phone's charts only to field radius 0.8: beyond it the fitted field term's radial powers
    extrapolate by up to 2 D, differently with each draw of tile noise; held along the radius (`fit.held_beyond_tiles`,
    what `aat-calibrate fit` stores) it is off by no more than the lens's own change beyond the farthest tile, and
    unchanged inside."""
    from aat_deploy.calibrate.fit import held_beyond_tiles
    from aat_deploy.calibrate.format import field_radius_of

    x, y = np.meshgrid(np.linspace(-1, 1, 64), np.linspace(-1, 1, 48))
    worst = {"extrapolated": 0.0, "held": 0.0}
    for seed in range(3):
        o = phone_observations(noise_d=0.05, seed=seed)
        o = o.subset(field_radius_of(o.x, o.y, o.aspect) <= 0.8)
        m = fit_model(o)
        h = held_beyond_tiles(m.field, o)
        assert h.radius_max == pytest.approx(float(np.max(field_radius_of(o.x, o.y, o.aspect))))
        r = field_radius_of(x, y, ASPECT)
        out = r > h.radius_max
        s = np.where(out, h.radius_max / r, 1.0)
        for f in (6.0, 10.0):
            t = m.focus.true_diopters(np.array([f]))
            tr = truth(x, y, np.full(x.shape, f))
            ex, he = t + m.field(x, y, t)[0], t + h(x, y, t)[0]
            np.testing.assert_array_equal(ex[~out], he[~out])
            change = truth(x * s, y * s, np.full(x.shape, f)) - tr  # the lens's own change beyond the tiles
            rms = lambda a: float(np.sqrt(np.mean(a[out] ** 2)))
            assert rms(he - tr) <= rms(change) + 0.1, (seed, f)
            worst["extrapolated"] = max(worst["extrapolated"], rms(ex - tr))
            worst["held"] = max(worst["held"], rms(he - tr))
    assert worst["held"] < 0.6 * worst["extrapolated"], worst


def _near_chart_observations(given_m: float, fit_distance: bool, noise_d: float = 0.05, seed: int = 0):
    """The phone's three charts (`phone_observations`) and a fourth at 5.5 cm (tilted), whose tiles peak where the
    traced map has its true objects in focus but whose objects are computed at given_m (a tape's error); dz (D per
    mm of its distance) only when fit_distance."""
    from benchmarks.probes.family_split import phone_map

    three = phone_observations(noise_d=noise_d, seed=seed)
    rng = np.random.default_rng([seed, 55])
    x, y = np.meshgrid((np.arange(24) + 0.5) / 12 - 1, 1 - (np.arange(18) + 0.5) / 9)
    r = np.sqrt(rho2(x, y)).ravel()
    f_grid = np.linspace(2.0, 20.0, 1801)
    t_grid = phone_map().frame_diopters(1.0 / f_grid, r, calibrated=False)
    tilt = (1 + 0.3 * 0.3 * x).ravel()
    true_obj = 1.0 / (0.055 * tilt)
    f = np.array([np.interp(true_obj[j], t_grid[:, j], f_grid, left=np.nan, right=np.nan) for j in range(r.size)])
    ok = np.isfinite(f)
    rep = f[ok] + rng.normal(0, noise_d, int(ok.sum()))
    given = 1.0 / (given_m * tilt[ok])
    dz = -given ** 2 * tilt[ok] / 1000.0 if fit_distance else np.zeros(int(ok.sum()))
    cat = lambda a, b: np.concatenate([a, b])
    return Observations(cat(three.x, x.ravel()[ok]), cat(three.y, y.ravel()[ok]), cat(three.reported_d, rep),
                        cat(three.object_d, given), cat(three.sweep, np.full(int(ok.sum()), 3)),
                        cat(three.cell, 3 * 10_000 + np.floor(rep / 1.1).astype(int)), aspect=ASPECT,
                        dz=cat(np.zeros(len(three)), dz))


def near_map_error(fit) -> float:
    """RMS (D) of the model against the truth inside field radius 0.9 for frames focused at 7-9 cm (11.1-14.3 D),
    whose outer field has objects nearer than the 7 cm chart in focus."""
    x, y = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 31))
    keep = rho2(x, y) < 0.81
    err = [(fit.predict(x, y, np.full(x.shape, t)) - truth(x, y, t))[keep] for t in np.linspace(11.1, 14.3, 4)]
    return float(np.sqrt(np.mean(np.concatenate(err) ** 2)))


def test_a_near_charts_distance_is_fitted_from_the_sweeps_consistency():
    """A fourth chart at 5.5 cm shows the outer field of frames focused at 7-9 cm, but a tape's 1.8 mm there is
    0.6 D: given that far off, the map of those frames is 10 x worse than with three charts. With its distance an
    unknown of the model (`Observations.dz`, `aat-calibrate fit --distance-m ...,~D`), the fit finds it within
    0.3 mm and the map is as good as with the true distance. (On these ideal tiles three charts are already
    within 0.03 D; on the benchmark's rendered sweeps the fourth chart is what helps: BENCHMARKS.md.)"""
    for seed in (0, 1):
        three = fit_model(phone_observations(seed=seed))
        true = fit_model(_near_chart_observations(0.055, False, seed=seed))
        taped = fit_model(_near_chart_observations(0.055 - 0.0018, False, seed=seed))
        fitted = fit_model(_near_chart_observations(0.055 - 0.0018, True, seed=seed))
        e = {k: near_map_error(f) for k, f in (("three", three), ("true", true), ("taped", taped),
                                                ("fitted", fitted))}
        assert abs(fitted.shifts_mm[3] - 1.8) < 0.3, (seed, fitted.shifts_mm)
        assert not taped.shifts_mm and set(fitted.shifts_mm) == {3}
        assert e["taped"] > e["three"] and e["taped"] > 2 * e["true"], (seed, e)
        assert e["fitted"] < e["true"] + 0.005 and e["fitted"] < e["three"] + 0.005, (seed, e)



def test_a_near_charts_distance_is_where_the_measured_charts_fit_best():
    """`profile_shifts` (the fit's criterion for a fitted distance since 2026-11-28): the near chart given 1.8 mm
    short is moved to where the three measured charts' tiles fit best, its objects recomputed there and asked again,
    within 0.1 mm of its true distance; the measured charts' squared residuals are least there (0.3 mm either side
    is worse), the near chart's own tiles do not enter that criterion, and the bootstrap's interval of the distance
    holds it."""
    from dataclasses import replace

    from aat_deploy.calibrate.model import bootstrap, measured_rss, profile_shifts, refit

    for seed in (0, 1):
        given = 0.055 - 0.0018
        fit = fit_model(_near_chart_observations(given, True, seed=seed))
        for _ in range(3):
            obs = _near_chart_observations(given, True, seed=seed)
            shift = profile_shifts(obs, fit)[3]
            given += shift / 1000.0
        assert abs(shift) < 0.01 and abs(given - 0.055) < 0.0001, (seed, given)
        obs = _near_chart_observations(given, True, seed=seed)
        rss = {}
        for s in (-0.3, 0.0, 0.3):
            o = replace(obs, object_d=obs.object_d + np.where(obs.sweep == 3, obs.dz, 0.0) * s, dz=None)
            rss[s] = measured_rss(obs, refit(o, fit, family=fit.focus.family).residual_d)
        assert rss[0.0] < rss[-0.3] and rss[0.0] < rss[0.3], (seed, rss)
        assert measured_rss(obs, np.where(obs.sweep == 3, 1.0, 0.0)) == 0.0  # the near chart's tiles: not counted
        # the bootstrap's interval of the distance (the same criterion per replicate) holds the fitted distance;
        # it is wider than the joint least squares' (here -0.7 to +1.3 mm against -0.1 to +0.2: a replicate that
        # drops a measured chart rests the distance on the others; docs/calibration.md)
        boot = bootstrap(obs, refit(replace(obs, dz=None), fit), n_boot=30, max_shift_mm={3: 2.75})
        lo, hi = boot.shifts_mm[3]
        assert lo < 0.0 < hi and hi - lo < 2.5, (seed, lo, hi)


def test_a_profile_has_a_minimum_or_none():
    from aat_deploy.calibrate.model import _vertex

    f = lambda s: 3.0 * (s - 0.7) ** 2 + 1.0
    assert _vertex((f(-0.5), f(0.0), f(0.5)), 0.5) == pytest.approx(0.7)
    assert _vertex((1.0, 2.0, 1.0), 0.5) is None and _vertex((1.0, 1.0, 1.0), 0.5) is None

FOUR_CHARTS = ((0.07, 0.4), (0.1, -0.3), (0.18, 0.2), (0.055, 0.3))  # (distance m, tilt): the phone's and a near one


def _tiles_of(surface, charts=FOUR_CHARTS, noise_d: float = 0.05, seed: int = 0, step_d: float = 0.55):
    """Tiles (24 x 18 per chart) of tilted charts, each peaking at the frame (true focus, D) where surface(x, y,
    f (F,)) -> (F, N) has its object in focus, plus Gaussian noise; cells of frames step_d apart."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid((np.arange(24) + 0.5) / 12 - 1, 1 - (np.arange(18) + 0.5) / 9)
    f_grid = np.linspace(2.0, 20.0, 1801)
    t_grid = surface(x.ravel(), y.ravel(), f_grid)
    cols = {k: [] for k in ("x", "y", "reported_d", "object_d", "sweep", "cell")}
    for i, (dist, tilt) in enumerate(charts):
        obj = (1.0 / (dist * (1 + tilt * 0.3 * x))).ravel()
        f = np.array([np.interp(obj[j], t_grid[:, j], f_grid, left=np.nan, right=np.nan) for j in range(obj.size)])
        ok = np.isfinite(f)
        rep = f[ok] + rng.normal(0, noise_d, int(ok.sum()))
        for k, v in (("x", x.ravel()[ok]), ("y", y.ravel()[ok]), ("reported_d", rep), ("object_d", obj[ok]),
                     ("sweep", np.full(int(ok.sum()), i)), ("cell", i * 10_000 + np.floor(rep / step_d).astype(int))):
            cols[k].append(v)
    return Observations(*(np.concatenate(cols[k]) for k in cols), aspect=ASPECT)


def _measure_map(x, y, f):
    """The phone's calibrated map (where the focus measure peaks): under its astigmatism the in-focus object's
    offset at the field's edge rises, falls and rises again with focus (BENCHMARKS.md, "The phone's outer field")."""
    from benchmarks.probes.family_split import phone_map

    return phone_map().frame_diopters(1.0 / f, np.sqrt(rho2(x, y)), calibrated=True)


def _zone_error(fit, surface, lo: float, hi: float) -> float:
    """RMS (D) of the model against surface at field radius lo..hi, frames truly focused at 5.6-14.3 D (part a's)."""
    x, y = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 31))
    r = np.sqrt(rho2(x, y))
    x, y = x[(r >= lo) & (r < hi)], y[(r >= lo) & (r < hi)]
    e = [fit.predict(x, y, np.full(x.shape, t)) - surface(x, y, np.array([t]))[0] for t in np.linspace(5.6, 14.3, 6)]
    return float(np.sqrt(np.mean(np.concatenate(e) ** 2)))


def test_the_edge_follows_focus_beyond_a_parabola_where_frames_say_so():
    """Four charts' tiles (0.05 D noise) from the phone's calibrated map: cross-validation over frame cells gives
    the edge powers (rho^8..) a cubic in focus, the rest of the field term stays quadratic, and the map at field
    radius 0.66-0.9 is within 0.09 D (a quadratic for all: 0.17 D), no worse inside 0.66. Three charts cannot ask
    for it (a Legendre degree per sweep); a surface that is smooth in focus does not get it."""
    for seed in (0, 1):
        obs = _tiles_of(_measure_map, seed=seed)
        new, quad = fit_model(obs), fit_model(obs, edge_focus=False)
        assert (new.focus_degree, new.low_focus_degree) == (3, 2), (seed, new.focus_degree, new.edge_cv)
        assert quad.focus_degree == 2 and quad.low_focus_degree is None and quad.edge_cv is None
        edge, edge_quad = _zone_error(new, _measure_map, 0.66, 0.9), _zone_error(quad, _measure_map, 0.66, 0.9)
        assert edge < 0.09 and edge_quad > 0.15, (seed, edge, edge_quad)
        assert _zone_error(new, _measure_map, 0, 0.66) < _zone_error(quad, _measure_map, 0, 0.66) + 0.005
        # the stored polynomial is the fitted model: the edge powers' cubic, the monomials' parabola
        fb = FieldBasis(new.degree, new.radial, ASPECT)
        assert fb.focus_mask(3, 2).sum() < fb.size * 4 and new.field.coefficients.shape[1] == 4
        three = fit_model(_tiles_of(_measure_map, FOUR_CHARTS[:3], seed=seed))
        assert three.edge_cv is None and three.focus_degree <= 2

    def smooth(x, y, f):  # curvature steep at the edge, changing slowly (linearly) with focus
        u = rho2(x, y)[None, :]
        return f[:, None] + (1.5 * u + 2.0 * u ** 4) * (1 + 0.02 * f[:, None])

    fit = fit_model(_tiles_of(smooth))
    assert fit.low_focus_degree is None and fit.focus_degree <= 2
    assert _zone_error(fit, smooth, 0, 0.9) < 0.02


def test_the_order_is_chosen_again_on_the_tiles_the_outlier_pass_keeps():
    """Tiles of the phone's four charts (0.05 D noise) with 16 of the 48 beyond field radius 0.9 put 1.5-2.5 D off
    (as tiles reaching the frame's corners, where its focus curves have two peaks, were on the benchmark): the first
    fit's cross-validations, which the gross tiles dominate, choose another field order than on clean tiles (on seed
    1 rho^8, the benchmark's case; on seed 2 degree 2). After the outlier pass the whole order is chosen again on the tiles kept
    (`fit.robust_fit`) and is the clean tiles' order; re-choosing only the edge powers' degree in focus (the rule
    before 2026-11-27, without the blend of orders) keeps the first fit's order, and the map at radius 0.66-1 is
    worse (seed 1: 0.161 against 0.133 D). On seed 2 the outlier pass (after a first fit that blends the orders
    near the best) drops clean corner tiles too (34 tiles for the 16 gross ones), and the order chosen on the
    tiles kept is degree 4, not the clean tiles' 3: chosen again all the same, and the map no worse than the rule
    before's (0.209 against 0.216 D; before the blend 0.200 against 0.198)."""
    import dataclasses

    from aat_deploy.calibrate.fit import robust_fit
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.model import refit_edge

    order = lambda f: (f.degree, f.radial, f.low_focus_degree, f.focus_degree)
    for seed in (1, 2):
        clean = _tiles_of(_measure_map, seed=seed)
        rng = np.random.default_rng(seed)
        pick = rng.choice(np.flatnonzero(field_radius_of(clean.x, clean.y, clean.aspect) > 0.9), 16, replace=False)
        rep = clean.reported_d.copy()
        rep[pick] += rng.choice([-1, 1], 16) * rng.uniform(1.5, 2.5, 16)
        dirty = dataclasses.replace(clean, reported_d=rep)
        first, want = fit_model(dirty), fit_model(clean)
        assert order(first) != order(want), seed  # the gross tiles move the first fit's choice
        fit, kept, warning = robust_fit(dirty)
        assert set(pick) <= set(np.flatnonzero(~np.isin(np.arange(len(dirty)), _kept_index(dirty, kept))))
        assert "tiles left out as outliers" in warning and order(fit) != order(first), (seed, order(fit))
        assert order(fit) == order(want) or seed == 2, (seed, order(fit))
        # the rule before: the first fit's order alone (no blend), the edge degree chosen again
        before = refit_edge(kept, dataclasses.replace(first, blend=()))
        assert (before.degree, before.radial) == (first.degree, first.radial) != (want.degree, want.radial)
        now, then = _zone_error(fit, _measure_map, 0.66, 1.0), _zone_error(before, _measure_map, 0.66, 1.0)
        assert now < then - (0.01 if seed == 1 else 0.0), (seed, now, then)  # seed 1: 0.133 against 0.161 D


def _kept_index(obs, kept) -> np.ndarray:
    """Indices into obs of the tiles in kept (matched by sweep, position and object)."""
    key = lambda o: list(zip(o.sweep.tolist(), np.round(o.x, 9).tolist(), np.round(o.y, 9).tolist(),
                             np.round(o.object_d, 9).tolist()))
    k = set(key(kept))
    return np.array([i for i, t in enumerate(key(obs)) if t in k], np.int64)


def test_orders_near_the_best_are_blended_with_weights_continuous_in_their_cv():
    """`order_weights`: 1 at the best spatial CV RMS, falling linearly to 0 at ORDER_BAND (2 %) worse; `edge_weight`:
    the edge cubic's weight 0 where the frame cells' CV gains nothing, 0.5 at a 2 % gain (the rule before took the
    cubic from there), 1 from 4 %."""
    from aat_deploy.calibrate.model import edge_weight, order_weights

    table = [{"cv_rms_d": 0.2}, {"cv_rms_d": 0.202}, {"cv_rms_d": 0.205}, {"cv_rms_d": float("inf")}]
    w = [wt for _, wt in order_weights(table)]
    assert len(w) == 2 and w[0] == 1.0 and abs(w[1] - 0.5) < 1e-9, w
    cv = lambda gain: {"cv_rms_d": {"2": 0.2 * (1 + gain), "edge 3": 0.2}}
    assert edge_weight(cv(0.0)) == 0.0 and edge_weight(cv(-0.1)) == 0.0 and edge_weight(cv(0.05)) == 1.0
    assert abs(edge_weight(cv(0.0199)) - 0.4975) < 1e-9 and abs(edge_weight(cv(0.0201)) - 0.5025) < 1e-9
    # a CV that failed in a fold (inf): the cubic is not taken where it failed, taken where only the quadratic did
    inf = float("inf")
    assert edge_weight({"cv_rms_d": {"2": inf, "edge 3": inf}}) == 0.0  # (inf / inf: was NaN, no order left)
    assert edge_weight({"cv_rms_d": {"2": 0.2, "edge 3": inf}}) == 0.0
    assert edge_weight({"cv_rms_d": {"2": inf, "edge 3": 0.2}}) == 1.0


def test_a_near_tie_at_the_edge_choice_moves_the_map_a_little(monkeypatch):
    """Where the frame cells' CV puts the edge cubic at the 2 % threshold, a change of the tiles that moves the
    margin from 1.99 to 2.01 % moved the map by the whole difference between the quadratic and the cubic (the rule
    before: a hard choice; the benchmark's phone copies moved by 0.01-0.03 D between machines). The blend moves it
    by under 2 % of that. The CV values are set (monkeypatched `model.cv_rms`) on the phone's four charts' tiles."""
    import aat_deploy.calibrate.model as model

    obs = _tiles_of(_measure_map, seed=0)

    def cv_with(gain):  # the edge cubic predicts held-out cells `gain` better than the quadratic
        return lambda o, fam, deg, rad, fd, folds, low=None: 0.2 if low is None else 0.2 / (1 + gain)

    fits = {}
    for gain in (0.0, 0.0199, 0.0201, 0.04):
        monkeypatch.setattr(model, "cv_rms", cv_with(gain))
        fits[gain] = fit_model(obs)
    x, y = np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 31))
    r = np.sqrt(rho2(x, y))
    x, y = x[(r >= 0.66) & (r < 0.9)], y[(r >= 0.66) & (r < 0.9)]
    diff = lambda a, b: float(np.sqrt(np.mean(np.concatenate(
        [fits[a].predict(x, y, np.full(x.shape, t)) - fits[b].predict(x, y, np.full(x.shape, t))
         for t in np.linspace(5.6, 14.3, 6)]) ** 2)))
    whole = diff(0.0, 0.04)  # the quadratic against the cubic
    assert whole > 0.03, whole
    assert diff(0.0199, 0.0201) < 0.02 * whole, (diff(0.0199, 0.0201), whole)
    assert {c.focus_degree for c in fits[0.0199].blend} == {2, 3}  # both in the blend, the cubic at about half
