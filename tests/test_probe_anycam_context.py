"""probes/anycam_context, anycam_errmap, anycam_border and anycam_precise_bn: argument checks made before any
export or render."""

import pytest

from benchmarks.probes import anycam_context, anycam_errmap


def test_context_refuses_even_windows_and_missing_checkpoints(tmp_path, capsys):
    ck = tmp_path / "last.pt"
    ck.write_bytes(b"")
    with pytest.raises(SystemExit):
        anycam_context.main([str(ck), "--windows", "0,8", "--out", str(tmp_path / "o")])
    assert "odd positive sizes or 0, got [8]" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        anycam_context.main([str(tmp_path / "none.pt"), "--out", str(tmp_path / "o")])
    assert "none.pt: no such checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_errmap_never_overwrites(tmp_path, capsys):
    out = tmp_path / "fig.png"
    out.write_bytes(b"mine")
    with pytest.raises(SystemExit):
        anycam_errmap.main(["--model", str(tmp_path / "m.onnx"), "--out", str(out)])
    assert "fig.png: exists" in capsys.readouterr().err
    assert out.read_bytes() == b"mine"


def test_border_probe_squares_and_its_three_ways():
    import numpy as np

    from benchmarks.probes.anycam_border import squares, three_ways

    assert squares(640, 960, 128, 128) == [(y, x) for y in (128, 256, 384) for x in (128, 256, 384, 512, 640)]
    assert squares(300, 300, 128, 128) == []
    rng = np.random.default_rng(0)
    stack = rng.random((3, 3, 384, 384)).astype(np.float32)
    maps = rng.random((4, 384, 384)).astype(np.float32)
    seen = []

    def infer(st, mp):  # the "depth" is the first frame's red channel plus the first map: shows what was passed
        seen.append((st.copy(), mp.copy()))
        assert st.shape[-2:] == mp.shape[-2:]
        return st[0, 0] + mp[0]

    alone, mirrored, true = three_ways(infer, stack, maps, 128, 160, 64, 32)
    want = stack[0, 0, 128:192, 160:224] + maps[0, 128:192, 160:224]
    sq, msq = stack[:, :, 128:192, 160:224], maps[:, 128:192, 160:224]
    (s0, m0), (s1, m1), (s2, m2) = seen
    np.testing.assert_array_equal(s0, sq)
    np.testing.assert_array_equal(m0, msq)
    # the margin is the square mirrored (stack and maps alike), or the frame around it
    np.testing.assert_array_equal(s1, np.pad(sq, ((0, 0), (0, 0), (32, 32), (32, 32)), mode="reflect"))
    np.testing.assert_array_equal(m1, np.pad(msq, ((0, 0), (32, 32), (32, 32)), mode="reflect"))
    np.testing.assert_array_equal(s2, stack[:, :, 96:224, 128:256])
    np.testing.assert_array_equal(m2, maps[:, 96:224, 128:256])
    # the square itself is the same three ways; only what surrounds it differs
    for d in (alone, mirrored, true):
        np.testing.assert_array_equal(d, want)


def test_precise_bn_probe_refuses_bad_counts_and_missing_checkpoints(tmp_path, capsys):
    from benchmarks.probes import anycam_precise_bn

    ck = tmp_path / "last.pt"
    ck.write_bytes(b"")
    with pytest.raises(SystemExit):
        anycam_precise_bn.main([str(ck), "--stacks", str(tmp_path), "--batches", "0,-5"])
    assert "--batches: counts >= 0, got [0, -5]" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        anycam_precise_bn.main([str(tmp_path / "none.pt"), "--stacks", str(tmp_path)])
    assert "no such checkpoint: " in capsys.readouterr().err
    out = tmp_path / "mine.json"
    out.write_text("mine")
    with pytest.raises(SystemExit):
        anycam_precise_bn.main([str(ck), "--stacks", str(tmp_path), "--out", str(out)])
    assert "mine.json: exists" in capsys.readouterr().err and out.read_text() == "mine"


def test_precise_bn_probe_saves_atomically(tmp_path, monkeypatch):
    """score's --save writes through a temporary file: a write that fails half-way leaves no file at its name (a
    half-written net there would be refused as existing by the next run, and read as a net by the export)."""
    from pathlib import Path
    from types import SimpleNamespace

    import torch

    import training.nets.registry
    import training.train.checkpoint
    import training.train.data
    import training.train.evaluate
    import training.train.loop
    import training.train.precise_bn
    from benchmarks.probes import anycam_precise_bn

    cfg = SimpleNamespace(name="v9", val_data={}, simulator=None, lens=None, effects=None, net="x", val_items=1,
                          loss=SimpleNamespace(mask_focus_range=True), field_channels=0,
                          to_dict=lambda: {"name": "v9"}, hash=lambda: "h")
    monkeypatch.setattr(training.train.loop, "load_trained", lambda path: (torch.nn.Linear(2, 2), cfg))
    monkeypatch.setattr(training.train.checkpoint, "load", lambda path: {"step": 7})
    monkeypatch.setattr(training.train.data, "make_dataset", lambda *a, **k: None)
    monkeypatch.setattr(training.train.evaluate, "evaluate",
                        lambda *a, **k: ({"mae": 1.0, "rmse": 1.0, "abs_rel": 0.1}, None))
    monkeypatch.setattr(training.nets.registry, "get", lambda name: SimpleNamespace(focus_maps=False))
    monkeypatch.setattr(training.train.precise_bn, "recompute_bn_stats", lambda model, batches, forward: 5)
    monkeypatch.setattr(anycam_precise_bn, "_train_batches", lambda cfg, stacks, n: [])

    def half_write(obj, path):
        Path(path).write_bytes(b"half")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", half_write)
    save = tmp_path / "saved"
    with pytest.raises(OSError, match="disk full"):
        anycam_precise_bn.score(tmp_path / "last.pt", str(tmp_path), [0, 5], save)
    assert list(save.iterdir()) == []


def test_fit_gap_probe_refuses_bad_counts_missing_checkpoints_and_an_existing_out(tmp_path, capsys):
    from benchmarks.probes import anycam_fit_gap

    ck = tmp_path / "last.pt"
    ck.write_bytes(b"x")
    for argv, msg in (([str(ck), "--stacks", str(tmp_path), "--n", "0"], "at least 1"),
                      ([str(ck), "--stacks", str(tmp_path), "--n-train", "0"], "at least 1"),
                      ([str(tmp_path / "none.pt"), "--stacks", str(tmp_path)], "no such checkpoint")):
        with pytest.raises(SystemExit):
            anycam_fit_gap.main(argv)
        assert msg in capsys.readouterr().err
    out = tmp_path / "rows.json"
    out.write_text("[]")
    with pytest.raises(SystemExit):
        anycam_fit_gap.main([str(ck), "--stacks", str(tmp_path), "--out", str(out)])
    assert "exists" in capsys.readouterr().err and out.read_text() == "[]"


def test_fit_gap_item_spread_by_hand():
    import numpy as np

    from benchmarks.probes.anycam_fit_gap import item_spread

    e = np.array([1.0] * 19 + [81.0])  # 20 items: the worst 5 % is one item, 81 of a sum of 100
    got = item_spread(e)
    assert got == {"n": 20, "median_m": 1.0, "mean_m": 5.0, "max_m": 81.0, "worst_5pct_share": 0.81}


def test_stack_curve_probe_refuses_before_any_work(tmp_path, capsys):
    from benchmarks.probes import anycam_stack_curve

    ck = tmp_path / "step_00200.pt"
    ck.write_bytes(b"")
    out = tmp_path / "curve.json"
    with pytest.raises(SystemExit):
        anycam_stack_curve.main([str(ck), "--n", "0", "--out", str(out)])
    assert "--n: at least 1 stack" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        anycam_stack_curve.main([str(tmp_path / "none.pt"), "--out", str(out)])
    assert "no such checkpoint" in capsys.readouterr().err
    out.write_text("mine")
    with pytest.raises(SystemExit):
        anycam_stack_curve.main([str(ck), "--out", str(out)])
    assert "curve.json: exists" in capsys.readouterr().err
    assert out.read_text() == "mine"
    out.unlink()
    with pytest.raises(SystemExit):
        anycam_stack_curve.main([str(ck), "--stack-size", "1", "--out", str(out)])
    assert "--stack-size: 2 to 32 frames, got 1" in capsys.readouterr().err
    assert not out.exists()


def test_fixed_stacks_sweeps_the_same_scenes_with_the_frames_asked_for(monkeypatch):
    """--stack-size: the validation spec (its own seed, training photographs) with only the frame count changed."""
    import training.train.testsets as ts
    from benchmarks.probes.anycam_tiles import fixed_stacks

    seen = []
    monkeypatch.setattr(ts, "load_test_set", lambda spec, cache, progress: seen.append(spec) or {"procedural": []})
    fixed_stacks("rf50", "validation", 4, "unused")
    fixed_stacks("rf50", "validation", 4, "unused", stack_size=3)
    a, b = seen
    assert (a.stack_size, b.stack_size) == (8, 3)
    assert a.seed == b.seed and a.photo_split == b.photo_split == "train"
    assert {k: v for k, v in vars(a).items() if k != "stack_size"} == {k: v for k, v in vars(b).items()
                                                                       if k != "stack_size"}


def test_stack_curve_errors_by_hand():
    import numpy as np

    from benchmarks.probes.anycam_stack_curve import stack_errors

    truth = np.array([[1.0, 2.0], [4.0, 0.0]])  # 0: no truth, left out
    depth = np.array([[2.0, 2.0], [2.0, 9.0]])
    e = stack_errors(depth, truth)
    assert e["mae_m"] == pytest.approx((1 + 0 + 2) / 3)
    assert e["mae_d"] == pytest.approx((0.5 + 0 + 0.25) / 3)  # |1/2 - 1/1|, 0, |1/2 - 1/4|
    assert e["median_m"] == pytest.approx(1.0)


def test_choose_takes_the_lowest_on_one_dozen_and_judges_on_another(tmp_path, capsys):
    import json

    from benchmarks.probes import anycam_choose

    sel = {"first": 12, "n": 2, "classical_lens_map": {"mae_m": [1.0, 1.0]},
           "rows": [{"step": 400, "mae_m": [0.5, 0.7]}, {"step": 200, "mae_m": [0.6, 0.6]},
                    {"step": 600, "mae_m": [0.9, 0.5]}]}
    assert anycam_choose.choose(sel)["step"] == 200  # 0.6, tied with 400: the earlier step
    sel["rows"][2]["mae_m"] = [0.9, 0.1]
    assert anycam_choose.choose(sel)["step"] == 600  # the lowest mean, not the lowest stack
    cur = {"first": 0, "classical_lens_map": {"mae_m": [2.0, 4.0], "mae_d": [0.2, 0.4]},
           "rows": [{"step": 200, "mae_m": [1.0, 2.0], "mae_d": [0.1, 0.1]}]}
    j = anycam_choose.judge(200, cur, [2.0, 2.0, 9.0])
    assert j["mae_m"] == 1.5 and j["classical_mae_m"] == 3.0 and j["first_run_tiles_mae_m"] == 2.0
    assert j["vs_classical_m"][0] == 0.5 and j["vs_classical_d"][0] == pytest.approx(1 / 3)
    assert j["vs_first_run_tiles_m"][0] == 0.75
    a, b, first = tmp_path / "s.json", tmp_path / "j.json", tmp_path / "f.json"
    a.write_text(json.dumps(sel))
    b.write_text(json.dumps({**cur, "first": 12}))
    first.write_text(json.dumps({"mae_m": [[2.0], [2.0]]}))
    with pytest.raises(SystemExit):
        anycam_choose.main(["--select", str(a), "--judge", str(b), "--first-run", str(first)])
    assert "score the same stacks" in capsys.readouterr().err
    b.write_text(json.dumps({**cur, "first": 13, "n": 2}))  # stacks 13-14 against 12-13: one stack in both
    with pytest.raises(SystemExit):
        anycam_choose.main(["--select", str(a), "--judge", str(b), "--first-run", str(first)])
    assert "(13-14) score the same stacks" in capsys.readouterr().err
    # the first run's rows are those of the judging stacks (anycam_tiles scores stacks 0, 1, ...), or refused
    cur = {**cur, "first": 2, "n": 2, "rows": [{"step": 600, "mae_m": [1.0, 2.0], "mae_d": [0.1, 0.1]}]}
    b.write_text(json.dumps(cur))
    with pytest.raises(SystemExit):
        anycam_choose.main(["--select", str(a), "--judge", str(b), "--first-run", str(first)])
    assert "scores 0 of the judging stacks 2-3" in capsys.readouterr().err
    first.write_text(json.dumps({"mae_m": [[9.0], [9.0], [2.0], [2.0]]}))
    assert anycam_choose.main(["--select", str(a), "--judge", str(b), "--first-run", str(first),
                               "--out", str(tmp_path / "o.json")]) == 0
    got = json.loads((tmp_path / "o.json").read_text())
    assert got["step"] == 600 and got["first_run_tiles_mae_m"] == 2.0 and got["vs_first_run_tiles_m"][0] == 0.75
    sel["rows"][0]["mae_d"] = sel["rows"][1]["mae_d"] = sel["rows"][2]["mae_d"] = [0.1, 0.1]
    a.write_text(json.dumps({**sel, "classical_lens_map": {"mae_m": [1.0, 1.0], "mae_d": [0.2, 0.2]}}))
    png = tmp_path / "c.png"
    assert anycam_choose.main(["--select", str(a), "--judge", str(b), "--first-run", str(first),
                               "--png", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(SystemExit):  # an existing figure is never overwritten
        anycam_choose.main(["--select", str(a), "--judge", str(b), "--first-run", str(first), "--png", str(png)])
    assert "c.png: exists" in capsys.readouterr().err
    # a run scored in parts: rows pooled, each step once; parts of other stacks refused
    late = {**sel, "rows": [{"step": 800, "mae_m": [0.0, 0.2]}, sel["rows"][0]]}
    pooled = anycam_choose.pool([sel, late], "--select")
    assert [r["step"] for r in pooled["rows"]] == [200, 400, 600, 800] and anycam_choose.choose(pooled)["step"] == 800
    with pytest.raises(SystemExit, match="different stacks"):
        anycam_choose.pool([sel, {**late, "first": 0}], "--select")
    assert anycam_choose.choose_window(pooled, 2) == (600, 800, pytest.approx(0.3))  # means 0.6, 0.6, 0.5, 0.1 m
    assert anycam_choose.choose_window(pooled, 4)[:2] == (200, 800)
    with pytest.raises(SystemExit, match="--window 5"):
        anycam_choose.choose_window(pooled, 5)
    with pytest.raises(SystemExit, match="step 400 scored twice"):
        anycam_choose.pool([sel, {**sel, "rows": [{"step": 400, "mae_m": [0.1, 0.1]}]}], "--select")


def test_compare_pairs_two_models_scene_by_scene(tmp_path, capsys):
    import json

    from benchmarks.probes import anycam_compare

    def res(maes, real):
        per = {"dfv_aat, lens map": {"procedural": [{"mae": m, "mae_outer": 2 * m} for m in maes],
                                     "middlebury": [{"mae": real}]}}
        return {"model": "m", "lenses": {"paper50": {"fixed": {"per_image": per}}}}

    rows = anycam_compare.compare(res([1.0, 2.0, 3.0], 0.5), res([2.0, 4.0, 6.0], 1.0), "dfv_aat, lens map")
    (e,) = rows
    assert e["a_mae"] == 2.0 and e["b_mae"] == 4.0 and e["n"] == 3
    assert e["a_over_b"][0] == 0.5 and e["a_over_b_outer"][0] == 0.5 and e["middlebury_a_over_b"] == 0.5
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(res([1.0, 2.0], 0.5)))
    b.write_text(json.dumps(res([1.0, 2.0, 3.0], 0.5)))
    with pytest.raises(SystemExit, match="not the same test set"):
        anycam_compare.main([str(a), str(b)])
    # as many scenes, but others: the classical method's per-scene MAE (the same for any model) tells
    ra, rb = res([1.0, 2.0, 3.0], 0.5), res([1.0, 2.0, 3.0], 0.5)
    for r, cl in ((ra, [0.4, 0.5, 0.6]), (rb, [0.4, 0.5, 0.6])):
        r["lenses"]["paper50"]["fixed"]["per_image"]["Classical, lens map"] = {"procedural": [{"mae": m} for m in cl]}
    assert len(anycam_compare.compare(ra, rb, "dfv_aat, lens map")) == 1
    rb["lenses"]["paper50"]["fixed"]["per_image"]["Classical, lens map"]["procedural"][2]["mae"] = 0.7
    with pytest.raises(SystemExit, match="classical method's per-scene MAE differs"):
        anycam_compare.compare(ra, rb, "dfv_aat, lens map")
    with pytest.raises(SystemExit):
        anycam_compare.main([str(a), str(b), "--row", "none"])
    assert "no lens and protocol or table row with the row 'none'" in capsys.readouterr().err


def test_error_by_interval_by_hand():
    """Frames at 0.5, 1 and 4 m (2, 1, 0.25 D): truths at 0.4 (nearer than all), 0.8 (between frames 1 and 2), 2 and
    8 m (between 2 and 3, farther than all); errors by hand."""
    import numpy as np

    from benchmarks.probes.anycam_error_by_interval import by_interval, summarise

    truth = np.array([[0.4, 0.8], [2.0, 8.0]])
    depth = np.array([[0.5, 0.8], [2.5, 4.0]])
    got = by_interval(depth, truth, np.array([4.0, 0.5, 1.0]))  # any order: sorted by the function
    assert [g["pixels"] for g in got] == [1, 1, 1, 1]
    assert [g["abs_m"] for g in got] == pytest.approx([0.1, 0.0, 0.5, 4.0])
    assert [g["abs_d"] for g in got] == pytest.approx([0.5, 0.0, 0.1, 0.125])
    s = summarise([got, got])
    assert [v["error_share_m"] for v in s] == pytest.approx([0.1 / 4.6, 0, 0.5 / 4.6, 4.0 / 4.6])
    assert [v["pixel_share"] for v in s] == pytest.approx([0.25] * 4)
    assert s[3]["mae_m"] == pytest.approx(4.0) and s[2]["mae_d"] == pytest.approx(0.1)
    holes = by_interval(depth, np.where(truth > 1, truth, 0.0), np.array([4.0, 0.5, 1.0]))
    assert [g["pixels"] for g in holes] == [0, 0, 1, 1]


def test_stack_curve_leaves_out_a_checkpoint_onnxruntime_disagrees_with(tmp_path, monkeypatch):
    """A checkpoint whose export fails the parity check is recorded as unexportable, not scored, and the rest go on."""
    import json

    import numpy as np

    import training.train.export as tx
    from benchmarks.probes import anycam_stack_curve
    from training.train.testsets import TestItem

    rng = np.random.default_rng(0)
    item = TestItem("procedural_000", rng.random((3, 3, 32, 32)).astype(np.float32), np.array([0.5, 1.0, 2.0]),
                    np.full((32, 32), 1.0, np.float32), rng.random((3, 32, 32)).astype(np.float32))
    monkeypatch.setattr(anycam_stack_curve, "fixed_stacks", lambda *a, **k: [item])

    def refuse(ck, out, force=False):
        raise RuntimeError(f"{out}: onnxruntime differs from torch by 1.10e-03 of the inputs' magnitude (> 0.001)")

    monkeypatch.setattr(tx, "export_checkpoint", refuse)
    cks = [tmp_path / "step_00200.pt", tmp_path / "step_00400.pt"]
    for ck in cks:
        ck.write_bytes(b"")
    out = tmp_path / "curve.json"
    assert anycam_stack_curve.main([*map(str, cks), "--n", "1", "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["rows"] == []
    assert [u["checkpoint"] for u in got["unexportable"]] == [str(c) for c in cks]
    assert got["unexportable"][0]["reason"].startswith("onnxruntime differs from torch by 1.10e-03")


def test_stack_curve_stops_on_any_other_export_failure(tmp_path, monkeypatch):
    import numpy as np

    import training.train.export as tx
    from benchmarks.probes import anycam_stack_curve
    from training.train.testsets import TestItem

    item = TestItem("procedural_000", np.zeros((3, 3, 32, 32), np.float32), np.array([0.5, 1.0, 2.0]),
                    np.ones((32, 32), np.float32), np.zeros((3, 32, 32), np.float32))
    monkeypatch.setattr(anycam_stack_curve, "fixed_stacks", lambda *a, **k: [item])

    def broken(ck, out, force=False):
        raise RuntimeError("something else")

    monkeypatch.setattr(tx, "export_checkpoint", broken)
    ck = tmp_path / "step_00200.pt"
    ck.write_bytes(b"")
    with pytest.raises(RuntimeError, match="something else"):
        anycam_stack_curve.main([str(ck), "--n", "1", "--out", str(tmp_path / "curve.json")])
    assert not (tmp_path / "curve.json").exists()
