"""The array namespace of a computation: numpy, or torch when the inputs are torch tensors.

One formula serves the torch-free runtime and the training side (optiland keeps its maths backend-neutral the
same way): a function asks `namespace(*arrays)` for `xp` and uses the functions numpy and torch share
(`xp.sqrt`, `xp.abs`, `xp.clip`, `xp.exp`, ...). torch is never imported here: a torch tensor can only reach this
code from a process that has imported torch already, so it is taken from `sys.modules`.
"""

from __future__ import annotations

import sys
from types import ModuleType

import numpy as np


def is_torch(x) -> bool:
    """True for a torch tensor (without importing torch)."""
    return type(x).__module__.split(".")[0] == "torch"


def namespace(*arrays) -> ModuleType:
    """`torch` if any argument is a torch tensor, else `numpy`."""
    return sys.modules["torch"] if any(is_torch(a) for a in arrays) else np


def as_tensor(a: np.ndarray):
    """The numpy array as a torch tensor sharing its memory (torch.from_numpy); only called where torch tensors
    are already about, so torch is taken from `sys.modules`."""
    return sys.modules["torch"].from_numpy(a)


def arange_like(start: int, stop: int, like):
    """start, start + 1, ..., stop - 1 in `like`'s namespace, precision (and device, for torch)."""
    if is_torch(like):
        return sys.modules["torch"].arange(start, stop, dtype=like.dtype, device=like.device)
    return np.arange(start, stop, dtype=like.dtype)
