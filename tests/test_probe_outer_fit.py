"""benchmarks/probes/outer_fit.py and tile_size.py (issue 33): the split of a map's error into parts that add up to
it, by hand; the radius bins; the fit's tile grids by hand; their one-line refusals (the renders and fits are the
probes' own minutes, not tested here)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.probes import outer_fit as O
from benchmarks.probes import tile_size as T


def test_split_shares_add_to_one_and_are_each_parts_projection_by_hand():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 3, 4)), rng.normal(size=(2, 3, 4))
    m = np.ones((3, 4), bool)
    out = O.split(a + b, {"a": a, "b": b}, {"all": m, "none": np.zeros((3, 4), bool)})
    assert "none" not in out  # an empty mask is left out
    row = out["all"]
    assert row["a"]["share"] + row["b"]["share"] == pytest.approx(1.0)
    assert row["a"]["share"] == pytest.approx(np.sum(a * (a + b)) / np.sum((a + b) ** 2))
    assert row["total"]["rms_d"] == pytest.approx(np.sqrt(np.mean((a + b) ** 2)))
    assert row["b"]["mean_d"] == pytest.approx(b.mean()) and row["pixel_share"] == 1.0
    # pixel-frame masks (S, H, W) pick per frame
    pf = np.zeros((2, 3, 4), bool)
    pf[1, 0, 0] = True
    one = O.split(a + b, {"a": a, "b": b}, {"one": pf})["one"]
    assert one["a"]["share"] == pytest.approx(a[1, 0, 0] / (a + b)[1, 0, 0])
    assert one["pixel_share"] == pytest.approx(1 / 24)


def test_split_refuses_parts_that_do_not_add_up():
    a = np.ones((1, 2, 2))
    with pytest.raises(ValueError, match="do not add up"):
        O.split(a, {"a": a, "b": 0.1 * a}, {"all": np.ones((2, 2), bool)})


def test_bin_masks_end_at_the_farthest_tile_and_do_not_overlap():
    r = np.linspace(0, 1, 101)[None, :]
    m = O.bin_masks(r, 0.92)
    rings = [k for k in m if k != "within"]
    assert rings == ["0-0.66", "0.66-0.75", "0.75-0.84", "0.84-0.92"]
    assert np.array_equal(sum(m[k].astype(int) for k in rings), m["within"].astype(int))
    assert m["within"].sum() == 93 and not m["0.84-0.92"][0, 93]  # 0..0.92 inclusive


@pytest.mark.parametrize("tile, grid, border, r", [
    (27, [17, 23], [9, 10], 0.920),  # the fit's: docs/calibration.md, "The tiles and the frame's corners"
    (20, [24, 32], [0, 0], 0.965),   # 20 px divides both sides: centres 10 px from each edge, hypot(310, 230) / 400
    (32, [15, 20], [0, 0], 0.944),   # centres 16 px from each edge: hypot(304, 224) / 400
])
def test_tile_grid_by_hand(tile, grid, border, r):
    g = T.tile_grid(480, 640, tile, 4 / 3)
    assert g["grid"] == grid and g["border_px"] == border
    assert g["farthest_centre_r"] == pytest.approx(r, abs=5e-4)


@pytest.mark.parametrize("mod, args, says", [
    (O, ["--noise-draws", "-1"], "--noise-draws -1: 0 or more"),
    (O, ["--variants", "nominl"], "--variants: nominl not of"),
    (T, ["--tiles-px", "27,x"], "whole numbers of pixels"),
    (T, ["--tiles-px", "4"], "sizes of 8 to 96 px"),
    (T, ["--variants", ""], "nothing to run"),
])
def test_probes_refuse_bad_arguments_in_one_line_before_reading_the_truth(tmp_path, capsys, mod, args, says):
    with pytest.raises(SystemExit):
        mod.main(["--truth", str(tmp_path / "no_truth.json"), *args, "--out", str(tmp_path / "o.json")])
    assert says in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "o.json").exists()


def test_more_charts_parses_extra_charts_and_refuses_bad_ones_by_name():
    from benchmarks.probes import more_charts as M

    assert M.parse_extra("0.128:-6:5,0.083:10:-4") == [(0.128, (-6.0, 5.0)), (0.083, (10.0, -4.0))]
    assert M.parse_extra("") == []
    with pytest.raises(ValueError, match="'0.1:3': distance_m:tilt_x_deg:tilt_y_deg"):
        M.parse_extra("0.128:-6:5,0.1:3")
    with pytest.raises(ValueError, match="'2:0:0': a distance of 0.055-0.5 m"):
        M.parse_extra("2:0:0")


def test_more_charts_refuses_no_extra_chart_in_one_line(tmp_path, capsys):
    from benchmarks.probes import more_charts as M

    with pytest.raises(SystemExit):
        M.main(["--truth", str(tmp_path / "t.json"), "--extra", "", "--out", str(tmp_path / "o.json")])
    assert "--extra: no chart given" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "o.json").exists()


def test_clean_sweep_is_the_benchmarks_sweep_without_noise_cached_apart_and_checked(tmp_path, monkeypatch):
    """`clean_sweep` renders through `bench_calibrate.sweep(noise=False)`: the variant's effects but `noise`, the
    same seed, cached under a `_noise0` name next to the noisy sweep's, and a cached one of other lens files is
    refused as the benchmark's own sweeps are (until 2026-11-28 it was a copy of `sweep` without that check)."""
    import json

    import aat_deploy.calibrate.scene as scene
    import aat_deploy.capture.virtual as virtual
    from benchmarks import bench_calibrate as bc

    rig = bc.Rig(bc.LENSES["z35"])
    monkeypatch.setattr(bc, "CACHE", tmp_path)
    monkeypatch.setattr(bc, "chart_for", lambda rig, d: (None, None))
    monkeypatch.setattr(scene, "chart_scene", lambda *a: (np.zeros((4, 6, 3), np.float32), np.full((4, 6), 0.3)))
    shot = []

    def shoot(lens, rgb, depth, true_m, effects, src, seed, workers, cell_px):
        shot.append((list(effects), seed))
        return np.zeros((len(true_m), 3, 4, 6), np.float32), np.asarray(true_m)

    monkeypatch.setattr(virtual, "shoot", shoot)
    O.clean_sweep(rig, "copy", 1, lambda m: None)
    bc.sweep(rig, "copy", 1, lambda m: None)
    noisy = bc.effects_for(rig.setup, "copy")
    assert "noise" in noisy and shot == [([e for e in noisy if e != "noise"], 1001), (noisy, 1001)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["z35_copy_0.6m_soft0.7px.npz",
                                                          "z35_copy_0.6m_soft0.7px_noise0.npz"]
    f = tmp_path / "z35_copy_0.6m_soft0.7px_noise0.npz"
    z = dict(np.load(f))
    np.savez(f, **{**z, "sources": json.dumps({**bc.sweep_sources(rig.setup), "psf": "0" * 64})})
    with pytest.raises(SystemExit) as e:
        O.clean_sweep(rig, "copy", 1, lambda m: None)
    assert str(f) in str(e.value) and "psf 000000000000 then" in str(e.value) and len(shot) == 2


def test_tile_size_exact_reaches_every_run_and_its_rows_are_written(tmp_path, monkeypatch, capsys):
    """--exact goes to every (variant, tile size) run, and the result file records the rows (with their exact
    fits) and its own command; without it no run is asked for exact tiles. The runs are stubbed (their renders and
    fits are the probe's minutes); the truth is a real map file (read before any run)."""
    import json

    calls = []

    def fake_run(variant, truth, tile_px, log, exact=False):
        calls.append((variant, tile_px, exact))
        row = {"variant": variant, "tile_px": tile_px, "grid": [17, 23], "kept_r_max": 0.92, "beyond_share": 0.0145,
               "kept": 1552, "part_a": {"rms_d": 0.0943}, "part_a_fixed_regions_rms_d": {"r <= 0.92": 0.078},
               "schedule": {"rms_d": 0.186}, "near_chart_fitted_mm": 55.0, "order": [2, 12, 3, 2]}
        return row | ({"exact": {"rms_d": 0.075}} if exact else {})

    monkeypatch.setattr(T, "run", fake_run)
    out = tmp_path / "o.json"
    truth = "results/render_truth_map_cellphone_19p.json"
    assert T.main(["--truth", truth, "--variants", "nominal,copy_s2027_0", "--tiles-px", "27,24", "--exact",
                   "--out", str(out)]) == 0
    assert calls == [("nominal", 27, True), ("nominal", 24, True), ("copy_s2027_0", 27, True),
                     ("copy_s2027_0", 24, True)]
    doc = json.loads(out.read_text())
    assert [r["exact"]["rms_d"] for r in doc["rows"]] == [0.075] * 4 and doc["truth"] == truth
    assert doc["command"].startswith("python -m benchmarks.probes.tile_size --truth") and "--exact" in doc["command"]
    assert "| copy_s2027_0 | 24 | 17 x 23 |" in capsys.readouterr().out
    calls.clear()
    T.main(["--truth", truth, "--variants", "nominal", "--tiles-px", "27", "--out", str(tmp_path / "p.json")])
    assert calls == [("nominal", 27, False)] and "exact" not in json.loads((tmp_path / "p.json").read_text())["rows"][0]
