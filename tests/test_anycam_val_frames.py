"""benchmarks/anycam_val_baseline.py --frames-set: the set keeps the first draws whose sweep changes the blur by at
least its floor, and an exported .onnx and its .pt checkpoint score alike (frames given far -> near are sorted)."""

import json

import numpy as np
import pytest
import torch
from conftest import ROOT

from benchmarks.anycam_val_baseline import frames_set, load_net


def _spec(tmp_path, items, floor, n_items=40):
    d = json.loads((ROOT / "configs/anycam/val_frames256.json").read_text())
    d["items"], d["min_span_px"] = items, floor
    d["data"] = {**d["data"], "n_items": n_items, "cache_dir": None}
    p = tmp_path / "set.json"
    p.write_text(json.dumps(d))
    return p


def test_the_set_keeps_the_first_draws_of_enough_blur_change_in_index_order(tmp_path):
    spec, ds, idx = frames_set(_spec(tmp_path, 6, 9.0))
    span = [ds.draw_sweep(np.random.default_rng([ds.cfg.seed, i, 35]), i).span_px() for i in range(40)]
    assert idx == [i for i in range(40) if span[i] >= 9.0][:6]
    assert any(s < 9.0 for s in span[: idx[-1]])  # some draws were left out before the last kept one
    with pytest.raises(SystemExit, match="raise n_items"):
        frames_set(_spec(tmp_path, 40, 9.0))


def test_onnx_and_checkpoint_of_one_net_score_alike_whatever_the_frame_order():
    pt, onnx = ROOT / "checkpoints/dfv_aat_v1/last.pt", ROOT / "models/reproduce/dfv_aat_v1.onnx"
    if not (pt.is_file() and onnx.is_file()):
        pytest.skip("the first any-camera run's checkpoint or export is not in this checkout")
    rng = np.random.default_rng(0)
    s, h, w = 5, 64, 64
    fd = np.linspace(0.2, 2.0, s)[:, None, None] + 0.05 * rng.random((s, h, w))  # ascending: far -> near
    item = {"stack": torch.from_numpy(rng.random((s, 3, h, w), np.float32) - 0.5),
            "focus_diopters": torch.from_numpy(fd.astype(np.float32)),
            "defocus_px_per_d": torch.full((1, h, w), 8.0)}
    a, b = load_net(pt)[0](item), load_net(onnx)[0](item)
    assert a.shape == (h, w) and np.isfinite(a).all()
    np.testing.assert_allclose(b, a, rtol=1e-3)
    flipped = {**item, "stack": item["stack"].flip(0), "focus_diopters": item["focus_diopters"].flip(0)}
    np.testing.assert_allclose(load_net(onnx)[0](flipped), a, rtol=1e-3)


def test_metre_spread_names_the_share_of_the_worst_items_hand_computed():
    from benchmarks.anycam_val_baseline import metre_spread

    rows = [{"mae": m, "frames_l1": f} for m, f in zip([1.0] * 19 + [81.0], [1.0] * 20)] + [
        {"mae": float("nan"), "frames_l1": 1.0}]
    text = metre_spread(rows, "ref")
    assert "worst 1 of 20 items carry 81% of the summed MAE (m) and 5% of the summed frame error" in text


def test_the_curve_groups_a_runs_checkpoints_by_folder_in_step_order(tmp_path):
    from benchmarks.anycam_val_baseline import plot_curves

    def rows(v):
        return [{"frames_l1": v * (1 + 0.1 * k)} for k in range(8)] + [{"frames_l1": float("nan")}]

    scores = {"ref/last.pt": {"step": 24000, "rows": rows(1.0)}, "classical, per-pixel map": {"rows": rows(2.0)},
              "v5/step2000.pt": {"step": 2000, "rows": rows(1.5)}, "v5/step1000.pt": {"step": 1000, "rows": rows(3.0)},
              "x/model.onnx": {"step": "onnx", "rows": rows(0.5)}}
    runs = plot_curves(scores, ["ref/last.pt", "v5/step2000.pt", "v5/step1000.pt", "x/model.onnx"],
                       tmp_path / "c.png")
    assert list(runs) == ["v5"] and [p[0] for p in sorted(runs["v5"])] == [1000, 2000]
    assert [round(p[1], 6) for p in sorted(runs["v5"])] == [3.0, 1.5]
    assert (tmp_path / "c.png").stat().st_size > 1000
