"""One training loop for AiFNet and DFVNet and both simulators (the dataset's `simulator` field is the only
difference between aberration-aware and thin-lens runs).

Adam, cosine learning rate over the configured number of optimizer steps, gradient clipping, optional start from
trained weights (`init`: an exported .onnx or a checkpoint, training.nets.warm_start), checkpoints every
`checkpoint_every` steps (atomic; `best.pt` also keeps the weights of the best validation MAE) and resume from
`last.pt`: the sampler order depends only on (seed, epoch) and
an epoch can start part-way, so kill + rerun with resume continues exactly where it stopped.

Devices (`device`: auto | cpu | cuda[:N] | mps, training.devices.select): the net, the optimizer state and every
batch live on the run's device; the data is made on the CPU by the dataset (loader workers) and copied over
(pinned memory on CUDA). Checkpoints hold CPU tensors and load on any device, so a run may resume on other
hardware. Mixed precision (`amp`: bf16 | fp16 | auto, training.devices.precision) autocasts the nets only.

Distributed data parallel: under `torchrun --nproc_per_node=N` (env WORLD_SIZE > 1) the process group is
initialised here, NCCL on GPUs and gloo on CPUs (training.devices.distributed); each process reads its own shard
(ResumableSampler), gradients are averaged, so the effective batch is batch_size x processes; on GPUs batch norm
is synchronised across processes (SyncBatchNorm, which torch has for GPUs only), on CPUs its running statistics
are broadcast from rank 0 at each checkpoint. Only rank 0 logs, validates and writes files.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from aat_deploy.io.atomic import atomic_file, write_text_atomic
from training.devices.distributed import barrier, broadcast_buffers, init_distributed
from training.devices.precision import amp_dtype, amp_name, autocast, grad_scaler
from training.devices.select import pin_memory, resolve_device, to_device
from training.nets import registry
from training.nets.dfvaat import train_levels as focus_map_levels
from training.nets.model import build_model, train_levels
from training.train.checkpoint import load, save_atomic, to_cpu
from training.train.config import TrainConfig
from training.train.evaluate import evaluate
from training.train.loss import dff_loss, focus_map_loss
from training.train.sampler import ResumableSampler
from training.train.schedule import lr_at


@dataclass
class TrainResult:
    step: int
    finished: bool
    last_loss: float | None
    seconds_per_step: float | None
    val_metrics: dict = field(default_factory=dict)


def _log(out_dir: Path, row: dict) -> None:
    with open(out_dir / "log.jsonl", "a") as f:
        f.write(json.dumps(row) + "\n")


def _make_sets(cfg: TrainConfig, train_set: Dataset | None, val_set: Dataset | None):
    if train_set is None or (val_set is None and cfg.val_data):
        from training.train.data import make_dataset

        if train_set is None:
            train_set = make_dataset(cfg.data, cfg.simulator, cfg.lens, cfg.effects)
        if val_set is None and cfg.val_data:
            val_set = make_dataset(cfg.val_data, cfg.simulator, cfg.lens, cfg.effects)
    return train_set, val_set


def _data_sources(train_set, val_set) -> dict:
    """How each cached split stands against the lens/PSF files it is rendered from (`check_sources` of
    training.data.cache: "verified", "recorded" or "unverified"; a changed file raises): kept in each session's
    record, so a run on renders made before the record says so."""
    out = {}
    for name, ds in (("train", train_set), ("val", val_set)):
        check = getattr(ds, "check_sources", None)
        if callable(check) and getattr(ds, "cache", None) is not None:
            out[name] = check()
    return out


def freeze_all_but(model: torch.nn.Module, prefix: str) -> int:
    """Only the parameters whose names start with `prefix` train (e.g. "extrap.": a new head on a trained body);
    returns how many tensors train. The frozen part is held in eval mode by `train_mode`."""
    n = 0
    for name, p in model.named_parameters():
        p.requires_grad_(name.startswith(prefix))
        n += int(p.requires_grad)
    if n == 0:
        raise ValueError(f"train_only {prefix!r}: no parameter of the {type(model).__name__} starts with it")
    return n


def train_mode(model: torch.nn.Module, train_only: str = "") -> None:
    """model.train(), except that with `train_only` every module none of whose parameters trains stays in eval
    mode: a frozen body's batch norms keep their running statistics and use them, so the body computes exactly what
    it did before the run."""
    model.train()
    if train_only:
        for m in model.modules():
            ps = list(m.parameters())
            if ps and not any(p.requires_grad for p in ps):
                m.eval()


def _validate_and_log(model, val_set, cfg: TrainConfig, out_dir: Path, step: int, final: bool) -> dict:
    metrics, err_map = evaluate(model, val_set, cfg.val_items, cfg.loss.mask_focus_range)
    _log(out_dir, {"step": step, "val": metrics})
    _keep_best(model, cfg, out_dir, step, metrics)
    if final:
        write_text_atomic(out_dir / "val_metrics.json", json.dumps(metrics, indent=1))
        if err_map is not None:  # None: validation items of several sizes
            with atomic_file(out_dir / "val_error_map_m.npy") as tmp:
                np.save(tmp, err_map.astype(np.float32))
    return metrics


def _keep_best(model, cfg: TrainConfig, out_dir: Path, step: int, metrics: dict) -> None:
    """best.pt: the weights of the lowest validation MAE so far (model.pt's format: load_trained and the export read
    it) and best.json its step and metrics. A run's validation items are fixed, so its steps compare; a fine-tune
    whose validation peaks early (the any-camera third run: best at step 500 of 9,000) keeps that net."""
    mae = metrics.get("mae")
    f = out_dir / "best.json"
    if mae is None or not np.isfinite(mae) or (f.is_file() and json.loads(f.read_text())["mae"] <= mae):
        return
    save_atomic({"model": to_cpu(model.state_dict()), "config": cfg.to_dict(), "config_hash": cfg.hash(),
                 "step": step}, out_dir / "best.pt")
    write_text_atomic(f, json.dumps({"step": step, **metrics}, indent=1))


def train(cfg: TrainConfig, out_dir, *, train_set: Dataset | None = None, val_set: Dataset | None = None,
          resume: bool = False, stop_at_step: int | None = None, progress: bool = True,
          device: str | torch.device = "auto", amp: str | None = None, sync_bn: bool | None = None) -> TrainResult:
    """Train `cfg` into `out_dir` (config.json, log.jsonl, last.pt, model.pt, val_*). Datasets default to
    training.data.stacks built from cfg.data / cfg.val_data. stop_at_step: end this run early (as if killed
    after that step's checkpoint). An existing last.pt needs resume=True. device: auto | cpu | cuda[:N] | mps;
    amp: off | auto | bf16 | fp16; sync_bn: SyncBatchNorm across processes (default: on GPUs under torchrun)."""
    dev = resolve_device(device)
    rank, world, created = init_distributed(dev)
    try:
        return _train(cfg, Path(out_dir), train_set, val_set, resume, stop_at_step, progress, rank, world, dev,
                      amp_dtype(amp, dev), dev.type == "cuda" and world > 1 if sync_bn is None else sync_bn)
    finally:
        if created:
            dist.destroy_process_group()


def _train(cfg, out_dir: Path, train_set, val_set, resume, stop_at_step, progress, rank, world, device, amp,
           sync_bn) -> TrainResult:
    cfg.validate()
    ckpt_path = out_dir / "last.pt"
    if ckpt_path.exists() and not resume:
        raise FileExistsError(f"{out_dir}: has a checkpoint; pass --resume to continue or choose another --out")
    train_set, val_set = _make_sets(cfg, train_set, val_set)
    torch.manual_seed(cfg.seed)
    model = build_model(cfg.net, cfg.size, cfg.field_channels)
    maps_in = registry.get(cfg.net).focus_maps  # the any-camera net: per-pixel focus maps, its own loss
    step, wall_before, seen_before, sessions, state = 0, 0.0, 0, [], None
    t_start = time.perf_counter()
    if resume and ckpt_path.exists():
        state = load(ckpt_path)
        old = state["config"]
        # train_only too: the optimizer's moments are stored per trained tensor, by position
        for k, unset in (("net", 0), ("size", 0), ("simulator", 0), ("field_channels", 0), ("train_only", "")):
            if old.get(k, unset) != getattr(cfg, k):
                raise ValueError(f"{ckpt_path}: checkpoint has {k}={old.get(k, unset)!r}, config has {getattr(cfg, k)!r}")
        model.load_state_dict(state["model"])
        step = int(state["step"])
        wall_before = float(state.get("wall_s", 0.0))
        seen_before = int(state.get("stacks_seen", step * cfg.batch_size * world))
        sessions = list(state.get("sessions", []))
        torch.set_rng_state(state["torch_rng"])
    elif cfg.init:
        from training.nets.warm_start import init_model
        from training.train.data import resolve_lens_path

        info = init_model(model, resolve_lens_path(cfg.init), train_set)  # on the CPU, before the move
        if rank == 0:
            out_dir.mkdir(parents=True, exist_ok=True)
            _log(out_dir, {"step": 0, "init": info})
    if sync_bn and world > 1:
        model = torch.nn.SyncBatchNorm.convert_sync_batchnorm(model)  # same parameter and buffer names
    model.to(device)
    if cfg.train_only:
        freeze_all_but(model, cfg.train_only)
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=cfg.lr,
                           weight_decay=cfg.weight_decay)
    scaler = grad_scaler(device, amp)
    if state is not None:
        opt.load_state_dict(state["optimizer"])  # moves the moments to the parameters' device
        if scaler.is_enabled() and state.get("grad_scaler"):
            scaler.load_state_dict(state["grad_scaler"])
    if rank == 0:
        out_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out_dir / "config.json", json.dumps(cfg.to_dict(), indent=1))
    barrier(world)
    step0 = step
    sessions.append({"from_step": step, "device": str(device), "amp": amp_name(amp), "processes": world,
                     "sync_bn": bool(sync_bn and world > 1), "data_sources": _data_sources(train_set, val_set)})
    if world > 1:
        ddp = DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)
    else:
        ddp = model
    train_mode(model, cfg.train_only)

    def seen() -> int:
        return seen_before + (step - step0) * cfg.batch_size * world

    sampler = ResumableSampler(len(train_set), rank, world, cfg.seed)
    per_epoch = sampler.per_rank // cfg.batch_size
    if per_epoch == 0:
        raise ValueError(f"dataset of {len(train_set)} items is too small for batch {cfg.batch_size} x {world} processes")
    end = cfg.steps if stop_at_step is None else min(cfg.steps, stop_at_step)

    def checkpoint() -> None:
        broadcast_buffers(model, world)
        if rank == 0:
            save_atomic({"model": to_cpu(model.state_dict()), "optimizer": to_cpu(opt.state_dict()), "step": step,
                         "wall_s": wall_before + time.perf_counter() - t_start, "stacks_seen": seen(),
                         "sessions": sessions, "grad_scaler": scaler.state_dict() if scaler.is_enabled() else None,
                         "config": cfg.to_dict(), "torch_rng": torch.get_rng_state()}, ckpt_path)
        barrier(world)

    bar = tqdm(total=cfg.steps, initial=step, disable=not progress or rank != 0, desc=cfg.name, unit="step")
    last_loss, t_steps, n_timed = None, 0.0, 0
    while step < end:
        epoch, offset = divmod(step, per_epoch)
        sampler.set_epoch(epoch, offset * cfg.batch_size)
        loader = DataLoader(train_set, batch_size=cfg.batch_size, sampler=sampler, drop_last=True,
                            num_workers=cfg.num_workers, pin_memory=pin_memory(device),
                            collate_fn=getattr(train_set, "collate", None))
        for batch in loader:
            t0 = time.perf_counter()
            batch = to_device(batch, device)
            lr = lr_at(step, cfg.steps, cfg.lr, cfg.lr_min, cfg.warmup_steps)
            for g in opt.param_groups:
                g["lr"] = lr
            field = batch["field_xy"].float() if cfg.field_channels else None
            with autocast(device, amp):  # the nets only: the loss below is float32
                if maps_in:  # per-pixel focus maps in (training.nets.dfvaat)
                    levels = focus_map_levels(ddp, batch)
                else:
                    levels = train_levels(ddp, batch["stack"].float(), batch["focus_m"].float(),
                                          model.size_multiple, field)
            levels = [tuple(None if t is None else t.float() for t in lv) for lv in levels]
            loss, parts = (focus_map_loss if maps_in else dff_loss)(levels, batch, cfg.loss)
            opt.zero_grad(set_to_none=True)
            scaler.scale(loss).backward()
            if cfg.grad_clip > 0:
                scaler.unscale_(opt)
                parts["grad_norm"] = float(torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip))
            scaler.step(opt)  # float16: skipped when the gradients overflowed (then the scale shrinks)
            scaler.update()
            step += 1
            t_steps += time.perf_counter() - t0
            n_timed += 1
            last_loss = parts["total"]
            bar.update(1)
            bar.set_postfix(loss=f"{last_loss:.4f}", lr=f"{lr:.2e}")
            if rank == 0 and (step % cfg.log_every == 0 or step == end):
                _log(out_dir, {"step": step, "lr": lr, **parts, "s_per_step": t_steps / n_timed,
                               "stacks_seen": seen(),
                               "wall_s": round(wall_before + time.perf_counter() - t_start, 1)})
            if step % cfg.checkpoint_every == 0 or step == end:
                checkpoint()
            if val_set is not None and cfg.val_every and step % cfg.val_every == 0 and step < cfg.steps:
                if rank == 0:
                    _validate_and_log(model, val_set, cfg, out_dir, step, final=False)
                    train_mode(model, cfg.train_only)  # evaluate restores plain train mode
                barrier(world)
            if step >= end:
                break
    bar.close()
    broadcast_buffers(model, world)
    finished = step >= cfg.steps
    val_metrics: dict = {}
    if finished:
        if rank == 0:
            save_atomic({"model": to_cpu(model.state_dict()), "config": cfg.to_dict(), "config_hash": cfg.hash(),
                         "step": step}, out_dir / "model.pt")
            if val_set is not None:
                val_metrics = _validate_and_log(model, val_set, cfg, out_dir, step, final=True)
            summary = {"steps": step, "batch_size": cfg.batch_size, "processes": world, "stacks_seen": seen(),
                       "effective_batch": cfg.batch_size * world, "sessions": sessions,
                       "distinct_stacks": min(seen(), len(train_set)), "dataset_items": len(train_set),
                       "dataset_cache": str(getattr(train_set, "cache", None)),
                       "wall_s": round(wall_before + time.perf_counter() - t_start, 1),
                       "s_per_step_last_session": t_steps / n_timed if n_timed else None}
            write_text_atomic(out_dir / "train_summary.json", json.dumps(summary, indent=1))
        barrier(world)
    return TrainResult(step, finished, last_loss, t_steps / n_timed if n_timed else None, val_metrics)


def load_trained(path, device: str | torch.device = "cpu") -> tuple[torch.nn.Module, TrainConfig]:
    """A DfFNet (eval mode, on `device`) and its config from model.pt or last.pt, whatever device trained it."""
    from training.train.config import config_from_dict

    state = load(path)
    cfg = config_from_dict(dict(state["config"]), str(path))
    model = build_model(cfg.net, cfg.size, cfg.field_channels)
    model.load_state_dict(state["model"])
    return model.to(resolve_device(device)).eval(), cfg
