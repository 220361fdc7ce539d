"""Mixed precision for the DfF nets (`--amp`): autocast to bfloat16 or float16 around the nets' forward pass.

Only the nets run under autocast. The loss is computed in float32 from float32 casts of the net outputs, the
optimizer keeps float32 weights, and the data (ray tracer, PSF surrogate, layered renderer) is made before and
outside the autocast region, so it stays float32. float16 has a narrow exponent range: its gradients go through
a GradScaler; bfloat16 needs none.
"""

from __future__ import annotations

import contextlib

import torch

from training.devices.options import AMP_CHOICES

_DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


def amp_dtype(amp: str | None, device: torch.device) -> torch.dtype | None:
    """The autocast dtype for `amp` on `device` (None = float32 throughout). ValueError for unknown names."""
    amp = (amp or "off").lower()
    if amp not in AMP_CHOICES:
        raise ValueError(f"--amp {amp!r}: expected one of {', '.join(AMP_CHOICES)}")
    if amp == "off":
        return None
    if amp == "auto":
        bf16_ok = device.type == "cpu" or (device.type == "cuda" and torch.cuda.is_bf16_supported())
        return torch.bfloat16 if bf16_ok else torch.float16
    return _DTYPES[amp]


def amp_name(dtype: torch.dtype | None) -> str:
    return {None: "off", torch.bfloat16: "bf16", torch.float16: "fp16"}[dtype]


def autocast(device: torch.device, dtype: torch.dtype | None):
    """The autocast context for the nets' forward pass (a no-op context for float32)."""
    if dtype is None:
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=dtype)


def grad_scaler(device: torch.device, dtype: torch.dtype | None) -> torch.amp.GradScaler:
    """Loss scaling for float16 (a disabled scaler, which passes everything through, otherwise)."""
    return torch.amp.GradScaler(device.type, enabled=dtype == torch.float16)
