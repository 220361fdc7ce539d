"""scripts.keep_run_weights: each new checkpoint's weights kept once, as step_NNNNN.pt, never overwritten; the
watcher stops when the run has finished."""

import torch

from scripts.keep_run_weights import keep_once, main
from training.train.checkpoint import save_atomic


def _ckpt(path, step, value):
    save_atomic({"model": {"w": torch.full((2,), value)}, "optimizer": {"state": {}}, "step": step,
                 "config": {"name": "run"}}, path)


def test_weights_are_kept_once_per_step_without_the_optimizer(tmp_path):
    last, dest = tmp_path / "last.pt", tmp_path / "kept"
    _ckpt(last, 200, 1.0)
    got = keep_once(last, dest)
    assert got == dest / "step_00200.pt"
    saved = torch.load(got, weights_only=False)
    assert set(saved) == {"model", "config", "step"} and saved["step"] == 200
    assert torch.equal(saved["model"]["w"], torch.full((2,), 1.0))
    _ckpt(last, 200, 5.0)  # the same step again: the kept file is not replaced
    assert keep_once(last, dest) is None
    assert torch.equal(torch.load(got, weights_only=False)["model"]["w"], torch.full((2,), 1.0))
    _ckpt(last, 400, 2.0)
    assert keep_once(last, dest) == dest / "step_00400.pt"


def test_the_watcher_stops_when_the_run_has_finished(tmp_path):
    last, dest = tmp_path / "last.pt", tmp_path / "kept"
    _ckpt(last, 24000, 3.0)
    (tmp_path / "model.pt").write_bytes(b"done")
    assert main([str(last), str(dest), "--every-s", "0"]) == 0
    assert (dest / "step_24000.pt").is_file()
