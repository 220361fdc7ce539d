"""The torchrun process group: NCCL between GPUs, gloo between CPU processes, chosen from the device.

torchrun (or `srun torchrun` on a cluster) sets RANK, WORLD_SIZE, LOCAL_RANK and the rendezvous address; a
process started without it is a world of one and creates no group. The helpers here are no-ops in a world of one.
"""

from __future__ import annotations

import datetime
import os

import torch
import torch.distributed as dist

# Rank 0 validates (or fits a PSF, in the chain) while the others wait in a collective: longer than torch's
# default. A lost node is noticed at the latest after this long, then torchrun restarts the workers.
DEFAULT_TIMEOUT = datetime.timedelta(minutes=60)


def backend_for(device: torch.device) -> str:
    """NCCL for CUDA devices, gloo for everything else (CPU; MPS has no collective backend of its own)."""
    return "nccl" if device.type == "cuda" else "gloo"


def world_from_env() -> int:
    return int(os.environ.get("WORLD_SIZE", "1"))


def init_distributed(device: torch.device, timeout: datetime.timedelta = DEFAULT_TIMEOUT) -> tuple[int, int, bool]:
    """(rank, world size, whether this call created the process group). Creates the group from torchrun's
    environment when WORLD_SIZE > 1 and there is none yet; the backend follows `device`."""
    created = False
    if world_from_env() > 1 and device.type == "mps":
        raise ValueError("--device mps under torchrun: torch has no collective backend for MPS tensors; "
                         "train one process on MPS, or use --device cpu")
    if world_from_env() > 1 and not dist.is_initialized():
        kw = {"device_id": device} if device.type == "cuda" else {}
        # The group's keys under a prefix of this attempt: after torchrun restarts lost workers, the store can still
        # hold the dead attempt's addresses, and gloo/NCCL would dial them ("Connection refused", or a hang until
        # the timeout; pytorch/pytorch#167288). A fresh namespace per restart makes them unreachable.
        store, rank, world = next(dist.rendezvous("env://", timeout=timeout))
        attempt = os.environ.get("TORCHELASTIC_RESTART_COUNT", "0")
        dist.init_process_group(backend_for(device), store=dist.PrefixStore(f"aat_attempt_{attempt}", store),
                                rank=rank, world_size=world, timeout=timeout, **kw)
        created = True
    if dist.is_initialized():
        return dist.get_rank(), dist.get_world_size(), created
    return 0, 1, created


def barrier(world: int) -> None:
    if world > 1:
        dist.barrier()


def broadcast_buffers(module: torch.nn.Module, world: int) -> None:
    """rank 0's buffers (batch-norm running statistics) on every replica."""
    if world > 1:
        for b in module.buffers():
            dist.broadcast(b, 0)


def share(obj, world: int):
    """rank 0's picklable `obj` on every process."""
    if world == 1:
        return obj
    box = [obj]
    dist.broadcast_object_list(box, src=0)
    return box[0]
