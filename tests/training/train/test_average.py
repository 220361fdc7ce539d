"""training.train.average: the element-wise mean of checkpoints' weights; the probe that scores it picks its window."""

import pytest
import torch
from torch import nn

from benchmarks.probes.anycam_swa import main as swa_main
from benchmarks.probes.anycam_swa import window
from training.train.average import average_state_dicts


def _state(seed: int) -> dict:
    torch.manual_seed(seed)
    net = nn.Sequential(nn.Linear(3, 2), nn.BatchNorm1d(2))
    net.train()
    for _ in range(seed + 1):  # num_batches_tracked differs per state
        net(torch.randn(5, 3))
    return {k: v.clone() for k, v in net.state_dict().items()}


def test_floats_are_the_mean_and_counters_come_from_the_last():
    a, b, c = _state(0), _state(1), _state(2)
    got = average_state_dicts([a, b, c])
    # hand-computed entry by entry
    w = (a["0.weight"] + b["0.weight"] + c["0.weight"]) / 3
    torch.testing.assert_close(got["0.weight"], w)
    torch.testing.assert_close(got["1.running_var"], (a["1.running_var"] + b["1.running_var"] + c["1.running_var"]) / 3)
    assert got["1.num_batches_tracked"].item() == 3 and got["1.num_batches_tracked"].dtype == torch.long
    assert got["0.weight"].dtype == torch.float32
    # the inputs are untouched and one state averages to itself
    assert torch.equal(average_state_dicts([a])["0.bias"], a["0.bias"])


def test_mismatches_are_refused_naming_the_entry():
    a, b = _state(0), _state(1)
    with pytest.raises(ValueError, match="no state"):
        average_state_dicts([])
    b2 = dict(b)
    b2["0.weight"] = torch.zeros(3, 3)
    with pytest.raises(ValueError, match=r"0\.weight"):
        average_state_dicts([a, b2])
    b3 = {k: v for k, v in b.items() if k != "0.bias"}
    with pytest.raises(ValueError, match=r"0\.bias"):
        average_state_dicts([a, b3])


def test_the_window_is_inclusive_and_in_step_order(tmp_path):
    for s in (200, 1000, 800, 12000, 400):
        (tmp_path / f"step_{s:05d}.pt").write_bytes(b"x")
    (tmp_path / "notes.txt").write_text("not a checkpoint")
    assert [p.name for p in window(tmp_path, 400, 1000)] == ["step_00400.pt", "step_00800.pt", "step_01000.pt"]
    assert [p.name for p in window(tmp_path, 1000, None)] == ["step_01000.pt", "step_12000.pt"]


def test_the_probe_refuses_too_few_checkpoints_and_an_existing_out(tmp_path, capsys):
    (tmp_path / "step_00200.pt").write_bytes(b"x")
    with pytest.raises(SystemExit):
        swa_main([str(tmp_path), "--from-step", "0", "--stacks", str(tmp_path)])
    assert "need 2" in capsys.readouterr().err
    out = tmp_path / "rows.json"
    out.write_text("{}")
    with pytest.raises(SystemExit):
        swa_main([str(tmp_path), "--from-step", "0", "--stacks", str(tmp_path), "--out", str(out)])
    assert "exists" in capsys.readouterr().err and out.read_text() == "{}"


def test_the_average_checkpoint_keeps_the_steps_and_refuses_two_runs(tmp_path):
    from benchmarks.probes.anycam_swa import averaged_checkpoint

    paths = []
    for i, (run, step) in enumerate((("v9", 200), ("v9", 400), ("v8", 600))):
        p = tmp_path / f"step_{step:05d}.pt"
        torch.save({"model": _state(i), "config": {"name": run}, "step": step}, p)
        paths.append(p)
    got = averaged_checkpoint(paths[:2])
    assert got["averaged_steps"] == [200, 400] and got["step"] == 400 and got["config"]["name"] == "v9"
    torch.testing.assert_close(got["model"]["0.weight"], (_state(0)["0.weight"] + _state(1)["0.weight"]) / 2)
    with pytest.raises(ValueError, match="more than one run"):
        averaged_checkpoint(paths)


def test_the_probe_refuses_a_missing_folder_no_batches_and_an_existing_save(tmp_path, capsys):
    with pytest.raises(SystemExit):
        swa_main([str(tmp_path / "nope"), "--from-step", "0", "--stacks", str(tmp_path)])
    assert "no such folder" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        swa_main([str(tmp_path), "--from-step", "0", "--stacks", str(tmp_path), "--bn-batches", "0"])
    assert "--bn-batches" in capsys.readouterr().err
    for i, step in enumerate((200, 400)):
        torch.save({"model": _state(i), "config": {"name": "v9"}, "step": step}, tmp_path / f"step_{step:05d}.pt")
    save = tmp_path / "saved"
    save.mkdir()
    kept = save / "v9_swa200-400_pbn50.pt"
    kept.write_bytes(b"kept")
    with pytest.raises(SystemExit):
        swa_main([str(tmp_path), "--from-step", "0", "--stacks", str(tmp_path), "--bn-batches", "50", "--save", str(save)])
    assert "never overwritten" in capsys.readouterr().err and kept.read_bytes() == b"kept"
