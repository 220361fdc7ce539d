"""Fitting PSF surrogates to a cached ray-traced dataset, on a wall-clock budget, resumable from checkpoints.

The learning rate follows a cosine over the time budget (not over steps), so a fit stopped and resumed ends
where an uninterrupted one would. A held-out set is scored every `eval_every_s` seconds; that history is the
"accuracy per training minute" curve. `device` (training.devices.select) runs the fit on a GPU; checkpoints hold
CPU tensors and load on any device, and the fitted model is handed back on the CPU.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from tqdm import tqdm

from aat_deploy.io.atomic import atomic_file
from training.devices.select import resolve_device, to_cpu
from training.psf.surrogates import PaperMLP, PSFModel, RotPSF


@dataclass
class FitConfig:
    minutes: float = 10.0
    batch: int = 256
    lr: float = 1e-3
    weight_decay: float = 1e-4
    loss: str = "l1"  # "l1" (sum over cells) or "mse" (the paper's)
    eval_every_s: float = 30.0
    checkpoint_every_s: float = 60.0
    seed: int = 0
    history: list = field(default_factory=list)


def psf_errors(pred: torch.Tensor, gt: torch.Tensor) -> tuple[float, float]:
    """Mean absolute and mean squared per-cell error over all PSFs and cells (energy units)."""
    d = (pred - gt).double()
    return float(d.abs().mean()), float((d * d).mean())


@torch.no_grad()
def evaluate(model: PSFModel, q: torch.Tensor, gt: torch.Tensor, batch: int = 4096) -> tuple[float, float]:
    model.eval()
    dev = next(model.parameters()).device
    preds = torch.cat([model(q[i:i + batch].to(dev)).cpu() for i in range(0, q.shape[0], batch)])
    model.train()
    return psf_errors(preds, gt.cpu())  # float64 on the CPU (MPS has no float64)


def _batch_loss(model: PSFModel, data: dict, idx: torch.Tensor, loss: str) -> torch.Tensor:
    if isinstance(model, RotPSF):
        # Trained on +y-axis PSFs at half-cell resolution. The shape is scored at the true energy and the energy
        # on its own: scoring shape x predicted energy lets L1 shrink the energy to zero while the shape is still
        # wrong, a plateau that wasted minutes of the time budget.
        shape, energy = model.axis_shape_energy(data["r"][idx], data["depth_m"][idx], data["focus_m"][idx])
        gt = data["kernels"][idx]
        e_gt = gt.sum((1, 2))
        return ((shape * e_gt[:, None, None] - gt).abs().sum((1, 2)) + (energy - e_gt).abs()).mean()
    else:
        q = torch.stack([data["x"][idx], data["y"][idx], data["depth_m"][idx], data["focus_m"][idx]], -1)
        pred = model(q)
    gt = data["kernels"][idx]
    d = pred - gt
    if loss == "mse":
        return (d * d).mean()
    return d.abs().sum((1, 2)).mean()


def fit(model: PSFModel, data: dict[str, torch.Tensor], cfg: FitConfig, ckpt: Path | None = None,
        val: tuple[torch.Tensor, torch.Tensor] | None = None, progress: bool = True,
        device: str | torch.device = "cpu") -> FitConfig:
    """Train `model` on `data` (tensors from dataset.to_tensors) for cfg.minutes of wall-clock time, on `device`
    (auto | cpu | cuda[:N] | mps); the model ends on the CPU.

    ckpt: a checkpoint path; if it exists the fit resumes from it (model, optimiser, elapsed time, history).
    val: (queries (M, 4), ray-traced kernels (M, k, k)) scored during training.
    """
    dev = resolve_device(device)
    torch.manual_seed(cfg.seed)
    model.to(dev)
    data = {k: v.to(dev) if isinstance(v, torch.Tensor) else v for k, v in data.items()}
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    elapsed, step = 0.0, 0
    if ckpt is not None and Path(ckpt).exists():
        st = torch.load(ckpt, map_location="cpu", weights_only=False)
        model.load_state_dict(st["model"])
        opt.load_state_dict(st["opt"])  # moves the moments to the parameters' device
        elapsed, step, cfg.history = st["elapsed"], st["step"], st["history"]
    n = data["kernels"].shape[0]
    budget = cfg.minutes * 60.0
    gen = torch.Generator().manual_seed(cfg.seed + step)
    last_eval = last_ckpt = -1e9
    t0 = time.perf_counter() - elapsed
    bar = tqdm(total=int(budget), desc=f"fitting {type(model).__name__}", unit="s", disable=not progress,
               initial=int(elapsed))

    def save():
        if ckpt is None:
            return
        Path(ckpt).parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(ckpt) as tmp:
            torch.save({"model": to_cpu(model.state_dict()), "opt": to_cpu(opt.state_dict()), "elapsed": elapsed,
                        "step": step, "history": cfg.history, "config": asdict(cfg)}, tmp)

    while elapsed < budget:
        for g in opt.param_groups:  # cosine over wall-clock time
            g["lr"] = cfg.lr * 0.5 * (1 + math.cos(math.pi * min(elapsed / budget, 1.0)))
        idx = torch.randint(0, n, (cfg.batch,), generator=gen).to(dev)  # drawn on the CPU: the same on any device
        loss = _batch_loss(model, data, idx, cfg.loss)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        now = time.perf_counter()
        bar.update(int(now - t0) - int(elapsed))
        elapsed = now - t0
        if val is not None and (elapsed - last_eval >= cfg.eval_every_s or elapsed >= budget):
            t_eval = time.perf_counter()
            l1, l2 = evaluate(model, *val)
            cfg.history.append({"minutes": elapsed / 60, "step": step, "l1": l1, "l2": l2})
            bar.set_postfix(l1=f"{l1:.2e}")
            last_eval = elapsed
            t0 += time.perf_counter() - t_eval  # scoring is not training time
        if elapsed - last_ckpt >= cfg.checkpoint_every_s:
            save()
            last_ckpt = elapsed
    save()
    bar.close()
    model.cpu()
    return cfg


def make_model(kind: str, lens, spec, near_m: float, far_m: float) -> PSFModel:
    if kind == "paper_mlp":
        return PaperMLP(lens, spec, near_m, far_m)
    if kind == "rot":
        return RotPSF(lens, spec, near_m, far_m)
    raise ValueError(f"unknown surrogate {kind!r} (paper_mlp, rot)")


__all__ = ["FitConfig", "evaluate", "fit", "make_model", "psf_errors"]
