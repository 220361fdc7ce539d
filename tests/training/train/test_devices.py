"""Training where users train (issue 38), checked on the CPU: device selection, the distributed backend, mixed
precision, checkpoints that load on any device, and torchrun data parallelism whose result equals one process
with the same effective batch, including a DDP checkpoint resumed by one process. What needs a GPU (NCCL, speed)
is in benchmarks/bench_devices.py, not run here."""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

import pytest
import torch
from training_fixtures import TwoPlaneStacks, train_config

from training.devices.distributed import backend_for
from training.devices.precision import amp_dtype
from training.devices.select import DeviceError, resolve_device
from training.train.config import LossConfig

ROOT = Path(__file__).resolve().parents[3]


def test_device_selection(monkeypatch):
    assert resolve_device("cpu") == torch.device("cpu")
    for bad in ("gpu", "cuda:x", "cuda:-1", ""):
        if bad:
            with pytest.raises(DeviceError, match="expected auto, cpu, cuda, cuda:N or mps"):
                resolve_device(bad)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr("training.devices.select._mps_available", lambda: False)
    assert resolve_device("auto") == resolve_device(None) == torch.device("cpu")
    with pytest.raises(DeviceError, match="no CUDA device here"):
        resolve_device("cuda")
    with pytest.raises(DeviceError, match="no MPS device"):
        resolve_device("mps")
    monkeypatch.setattr("training.devices.select._mps_available", lambda: True)
    assert resolve_device("auto") == torch.device("mps")  # a GPU when there is one
    # two CUDA GPUs (faked): auto prefers CUDA; under torchrun each process takes its LOCAL_RANK's GPU
    chosen = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    monkeypatch.setattr(torch.cuda, "set_device", chosen.append)
    assert resolve_device("auto") == torch.device("cuda", 0)
    assert resolve_device("cuda:1") == torch.device("cuda", 1)
    with pytest.raises(DeviceError, match="only 2 CUDA devices"):
        resolve_device("cuda:2")
    monkeypatch.setenv("LOCAL_RANK", "1")
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "2")
    assert resolve_device("cuda") == torch.device("cuda", 1)
    with pytest.raises(DeviceError, match="LOCAL_RANK"):
        resolve_device("cuda:0")
    assert chosen == [0, 1, 1]
    assert backend_for(torch.device("cuda", 1)) == "nccl"
    assert backend_for(torch.device("cpu")) == backend_for(torch.device("mps")) == "gloo"


def test_amp_choice(monkeypatch):
    cpu = torch.device("cpu")
    assert amp_dtype(None, cpu) is None and amp_dtype("off", cpu) is None
    assert amp_dtype("auto", cpu) == amp_dtype("bf16", cpu) == torch.bfloat16
    assert amp_dtype("fp16", cpu) == torch.float16
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda: False)
    assert amp_dtype("auto", torch.device("cuda", 0)) == torch.float16  # e.g. a V100: fp16 with loss scaling
    with pytest.raises(ValueError, match="--amp 'fp8'"):
        amp_dtype("fp8", cpu)


def test_cli_refuses_a_missing_gpu_in_one_line(monkeypatch, capsys):
    from training.cli.train import main

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert main(["--config", str(ROOT / "configs" / "dff_ci.json"), "--device", "cuda", "--out", "/nonexistent"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("aat-train: error: --device cuda: no CUDA device here") and "\n" not in err


def test_psf_fit_refuses_a_missing_gpu_before_tracing(monkeypatch, capsys):
    from training.cli.psf import main

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr("training.psf.experiment.PSFExperiment.load", lambda path: pytest.fail("traced first"))
    assert main(["fit", "--config", str(ROOT / "configs" / "psf_ci.json"), "--device", "cuda"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("aat-psf: error: --device cuda: no CUDA device here") and "\n" not in err


def test_checkpoint_loads_onto_the_requested_device(tmp_path):
    """map_location: tensors land where asked (the meta device stands in for a GPU here), whatever wrote them."""
    from training.train.checkpoint import load, save_atomic, to_cpu

    state = {"model": {"w": torch.ones(3)}, "optimizer": {"state": {0: {"exp_avg": torch.zeros(2)}}}, "step": 4}
    save_atomic(to_cpu(state), tmp_path / "last.pt")
    on_meta = load(tmp_path / "last.pt", map_location="meta")
    assert on_meta["model"]["w"].device.type == "meta" and on_meta["step"] == 4
    assert on_meta["optimizer"]["state"][0]["exp_avg"].device.type == "meta"
    assert load(tmp_path / "last.pt")["model"]["w"].device.type == "cpu"


@pytest.mark.parametrize("net", ["dfvnet", "aifnet"])
def test_amp_bf16_loss_curve_follows_float32(tmp_path, net):
    """--amp bf16 on the CPU: the same 12 steps as float32. Tolerances: the first step (same weights, same batch,
    only the nets' precision differs) within 3 %; the mean loss over each third of the run within 15 %
    (bfloat16 keeps 8 mantissa bits, and the runs drift apart step by step). 64 px crops: torch 2.13's CPU
    bfloat16 backward of the small AiFNet aborts at 32 px (1 px at its deepest level)."""
    from training.train.loop import train

    data = TwoPlaneStacks(n=16, size=64)
    curves = {}
    for amp in ("off", "bf16"):
        cfg = train_config(net=net, steps=12, checkpoint_every=100, loss=LossConfig(level_weights=(2.0, 1.0)))
        res = train(cfg, tmp_path / amp, train_set=data, progress=False, device="cpu", amp=amp)
        assert res.finished
        curves[amp] = [json.loads(r)["total"] for r in (tmp_path / amp / "log.jsonl").read_text().splitlines()]
        summary = json.loads((tmp_path / amp / "train_summary.json").read_text())
        assert summary["sessions"] == [{"from_step": 0, "device": "cpu", "amp": amp, "processes": 1,
                                        "sync_bn": False, "data_sources": {}}]  # in-memory data: no cache
    f32, bf16 = curves["off"], curves["bf16"]
    assert f32 != bf16  # autocast really ran in bfloat16
    assert abs(bf16[0] - f32[0]) < 0.03 * f32[0]
    for k in range(3):
        a, b = sum(f32[4 * k:4 * k + 4]) / 4, sum(bf16[4 * k:4 * k + 4]) / 4
        assert abs(a - b) < 0.15 * a, (k, a, b)


# -- torchrun data parallelism (2 gloo processes, as torchrun would start them) ---------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _without_batchnorm(build):
    """build_model, with batch norm replaced by identities: the one layer whose training-mode output depends on how
    the batch is split across processes (torch synchronises it on GPUs only, SyncBatchNorm)."""
    def build_model(net, size, field_channels=0):
        model = build(net, size, field_channels)
        for name, mod in list(model.named_modules()):
            for child_name, child in list(mod.named_children()):
                if isinstance(child, torch.nn.modules.batchnorm._BatchNorm):
                    setattr(mod, child_name, torch.nn.Identity())
        return model
    return build_model


def _cfg(batch: int, steps: int):
    return train_config(net="dfvnet", steps=steps, batch_size=batch, checkpoint_every=3, log_every=1,
                        loss=LossConfig(level_weights=(2.0, 1.0), aif=0.1))


def _assert_same_model(a: dict, b: dict, data) -> None:
    """Same predictions (depth within 1e-4 relative on two items) and parameters within a quarter of one Adam
    step (lr 2e-3). Left out of the parameter check: the classifiers' output biases (`classify.1.bias`), one
    number added to every frame's score before the softmax over frames, so their true gradient is zero and Adam
    moves them by lr-sized steps on rounding noise, which differs between CPUs (by 5.6e-4 on one, past the
    tolerance). That they cannot change a prediction is checked here, not assumed."""
    from training.nets.model import build_model, predict

    batch = [data[i] for i in (0, 1)]
    stack, focus = torch.stack([x["stack"] for x in batch]), torch.stack([x["focus_m"] for x in batch])

    def depth(state):
        model = _without_batchnorm(build_model)("dfvnet", "small")
        model.load_state_dict(state)
        model.eval()
        return predict(model, stack, focus)["depth_m"]

    torch.testing.assert_close(depth(a), depth(b), rtol=1e-4, atol=0)
    shift_only = [k for k in b if k.endswith("classify.1.bias")]
    assert len(shift_only) == 2
    shifted = {k: v + 0.5 if k in shift_only else v for k, v in b.items()}
    torch.testing.assert_close(depth(shifted), depth(b), rtol=1e-5, atol=0)  # no effect: nothing to compare
    for k in b:
        if k not in shift_only:
            torch.testing.assert_close(a[k], b[k], rtol=0, atol=5e-4, msg=k)


def _ddp_worker(rank: int, world: int, port: int, out: str) -> None:
    os.environ.update({"MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "RANK": str(rank),
                       "WORLD_SIZE": str(world), "LOCAL_RANK": str(rank), "LOCAL_WORLD_SIZE": str(world)})
    torch.set_num_threads(1)
    from training.train import loop

    loop.build_model = _without_batchnorm(loop.build_model)
    loop.train(_cfg(batch=1, steps=5), Path(out), train_set=TwoPlaneStacks(n=8), stop_at_step=3, progress=False,
               device="auto")


def test_ddp_equals_one_process_with_the_same_effective_batch_and_resumes_single(tmp_path, monkeypatch):
    """2 processes x batch 1 for 3 steps (gloo, chosen automatically on CPUs), then resumed by one process with
    batch 2 to step 5, against one process x batch 2 for 5 steps: the same items in the same global batches, the
    gradients averaged, so the weights agree to float32 rounding (the summation order differs)."""
    import torch.multiprocessing as mp

    from training.train import loop
    from training.train.checkpoint import load

    ddp_dir = tmp_path / "ddp"
    mp.spawn(_ddp_worker, args=(2, _free_port(), str(ddp_dir)), nprocs=2, join=True)
    at3 = load(ddp_dir / "last.pt")
    assert at3["step"] == 3 and at3["stacks_seen"] == 6 and not (ddp_dir / "model.pt").exists()
    assert at3["sessions"] == [{"from_step": 0, "device": "cpu", "amp": "off", "processes": 2, "sync_bn": False,
                                "data_sources": {}}]
    assert not list(ddp_dir.glob("*.tmp*"))  # one writer (rank 0), nothing half-written

    monkeypatch.setattr(loop, "build_model", _without_batchnorm(loop.build_model))
    data = TwoPlaneStacks(n=8)
    one = loop.train(_cfg(batch=2, steps=5), tmp_path / "one", train_set=data, stop_at_step=3, progress=False,
                     device="cpu")
    assert one.step == 3
    _assert_same_model(at3["model"], load(tmp_path / "one" / "last.pt")["model"], data)
    loop.train(_cfg(batch=2, steps=5), tmp_path / "one", train_set=data, resume=True, progress=False, device="cpu")
    res = loop.train(_cfg(batch=2, steps=5), ddp_dir, train_set=data, resume=True, progress=False, device="cpu")
    assert res.finished and res.step == 5
    summary = json.loads((ddp_dir / "train_summary.json").read_text())
    assert summary["stacks_seen"] == 10 and [s["processes"] for s in summary["sessions"]] == [2, 1]
    b = load(tmp_path / "one" / "model.pt")["model"]
    _assert_same_model(load(ddp_dir / "model.pt")["model"], b, data)
    from training.nets.model import build_model

    torch.manual_seed(0)
    fresh = _without_batchnorm(build_model)("dfvnet", "small").state_dict()
    assert any(not torch.equal(fresh[k], b[k]) for k in fresh)  # and it trained
    steps = [json.loads(r)["step"] for r in (ddp_dir / "log.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 3, 4, 5]  # rank 0 alone logged, once per step


def _head_cfg(batch: int, init: str):
    return train_config(net="dfvnet", steps=3, batch_size=batch, checkpoint_every=3, log_every=1, init=init,
                        train_only="net.decoders.", loss=LossConfig(level_weights=(2.0, 1.0), aif=0.1))


def _ddp_head_worker(rank: int, world: int, port: int, out: str, init: str) -> None:
    os.environ.update({"MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "RANK": str(rank),
                       "WORLD_SIZE": str(world), "LOCAL_RANK": str(rank), "LOCAL_WORLD_SIZE": str(world)})
    torch.set_num_threads(1)
    from training.train import loop

    loop.build_model = _without_batchnorm(loop.build_model)
    loop.train(_head_cfg(1, init), Path(out), train_set=TwoPlaneStacks(n=8), progress=False, device="auto")


def test_ddp_with_train_only_trains_the_head_alone_and_equals_one_process(tmp_path, monkeypatch):
    """train_only under 2 gloo processes: DDP wraps a model whose body does not train (those tensors get no
    gradient, so DDP must leave them out of its all-reduce rather than wait for them). The body ends bit-identical
    to the checkpoint it started from, the head moves, and the result equals one process with batch 2."""
    import torch.multiprocessing as mp

    from training.nets.model import build_model
    from training.train import loop
    from training.train.checkpoint import load

    torch.manual_seed(3)
    base = _without_batchnorm(build_model)("dfvnet", "small").state_dict()
    ck = tmp_path / "base.pt"
    torch.save({"model": base, "config": {"net": "dfvnet", "size": "small"}, "step": 7}, ck)
    mp.spawn(_ddp_head_worker, args=(2, _free_port(), str(tmp_path / "ddp"), str(ck)), nprocs=2, join=True)
    two = load(tmp_path / "ddp" / "model.pt")["model"]
    summary = json.loads((tmp_path / "ddp" / "train_summary.json").read_text())
    assert [x["processes"] for x in summary["sessions"]] == [2]
    body = [k for k in base if not k.startswith("net.decoders.")]
    assert body and all(torch.equal(two[k], base[k]) for k in body)
    assert any(not torch.equal(two[k], base[k]) for k in base if k.startswith("net.decoders."))
    monkeypatch.setattr(loop, "build_model", _without_batchnorm(loop.build_model))
    data = TwoPlaneStacks(n=8)
    loop.train(_head_cfg(2, str(ck)), tmp_path / "one", train_set=data, progress=False, device="cpu")
    _assert_same_model(two, load(tmp_path / "one" / "model.pt")["model"], data)


def test_torchrun_restarts_after_a_lost_process_and_resumes(tmp_path):
    """torchrun --max-restarts=3 with 2 gloo processes: rank 1 dies before step 4 (after the step-2 checkpoint);
    torchrun restarts both, they resume from last.pt and end where an uninterrupted 2-process run ends, bit for
    bit (the same steps on the same data). Three restarts, not one: a restarted group's gloo connection can fail
    once on a stale address from the dead attempt (seen here about once in five runs; pytorch/pytorch#167288
    reports the same with NCCL), and the next restart then succeeds."""
    import subprocess
    import sys

    from training.train.checkpoint import load

    worker = Path(__file__).with_name("elastic_worker.py")
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", OMP_WAIT_POLICY="PASSIVE")
    for name, extra in (("whole", []), ("lost", ["die"])):
        p = subprocess.Popen([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
                              "--max-restarts=3", str(worker), str(tmp_path / name), *extra],
                             env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            _, err = p.communicate(timeout=300)
        except subprocess.TimeoutExpired:  # a hung run: torchrun stops its workers on SIGTERM (and they die with it)
            p.terminate()
            try:
                _, err = p.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()
                _, err = p.communicate()
        (tmp_path / f"{name}.log").write_text(err)
        assert p.returncode == 0, (name, str(tmp_path / f"{name}.log"))
    whole, lost = load(tmp_path / "whole" / "model.pt"), load(tmp_path / "lost" / "model.pt")
    assert whole["step"] == lost["step"] == 5
    for k in whole["model"]:
        assert torch.equal(whole["model"][k], lost["model"][k]), k
    sessions = json.loads((tmp_path / "lost" / "train_summary.json").read_text())["sessions"]
    assert [s["from_step"] for s in sessions] == [0, 2]  # the second attempt resumed at the last checkpoint


def test_psf_sources_answer_on_the_cpu_inside_a_device_context():
    """The simulator renders on a GPU under `with device:`; the PSF sources it calls must still compute on the CPU
    (their generators and numpy exchanges are CPU-bound). The meta device stands in for the GPU: inside its
    context the ray tracer and the thin-lens source give the same CPU kernels as outside."""
    import numpy as np

    from aat_deploy.lens.io import load_lens
    from training.render.sources import RayTracedPSF, thin_lens_source

    lens = load_lens(ROOT / "lenses" / "canon_rf50mm_f1.8.json")
    x, y, d, f = np.array([0.0, 0.5]), np.array([0.0, -0.3]), np.array([1.0, 3.0]), np.array([2.0, 2.0])
    for src in (RayTracedPSF(lens, n_rays=64), thin_lens_source(lens)):
        k_out, s_out = src(x, y, d, f)
        with torch.device("meta"):
            k_in, s_in = src(x, y, d, f)
        assert k_in.device.type == "cpu" and torch.equal(k_in, k_out) and torch.equal(s_in, s_out)
