"""`--device auto|cpu|cuda[:N]|mps`: one parser and one resolver for every training-side command.

auto takes a GPU when there is one (CUDA first, then Apple's MPS), else the CPU. Under torchrun each process
takes the GPU of its LOCAL_RANK (one GPU per process, as DDP expects), so `--device cuda` or `auto` is what a
multi-GPU command passes; an explicit `cuda:N` with several processes per machine is refused.
"""

from __future__ import annotations

import functools
import os
import re

import torch

from aat_deploy.errors import AatError

_SPEC = re.compile(r"^(auto|cpu|mps|cuda(:\d+)?)$")


class DeviceError(AatError):
    """A --device that is malformed or not available here (one line)."""


def _mps_available() -> bool:
    mps = getattr(torch.backends, "mps", None)
    return bool(mps is not None and mps.is_available())


def local_rank() -> int:
    """This process's index on its machine (torchrun's LOCAL_RANK; 0 without torchrun)."""
    return int(os.environ.get("LOCAL_RANK", "0"))


def local_world() -> int:
    """Processes per machine (torchrun's LOCAL_WORLD_SIZE; 1 without torchrun)."""
    return int(os.environ.get("LOCAL_WORLD_SIZE", "1"))


def resolve_device(spec: str | torch.device | None = "auto") -> torch.device:
    """The torch.device for `spec` (None = auto). Raises DeviceError with one line when it is malformed or
    absent (e.g. cuda on a machine without CUDA, cuda:3 with 2 GPUs)."""
    if isinstance(spec, torch.device):
        spec = str(spec)
    spec = (spec or "auto").strip().lower()
    if not _SPEC.match(spec):
        raise DeviceError(f"--device {spec!r}: expected auto, cpu, cuda, cuda:N or mps")
    if spec == "auto":
        if torch.cuda.is_available():
            spec = "cuda"
        elif _mps_available():
            spec = "mps"
        else:
            return torch.device("cpu")
    if spec == "cpu":
        return torch.device("cpu")
    if spec == "mps":
        if not _mps_available():
            raise DeviceError("--device mps: this torch has no MPS device (Apple GPUs only)")
        return torch.device("mps")
    if not torch.cuda.is_available():
        raise DeviceError(f"--device {spec}: no CUDA device here (torch {torch.__version__}, "
                          f"CUDA build: {torch.version.cuda or 'no'}); use --device cpu or auto")
    n = torch.cuda.device_count()
    if spec == "cuda":
        index = local_rank() % n
    else:
        index = int(spec.split(":")[1])
        if local_world() > 1:
            raise DeviceError(f"--device {spec}: under torchrun each process uses the GPU of its LOCAL_RANK; "
                              "pass --device cuda (or auto)")
    if index >= n:
        raise DeviceError(f"--device cuda:{index}: only {n} CUDA device{'s' if n != 1 else ''} here")
    torch.cuda.set_device(index)  # NCCL and tensors created without a device index use this one
    return torch.device("cuda", index)


def pin_memory(device: torch.device) -> bool:
    """Page-locked loader batches speed up host-to-GPU copies; pointless (and a warning) elsewhere."""
    return device.type == "cuda"


def to_device(batch: dict, device: torch.device) -> dict:
    """Every tensor of a loader batch on `device` (non-blocking from pinned memory)."""
    return {k: v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}


def to_cpu(obj):
    """A state dict (nested dicts / lists of tensors, e.g. an optimizer's) with every tensor on the CPU: what
    checkpoints store, so they load anywhere."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu()
    if isinstance(obj, dict):
        return {k: to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(to_cpu(v) for v in obj)
    return obj


def on_cpu(fn):
    """Run `fn` with the CPU as torch's default device, whatever device context its caller is in: for the PSF
    sources, which answer on the CPU (their random generators and numpy exchanges are CPU-bound) while the
    simulator renders on a GPU under `with device:` (training.render.simulator)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with torch.device("cpu"):
            return fn(*args, **kwargs)
    return wrapper
