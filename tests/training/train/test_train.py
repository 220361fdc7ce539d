"""Training loop: config files, schedule, loss, learning on a tiny synthetic set, exact resume, DDP with gloo,
evaluation, CLI. The synthetic set (thin-lens Gaussian blur of random textures at two depth planes) is in
tests/training_fixtures.py."""

from __future__ import annotations

import json
import math
import os
import socket
from pathlib import Path

import numpy as np
import pytest
import torch
from training_fixtures import TwoPlaneStacks, train_config

from training.train.config import (
    ConfigError,
    LossConfig,
    config_from_dict,
    load_config,
)
from training.train.loss import depth_mask, dff_loss, edge_aware_smoothness, masked_l1
from training.train.sampler import ResumableSampler
from training.train.schedule import lr_at

ROOT = Path(__file__).resolve().parents[3]


def test_shipped_configs_load():
    paths = sorted((ROOT / "configs").glob("dff_*.json"))
    assert paths
    for p in paths:
        cfg = load_config(p)
        assert (ROOT / cfg.lens).exists(), p
    with pytest.raises(ConfigError, match="unknown config keys"):
        config_from_dict({"name": "x", "net": "aifnet", "size": "small", "simulator": "aat", "lens": "l", "lr0": 1})
    with pytest.raises(ConfigError, match="simulator"):
        config_from_dict({"name": "x", "net": "aifnet", "size": "small", "simulator": "gauss", "lens": "l"})
    c = train_config()
    assert config_from_dict(json.loads(json.dumps(c.to_dict()))) == c  # checkpoint round trip


def test_cosine_schedule_spans_exactly_the_steps():
    assert lr_at(0, 101, 1.0) == pytest.approx(1.0)
    assert lr_at(50, 101, 1.0) == pytest.approx(0.5)
    assert lr_at(100, 101, 1.0) == pytest.approx(0.0, abs=1e-12)
    assert lr_at(100, 101, 1.0, lr_min=0.1) == pytest.approx(0.1)
    assert lr_at(0, 100, 1.0, warmup_steps=4) == pytest.approx(0.25)
    assert lr_at(4, 100, 1.0, warmup_steps=4) == pytest.approx(1.0)


def test_loss_hand_computed():
    gt = torch.tensor([[[1.0, 2.0], [0.0, 4.0]]])
    pred = torch.tensor([[[1.5, 2.0], [9.0, 3.0]]], requires_grad=True)
    m = depth_mask(gt)
    assert masked_l1(pred, gt, m).item() == pytest.approx((0.5 + 0 + 1) / 3)
    focus = torch.tensor([[1.0, 3.0]])
    assert depth_mask(gt, focus).sum() == 2  # 4 m outside [1, 3]
    aif = torch.zeros(1, 3, 2, 2)
    cfg = LossConfig(level_weights=(3.0, 1.0))
    coarse = pred.detach() + 1.0  # errors 1.5, 1, 0 -> mean 2.5 / 3
    total, parts = dff_loss([(pred, aif, None), (coarse, None, None)], {"depth_m": gt, "focus_m": focus}, cfg)
    assert total.item() == pytest.approx((3 * 1.5 / 3 + 1 * 2.5 / 3) / 4)
    assert parts["depth_l1"] == pytest.approx(0.5)
    total.backward()
    assert pred.grad[0, 1, 0] == 0  # invalid pixel gets no gradient
    empty = dff_loss([(pred, aif, None)], {"depth_m": torch.zeros(1, 2, 2), "focus_m": focus}, LossConfig())[0]
    assert empty.item() == 0.0
    with pytest.raises(ValueError, match="aif"):
        dff_loss([(pred, aif, None)], {"depth_m": gt, "focus_m": focus}, LossConfig(aif=1.0))


def test_smoothness_zero_for_flat_depth_and_edge_aware():
    img = torch.zeros(1, 3, 4, 4)
    flat = edge_aware_smoothness(torch.ones(1, 4, 4), img, eps=0.0)
    assert flat.item() == 0.0
    step_depth = torch.zeros(1, 4, 4)
    step_depth[:, :, 2:] = 1.0
    no_edge = edge_aware_smoothness(step_depth, img, eps=0.0)
    img_edge = img.clone()
    img_edge[..., 2:] = 1.0
    with_edge = edge_aware_smoothness(step_depth, img_edge, eps=0.0)
    assert no_edge.item() == pytest.approx(4 / 12) and with_edge.item() < 1e-6


def test_sampler_shards_and_resumes():
    a = list(ResumableSampler(10, 0, 2, seed=1))
    b = list(ResumableSampler(10, 1, 2, seed=1))
    assert len(a) == len(b) == 5 and not set(a) & set(b)
    s = ResumableSampler(10, 0, 2, seed=1)
    s.set_epoch(0, 3)
    assert list(s) == a[3:]
    s.set_epoch(1)
    assert list(s) != a


def _params(model: torch.nn.Module) -> torch.Tensor:
    return torch.cat([p.detach().flatten() for p in model.state_dict().values() if p.dtype.is_floating_point])


@pytest.mark.numerics  # bit for bit: it must hold with torch's deterministic algorithms too
@pytest.mark.parametrize("net", ["aifnet", "dfvnet"])
def test_resume_equals_uninterrupted(tmp_path, net):
    from training.train.loop import load_trained, train

    cfg = train_config(net=net, loss=LossConfig(level_weights=(2.0, 1.0), aif=0.1, smooth=0.01))
    data = TwoPlaneStacks(n=6)  # 3 batches per epoch: the run crosses an epoch boundary
    full = train(cfg, tmp_path / "a", train_set=data, progress=False)
    assert full.finished and full.step == 6
    part = train(cfg, tmp_path / "b", train_set=data, stop_at_step=4, progress=False)
    assert not part.finished and part.step == 4 and not (tmp_path / "b" / "model.pt").exists()
    with pytest.raises(FileExistsError, match="--resume"):
        train(cfg, tmp_path / "b", train_set=data, progress=False)
    rest = train(cfg, tmp_path / "b", train_set=data, resume=True, progress=False)
    assert rest.finished and rest.step == 6
    ma, _ = load_trained(tmp_path / "a" / "model.pt")
    mb, cfg_b = load_trained(tmp_path / "b" / "model.pt")
    assert cfg_b == cfg
    assert torch.equal(_params(ma), _params(mb))  # the same steps on the same data in one process: bit for bit
    init = _params(__import__("training.nets.model", fromlist=["x"]).build_model(net, "small"))
    assert not torch.allclose(init, _params(ma))
    log = [json.loads(line) for line in (tmp_path / "a" / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3, 4, 5, 6] and log[-1]["lr"] < log[0]["lr"]


def test_training_learns_and_evaluates(tmp_path):
    from training.train.evaluate import evaluate
    from training.train.loop import load_trained, train

    train_set, val_set = TwoPlaneStacks(n=32, seed=0), TwoPlaneStacks(n=6, seed=1)
    cfg = train_config(net="dfvnet", steps=60, batch_size=4, lr=3e-3, checkpoint_every=60, log_every=10, val_items=6)
    torch.manual_seed(0)
    before, _ = evaluate(__import__("training.nets.model", fromlist=["x"]).build_model("dfvnet", "small"), val_set)
    res = train(cfg, tmp_path / "run", train_set=train_set, val_set=val_set, progress=False)
    after = res.val_metrics
    print(f"val MAE before {before['mae']:.3f} m, after {after['mae']:.3f} m; {res.seconds_per_step:.3f} s/step")
    assert after["mae"] < 0.7 * before["mae"]
    assert set(after) >= {"mae", "rmse", "abs_rel", "delta1", "psnr", "ssim", "n_images"}
    emap = np.load(tmp_path / "run" / "val_error_map_m.npy")
    assert emap.shape == (32, 32) and np.isnan(emap[0, 0]) and np.nanmean(emap) == pytest.approx(
        np.nanmean(emap), rel=1e-6)
    assert not [f.name for f in (tmp_path / "run").iterdir() if ".tmp-" in f.name]  # every output renamed into place
    model, _ = load_trained(tmp_path / "run" / "model.pt")
    again, _ = evaluate(model, val_set)
    assert again["mae"] == pytest.approx(after["mae"], rel=1e-5)



def test_validation_items_of_several_sizes_are_scored_without_an_error_map(tmp_path):
    """Renders no larger than each camera's sensor differ in size (configs/anycam/dfv_aat_v7.json): validation
    scores them all and skips only the per-pixel map, instead of stopping the run at its first validation."""
    from torch.utils.data import ConcatDataset

    from training.train.evaluate import evaluate
    from training.train.loop import train

    val_set = ConcatDataset([TwoPlaneStacks(n=2, size=32, seed=1), TwoPlaneStacks(n=2, size=24, seed=2)])
    cfg = train_config(net="dfvnet", steps=2, batch_size=2, checkpoint_every=2, log_every=1, val_items=4)
    res = train(cfg, tmp_path / "run", train_set=TwoPlaneStacks(n=4), val_set=val_set, progress=False)
    assert res.val_metrics["n_images"] == 4 and np.isfinite(res.val_metrics["mae"])
    assert not (tmp_path / "run" / "val_error_map_m.npy").exists()
    model = __import__("training.nets.model", fromlist=["x"]).build_model("dfvnet", "small")
    metrics, emap = evaluate(model, val_set)
    assert emap is None and metrics["n_images"] == 4
    assert evaluate(model, TwoPlaneStacks(n=2, size=24))[1].shape == (24, 24)

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ddp_worker(rank: int, world: int, port: int, out: str) -> None:
    """Train 3 steps in a 2-process gloo group (the env torchrun sets); save this replica's final state."""
    os.environ.update({"MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "RANK": str(rank),
                       "WORLD_SIZE": str(world), "LOCAL_RANK": str(rank)})
    torch.set_num_threads(1)
    from training.train import loop
    from training.train.checkpoint import load

    captured = {}
    real_build = loop.build_model

    def build_and_keep(net, size, field_channels=0):
        captured["model"] = real_build(net, size, field_channels)
        return captured["model"]

    loop.build_model = build_and_keep
    data = TwoPlaneStacks(n=8)
    cfg = train_config(net="dfvnet", steps=3, checkpoint_every=10, loss=LossConfig(level_weights=(2.0, 1.0)))
    res = loop.train(cfg, Path(out) / "run", train_set=data, progress=False)
    torch.save({"state": {k: v.clone() for k, v in captured["model"].state_dict().items()},
                "ckpt": load(Path(out) / "run" / "last.pt")["model"], "step": res.step,
                "items": list(ResumableSampler(len(data), rank, world, cfg.seed))},
               Path(out) / f"rank{rank}.pt")


def test_ddp_two_processes_keep_replicas_identical(tmp_path):
    import torch.multiprocessing as mp

    from training.nets.model import build_model

    mp.spawn(_ddp_worker, args=(2, _free_port(), str(tmp_path)), nprocs=2, join=True)
    r0 = torch.load(tmp_path / "rank0.pt", weights_only=False)
    r1 = torch.load(tmp_path / "rank1.pt", weights_only=False)
    assert r0["step"] == r1["step"] == 3
    assert not set(r0["items"]) & set(r1["items"])  # each replica saw different data ...
    for k in r0["state"]:
        assert torch.equal(r0["state"][k], r1["state"][k]), k  # ... yet parameters and buffers are identical
        assert torch.equal(r0["state"][k], r0["ckpt"][k]), k
    torch.manual_seed(0)
    init = build_model("dfvnet", "small").state_dict()
    assert any(not torch.equal(init[k], r0["state"][k]) for k in init)  # and it trained


def test_cli_trains_resumes_and_refuses(tmp_path, monkeypatch, capsys):
    import training.train.data as data_mod
    from training.cli.train import main

    monkeypatch.setattr(data_mod, "make_dataset", lambda data, simulator, lens, effects=None:
                        TwoPlaneStacks(n=data["n_items"], seed=data["seed"]))
    out = tmp_path / "run"
    args = ["--config", str(ROOT / "configs" / "dff_ci.json"), "--out", str(out), "--no-progress"]
    assert main(args + ["--steps", "2"]) == 0
    assert "finished at step 2/2" in capsys.readouterr().out
    assert (out / "model.pt").exists() and (out / "val_metrics.json").exists()
    assert main(args + ["--steps", "3"]) == 2  # an input error: no retry helps
    assert "--resume" in capsys.readouterr().err
    assert main(args + ["--steps", "3", "--resume"]) == 0
    assert "finished at step 3/3" in capsys.readouterr().out
    bad = tmp_path / "bad.json"
    bad.write_text('{"name": "x"}')
    assert main(["--config", str(bad)]) == 2
    assert "missing config keys" in capsys.readouterr().err


def test_make_dataset_fills_simulator_lens_and_rejects_unknown_keys(monkeypatch):
    """The adapter against a stand-in for training.data.stacks (the real module's interface)."""
    import dataclasses
    import sys
    import types

    from training.train.data import make_dataset

    @dataclasses.dataclass(frozen=True)
    class StackConfig:
        height: int = 32
        simulator: str = "aat"
        lens: str = ""
        effects: tuple = ()

    class FocalStackDataset:
        def __init__(self, cfg: StackConfig):
            self.cfg = cfg

    fake = types.ModuleType("training.data.stacks")
    fake.FocalStackDataset, fake.StackConfig = FocalStackDataset, StackConfig
    FocalStackDataset.__init__.__annotations__["cfg"] = StackConfig
    monkeypatch.setitem(sys.modules, "training.data.stacks", fake)
    import training.data

    monkeypatch.setattr(training.data, "stacks", fake, raising=False)
    ds = make_dataset({"height": 64}, "thin_lens", "lenses/canon_rf50mm_f1.8.json", ["noise"])
    assert ds.cfg.height == 64 and ds.cfg.simulator == "thin_lens" and ds.cfg.effects == ("noise",)
    assert Path(ds.cfg.lens).is_file()
    with pytest.raises(ValueError, match="n_items"):
        make_dataset({"n_items": 3}, "aat", "lenses/canon_rf50mm_f1.8.json")


def test_diopter_loss_is_l1_on_inverse_depth():
    """loss.depth_space 'diopter': mean |1/pred - 1/gt| over valid pixels (hand-computed)."""
    from training.train.loss import dff_loss

    pred = torch.tensor([[[1.0, 2.0], [4.0, 5.0]]])
    gt = torch.tensor([[[0.5, 2.0], [5.0, 0.0]]])  # last pixel invalid
    batch = {"depth_m": gt, "focus_m": torch.tensor([[0.5, 5.0]])}
    loss, _ = dff_loss([(pred, None, None)], batch, LossConfig(depth_space="diopter"))
    expect = (abs(1 / 1.0 - 1 / 0.5) + 0 + abs(1 / 4.0 - 1 / 5.0)) / 3
    assert abs(float(loss) - expect) < 1e-6
    loss_m, _ = dff_loss([(pred, None, None)], batch, LossConfig())
    assert abs(float(loss_m) - (0.5 + 0 + 1.0) / 3) < 1e-6


@pytest.mark.numerics
def test_any_camera_net_trains_resumes_exactly_validates_and_exports(tmp_path):
    """The dfvaat net through the project's loop: per-batch stack sizes (the dataset's collate), its own loss, exact
    resume, validation on whole items with their own frames, export with the focus-map metadata."""
    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.train.export import export_checkpoint
    from training.train.loop import load_trained, train

    common = dict(seed=4, height=32, width=32, margin_px=8, max_layers=16, cache_dir=str(tmp_path / "cache"))
    data = AnyCamDataset(AnyCamConfig(n_items=6, crop=0, **common))
    val = AnyCamDataset(AnyCamConfig(n_items=6, crop=0, fixed_subsets=True, **common))
    cfg = train_config(net="dfvaat", simulator="any_camera", lens="", val_every=0,
                       loss=LossConfig(level_weights=(2.0, 1.0), mask_focus_range=True))
    full = train(cfg, tmp_path / "a", train_set=data, val_set=val, progress=False)
    assert full.finished and full.step == 6 and 0 < full.val_metrics["mae"] < 100
    train(cfg, tmp_path / "b", train_set=data, val_set=val, stop_at_step=3, progress=False)
    rest = train(cfg, tmp_path / "b", train_set=data, val_set=val, resume=True, progress=False)
    assert rest.finished
    ma, _ = load_trained(tmp_path / "a" / "model.pt")
    mb, _ = load_trained(tmp_path / "b" / "model.pt")
    assert torch.equal(_params(ma), _params(mb))
    log = [json.loads(line) for line in (tmp_path / "a" / "log.jsonl").read_text().splitlines() if "frames_l1" in line]
    assert len(log) == 6 and all(math.isfinite(r["frames_l1"]) for r in log)
    md, err = export_checkpoint(tmp_path / "a" / "model.pt", tmp_path / "m.onnx")
    assert md["aat.inputs"] == "focus_map" and md["aat.net"] == "dfvaat" and err < 1e-3
    assert md["aat.checkpoint_step"] == "6" and md["aat.train_steps"] == "6"


@pytest.mark.numerics
def test_an_any_camera_run_resumes_on_renders_made_before_the_sources_record(tmp_path):
    """`scripts/train_dfv_aat.sh dfv_aat_v6` on a new machine with today's code (the script itself, in a copy of
    the checkout's layout): the sixth run's config (shrunk) on renders without sources.json (the v4-v6 data were made
    before it) resumes from its committed checkpoint, says once per folder that they cannot be checked, records them
    as unverified in the run and writes nothing into the cache."""
    import shutil
    import subprocess
    import sys

    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.data.cache import SOURCES
    from training.train.config import load_config
    from training.train.loop import train

    v6 = json.loads((ROOT / "configs" / "anycam" / "dfv_aat_v6.json").read_text())
    tiny = dict(n_items=4, height=32, width=32, margin_px=8, max_layers=16, cache_dir=str(tmp_path / "cache"))
    folders = []
    for split in ("data", "val_data"):
        ds = AnyCamDataset(AnyCamConfig(**{**v6[split], **tiny, "only_cached": False}))
        for i in range(4):
            ds.load_or_render(i)
        (ds.cache / SOURCES).unlink()  # as the code that rendered the v4-v6 data left its folders
        folders.append(ds.cache)
    listing = {f: f.stat().st_mtime_ns for d in folders for f in d.rglob("*")}
    box = tmp_path / "checkout"  # the script runs configs/anycam/NAME.json and checkpoints/NAME/ of its checkout
    (box / "scripts").mkdir(parents=True)
    shutil.copy(ROOT / "scripts" / "train_dfv_aat.sh", box / "scripts")
    cfg_path = box / "configs" / "anycam" / "dfv_aat_v6.json"
    cfg_path.parent.mkdir(parents=True)
    cfg_path.write_text(json.dumps({**v6, "data": {**v6["data"], **tiny}, "val_data": {**v6["val_data"], **tiny},
                                    "steps": 4, "batch_size": 2, "warmup_steps": 1, "checkpoint_every": 2,
                                    "val_every": 0, "val_items": 4, "log_every": 1}))
    train(load_config(cfg_path), box / "checkpoints" / "dfv_aat_v6", stop_at_step=2, progress=False)  # committed
    env = {**os.environ, "OUT": "cache/runs", "RETRIES": "1", "PYTHONPATH": str(ROOT),
           "PATH": f"{Path(sys.executable).parent}:{os.environ.get('PATH', '')}"}
    done = subprocess.run(["bash", str(box / "scripts" / "train_dfv_aat.sh"), "dfv_aat_v6"], env=env,
                          capture_output=True, text=True, timeout=600)
    log = (box / "cache" / "runs" / "dfv_aat_v6.log").read_text()
    assert done.returncode == 0, done.stderr + log
    assert "resumed from checkpoints/dfv_aat_v6" in done.stdout and "finished at step 4/4" in log
    summary = json.loads((box / "cache" / "runs" / "dfv_aat_v6" / "train_summary.json").read_text())
    assert summary["steps"] == 4 and [s["from_step"] for s in summary["sessions"]] == [0, 2]
    assert all(s["data_sources"] == {"train": "unverified", "val": "unverified"} for s in summary["sessions"])
    warned = [line for line in log.splitlines() if "cannot check" in line]
    assert sorted(w.split(": made before")[0].removeprefix("warning: ") for w in warned) == sorted(map(str, folders))
    assert {f: f.stat().st_mtime_ns for d in folders for f in d.rglob("*")} == listing  # nothing written there


def test_the_any_camera_script_stops_at_once_when_its_inputs_are_refused(tmp_path):
    """A refusal (here: the renders' sources.json unreadable, as for a changed lens/PSF file) exits 2 with the
    one-line reason, after one attempt: the script's crash retries (60 s apart) are for kills, not for inputs."""
    import shutil
    import subprocess
    import sys
    import time

    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.data.cache import SOURCES

    v6 = json.loads((ROOT / "configs" / "anycam" / "dfv_aat_v6.json").read_text())
    tiny = dict(n_items=4, height=32, width=32, margin_px=8, max_layers=16, cache_dir=str(tmp_path / "cache"))
    cache = AnyCamDataset(AnyCamConfig(**{**v6["data"], **tiny, "only_cached": False})).cache
    cache.mkdir(parents=True, exist_ok=True)
    (cache / SOURCES).write_text("{")
    box = tmp_path / "checkout"
    (box / "scripts").mkdir(parents=True)
    shutil.copy(ROOT / "scripts" / "train_dfv_aat.sh", box / "scripts")
    cfg = box / "configs" / "anycam" / "dfv_aat_v6.json"
    cfg.parent.mkdir(parents=True)
    cfg.write_text(json.dumps({**v6, "data": {**v6["data"], **tiny}, "val_data": {**v6["val_data"], **tiny},
                               "steps": 2, "batch_size": 2, "val_every": 0}))
    env = {**os.environ, "OUT": "cache/runs", "RETRIES": "20", "PYTHONPATH": str(ROOT),
           "PATH": f"{Path(sys.executable).parent}:{os.environ.get('PATH', '')}"}
    t0 = time.monotonic()
    done = subprocess.run(["bash", str(box / "scripts" / "train_dfv_aat.sh"), "dfv_aat_v6"], env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert time.monotonic() - t0 < 60  # no retry slept
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("dfv_aat_v6: refused: aat-train: ") and str(cache / SOURCES) in last
    assert "attempt" not in (box / "cache" / "runs" / "dfv_aat_v6.log").read_text()
    assert (cache / SOURCES).read_text() == "{"  # the input untouched


@pytest.mark.numerics
def test_the_best_validation_weights_are_kept(tmp_path):
    """best.pt holds the weights of the step whose validation MAE is the lowest logged (model.pt's format), across a
    resume; best.json names that step."""
    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.train.loop import load_trained, train

    common = dict(seed=4, height=32, width=32, margin_px=8, max_layers=16, cache_dir=str(tmp_path / "cache"))
    data = AnyCamDataset(AnyCamConfig(n_items=6, crop=0, **common))
    val = AnyCamDataset(AnyCamConfig(n_items=4, crop=0, fixed_subsets=True, **common))
    cfg = train_config(net="dfvaat", simulator="any_camera", lens="", val_every=1, val_items=4, lr=3e-3,
                       loss=LossConfig(level_weights=(2.0, 1.0), mask_focus_range=True))
    train(cfg, tmp_path / "r", train_set=data, val_set=val, stop_at_step=3, progress=False)
    train(cfg, tmp_path / "r", train_set=data, val_set=val, resume=True, progress=False)
    rows = [json.loads(line) for line in (tmp_path / "r" / "log.jsonl").read_text().splitlines()]
    maes = {r["step"]: r["val"]["mae"] for r in rows if "val" in r}
    assert len(maes) == 6 and len(set(maes.values())) > 1  # the weights changed between validations
    best = json.loads((tmp_path / "r" / "best.json").read_text())
    assert best["mae"] == min(maes.values()) and maes[best["step"]] == best["mae"]
    model, _ = load_trained(tmp_path / "r" / "best.pt")
    last, _ = load_trained(tmp_path / "r" / "model.pt")
    assert torch.equal(_params(model), _params(last)) is (best["step"] == 6)
    from training.train.export import export_checkpoint

    md, err = export_checkpoint(tmp_path / "r" / "best.pt", tmp_path / "best.onnx")  # exported as model.pt is
    assert md["aat.net"] == "dfvaat" and err < 1e-3
    assert md["aat.checkpoint_step"] == str(best["step"])  # the weights' own step, not the schedule's 6


def test_focus_map_loss_weighs_pixels_beyond_their_frames_by_out_of_range_weight():
    """loss.out_of_range_weight: 1 scores every valid pixel alike (the first runs' loss, bit for bit as before), 0
    only the pixels whose true diopters their frames reach, 0.5 halves the others' weight; hand-computed."""
    from training.train.loss import focus_map_loss

    fd = torch.tensor([2.0, 1.5, 1.0])[None, :, None, None].expand(1, 3, 1, 3).clone()  # spacing 0.5 D
    gt = torch.tensor([[[0.5, 1.0, 0.25]]])  # 2 D, 1 D inside; 4 D beyond the nearest frame (2 D)
    pred_d = torch.tensor([[[1.5, 1.5, 2.0]]])  # errors 1, 1, 4 frame spacings
    levels = [(1 / pred_d, None, None, pred_d)]
    batch = {"depth_m": gt, "focus_diopters": fd}

    def loss(w):
        return float(focus_map_loss(levels, batch, LossConfig(out_of_range_weight=w))[0])

    assert loss(1.0) == pytest.approx((1 + 1 + 4) / 3)
    assert loss(1.0) == float(masked_l1(pred_d / 0.5, 1 / gt / 0.5, depth_mask(gt)))
    assert loss(0.0) == pytest.approx(1.0)
    assert loss(0.5) == pytest.approx((1 + 1 + 0.5 * 4) / 2.5)
    d = json.loads((ROOT / "configs/anycam/dfv_aat_v5.json").read_text())
    assert config_from_dict(d).hash() == config_from_dict({**d, "loss": {**d["loss"], "out_of_range_weight": 1.0}}).hash()
    with pytest.raises(ConfigError, match="out_of_range_weight"):
        config_from_dict({**d, "loss": {**d["loss"], "out_of_range_weight": 2.0}})


def test_a_head_only_run_leaves_the_body_exactly_as_it_started_and_trains_the_head(tmp_path):
    """train_only "extrap.": a bounded extrapolating head on a trained body. The body's weights and its batch
    norms' running statistics stay bit-identical through training and validation (its batch norms run in eval
    mode); the head moves; a resume ends where the uninterrupted run does, and one with another train_only is
    refused; a prefix nothing has is refused."""
    import dataclasses

    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.nets.dfvaat import build
    from training.train.loop import load_trained, train

    common = dict(seed=4, height=32, width=32, margin_px=8, max_layers=16, cache_dir=str(tmp_path / "cache"))
    data = AnyCamDataset(AnyCamConfig(n_items=6, crop=0, **common))
    val = AnyCamDataset(AnyCamConfig(n_items=2, crop=0, fixed_subsets=True, **common))
    torch.manual_seed(5)
    base = build("small_replicate")
    for m in base.modules():  # running statistics a training would have left (not the defaults)
        if isinstance(m, torch.nn.BatchNorm2d | torch.nn.BatchNorm3d):
            m.running_mean.uniform_(-0.1, 0.1)
            m.running_var.uniform_(0.5, 1.5)
    ck = tmp_path / "base.pt"
    torch.save({"model": base.state_dict(), "config": {"net": "dfvaat", "size": "small_replicate"}, "step": 5}, ck)
    cfg = train_config(net="dfvaat", simulator="any_camera", lens="", size="small_replicate_xb", init=str(ck),
                       train_only="extrap.", val_every=2, val_items=2, lr=3e-2,
                       loss=LossConfig(level_weights=(2.0, 1.0), mask_focus_range=True))
    assert cfg.hash() != train_config(net="dfvaat", simulator="any_camera", lens="", size="small_replicate_xb",
                                      init=str(ck), val_every=2, val_items=2, lr=3e-2,
                                      loss=LossConfig(level_weights=(2.0, 1.0), mask_focus_range=True)).hash()
    full = train(cfg, tmp_path / "a", train_set=data, val_set=val, progress=False)
    assert full.finished
    trained, _ = load_trained(tmp_path / "a" / "model.pt")
    after, before = trained.state_dict(), base.state_dict()
    assert all(torch.equal(after[k], before[k]) for k in before)  # weights and buffers of the body
    fresh = build("small_replicate_xb").state_dict()
    assert any(not torch.equal(after[k], fresh[k]) for k in after if k.startswith("extrap."))
    train(cfg, tmp_path / "b", train_set=data, val_set=val, stop_at_step=3, progress=False)
    train(cfg, tmp_path / "b", train_set=data, val_set=val, resume=True, progress=False)
    resumed, _ = load_trained(tmp_path / "b" / "model.pt")
    assert torch.equal(_params(trained), _params(resumed))
    with pytest.raises(ValueError, match="checkpoint has train_only='extrap.', config has ''"):
        train(dataclasses.replace(cfg, train_only=""), tmp_path / "b", train_set=data, val_set=val, resume=True,
              progress=False)  # the optimizer state holds the head's tensors only
    bad = train_config(net="dfvaat", simulator="any_camera", lens="", size="small_replicate_xb", init=str(ck),
                       train_only="nothing.", loss=LossConfig(level_weights=(2.0, 1.0)))
    with pytest.raises(ValueError, match="train_only 'nothing.': no parameter"):
        train(bad, tmp_path / "c", train_set=data, val_set=val, progress=False)


def test_configs_made_before_train_only_hash_as_their_shipped_models_record():
    """The hash names a trained model (its ONNX metadata's aat.config_hash): adding `train_only` must not change it
    for a config without it, or every shipped model's provenance check would fail."""
    import dataclasses

    import onnxruntime as ort

    for cfg_name, model_name in (("dfv_aat_v10", "dfv_aat_v10_s23200"), ("dfv_aat_v13", "dfv_aat_v13_s22600")):
        cfg = config_from_dict(json.loads((ROOT / "configs" / "anycam" / f"{cfg_name}.json").read_text()))
        sess = ort.InferenceSession(str(ROOT / "models" / "reproduce" / f"{model_name}.onnx"),
                                    providers=["CPUExecutionProvider"])
        assert cfg.hash() == sess.get_modelmeta().custom_metadata_map["aat.config_hash"], cfg_name
        assert dataclasses.replace(cfg, train_only="").hash() == cfg.hash()
        assert dataclasses.replace(cfg, train_only="extrap.").hash() != cfg.hash()
