"""Training where users train (issue 38): the GPU paths against the CPU, in one run, on the same inputs.

    python -m benchmarks.bench_devices --device cuda                       # one GPU vs this machine's CPU
    python -m benchmarks.bench_devices --device cuda --sections train --nets aifnet:full,dfvnet:full
    torchrun --standalone --nproc_per_node=gpu -m benchmarks.bench_devices --sections ddp   # NCCL, all GPUs
    python -m benchmarks.bench_devices --device cpu --quick                # smoke run of the script itself

Sections (each prints a table; times are wall clock, best of --repeat, the ratio is CPU time / device time):
- trace: ray-traced PSFs (training.psf.raytrace, RF50, 1024 rays, 11 x 11): the kernels' largest difference
  relative to their peak, and the time of each.
- render: one 8-frame focal stack through the RF50 surrogate (training.render.simulator, 192 x 192 crop and the
  whole 640 x 960 sensor): largest |difference| / mean intensity, and the times.
- psf_fit: RotPSF steps per second on traced axis PSFs (training.psf.fit, 20 s budget each by default).
- train: seconds per optimizer step of the training loop (training.train.loop.train, 128 x 128 crops, 8 frames,
  batch 4, synthetic stacks) per net and size, in float32 and with --amp bf16 / fp16 on the device.
- amp: the loss curves of 60 steps in float32 and under autocast (bf16, fp16) on the device: the largest relative
  difference of the mean loss over windows of 10 steps (the CPU test, tests/training/train/test_devices.py,
  states 15 % over 4-step windows for bf16).
- export: a net trained a few steps on the device, exported from its checkpoint (training.train.export): the
  ONNX-vs-torch parity error, as the export checks it for CPU-trained nets.
- ddp (under torchrun): seconds per step with all processes (NCCL on GPUs) against one, the effective batch and
  the scaling efficiency.

Not run on this project's machines (2 CPU cores, no GPU); BENCHMARKS.md, "Devices", says so.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from benchmarks.timing import best_of

ROOT = Path(__file__).resolve().parents[1]

LENS = ROOT / "lenses" / "canon_rf50mm_f1.8.json"
PSF = ROOT / "models" / "psf_rf50.onnx"
SECTIONS = ("trace", "render", "psf_fit", "train", "amp", "export", "ddp")


def _sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def _table(title: str, head: list[str], rows: list[list]) -> None:
    print(f"\n### {title}\n")
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for r in rows:
        print("| " + " | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r) + " |")
    sys.stdout.flush()


class RandomStacks(Dataset):
    """Synthetic items of the training interface (training/train/data.py): random stacks and depths. For timing
    and loss-curve comparison only (deterministic in the index)."""

    def __init__(self, n: int, size: int, frames: int = 8):
        self.n, self.size, self.frames = n, size, frames

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> dict:
        g = torch.Generator().manual_seed(i)
        s, f = self.size, self.frames
        depth = 0.5 + 9.5 * torch.rand(s // 8, s // 8, generator=g)
        depth = torch.nn.functional.interpolate(depth[None, None], size=(s, s), mode="nearest")[0, 0]
        return {"stack": torch.rand(f, 3, s, s, generator=g), "focus_m": 1 / torch.linspace(2.0, 0.1, f),
                "depth_m": depth, "aif": torch.rand(3, s, s, generator=g)}


def bench_trace(dev, a) -> None:
    from aat_deploy.lens.io import load_lens
    from training.psf.raytrace import raytrace_psfs

    lens = load_lens(LENS)
    rng = np.random.default_rng(0)
    n = 256 if a.quick else 4096
    x, y = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    d, f = 1 / rng.uniform(0.1, 2, n), 1 / rng.uniform(0.1, 2, n)
    rows = []
    out = {}
    for name, where in (("cpu", "cpu"), (str(dev), dev)):
        (b, t) = best_of(lambda: (raytrace_psfs(lens, x, y, d, f, n_rays=1024, device=where), _sync(dev))[0], a.repeat)
        out[name] = (b.kernels, t)
    err = float((out["cpu"][0] - out[str(dev)][0]).abs().max() / out["cpu"][0].max())
    rows.append([n, 1024, out["cpu"][1], out[str(dev)][1], out["cpu"][1] / out[str(dev)][1], err])
    _table("Ray-traced PSFs", ["PSFs", "rays", "cpu s", f"{dev} s", "ratio", "max |diff| / peak"], rows)


def bench_render(dev, a) -> None:
    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.focus_table import diopter_grid
    from aat_deploy.render import effects as fx
    from training.data.scenes import SceneConfig, procedural_scene
    from training.render.layered import LayeredConfig
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF

    lens = load_lens(LENS)
    src = OnnxPSF(PSF, lens)
    focus = diopter_grid(0.5, 10.0, 8)
    rows = []
    sizes = [(192, 192)] if a.quick else [(192, 192), (lens.sensor.height_px, lens.sensor.width_px)]
    for h, w in sizes:
        rgb, depth = procedural_scene(SceneConfig(height=h, width=w), np.random.default_rng(0))
        img = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))).float()
        dep = torch.from_numpy(depth).float()
        res = {}
        for where in ("cpu", dev):
            sim = Simulator(lens, src, fx.parse(["aberrations"]), LayeredConfig(cell_px=64), device=where)
            st, t = best_of(lambda: (sim.render_stack(img, dep, focus, rng=np.random.default_rng(0)), _sync(dev))[0],
                            a.repeat)
            res[str(where)] = (st.frames, t)
        cpu, gpu = res["cpu"], res[str(dev)]
        err = float((cpu[0] - gpu[0]).abs().max() / cpu[0].abs().mean())
        rows.append([f"{w} x {h}", 8, cpu[1], gpu[1], cpu[1] / gpu[1], err])
    _table("Focal-stack rendering (RF50 surrogate)", ["size", "frames", "cpu s", f"{dev} s", "ratio",
                                                      "max |diff| / mean"], rows)


def bench_psf_fit(dev, a) -> None:
    from aat_deploy.lens.io import load_lens
    from aat_deploy.psf.kernel import KernelSpec
    from training.psf.dataset import PSFDataConfig, build_psf_dataset, to_tensors
    from training.psf.fit import FitConfig, fit
    from training.psf.surrogates import RotPSF

    lens = load_lens(LENS)
    cfg = PSFDataConfig(layout="axis", n=2000 if a.quick else 20000, n_rays=512, near_m=0.3, far_m=20.0)
    data = to_tensors(build_psf_dataset(lens, cfg, Path(a.cache), progress=False))
    rows = []
    secs = 5.0 if a.quick else a.fit_seconds
    for where in ("cpu", dev):
        torch.manual_seed(0)
        model = RotPSF(lens, KernelSpec.for_lens(lens, 11, 4.0), 0.3, 20.0)
        fc = FitConfig(minutes=secs / 60, batch=256, eval_every_s=1e9, checkpoint_every_s=1e9)
        with tempfile.TemporaryDirectory() as tmp:
            fit(model, data, fc, ckpt=Path(tmp) / "fit.pt", progress=False, device=where)
            steps = torch.load(Path(tmp) / "fit.pt", map_location="cpu", weights_only=False)["step"]
        rows.append([str(where), steps / secs])
    rows.append(["ratio", rows[1][1] / rows[0][1]])
    _table(f"RotPSF fit (batch 256, {secs:g} s each)", ["device", "steps / s"], rows)


def _step_seconds(log: list[dict]) -> float:
    """Median seconds of one step after the first (the log holds running means of s_per_step)."""
    means = [r["s_per_step"] for r in log]
    per = [k * m - (k - 1) * p for k, (p, m) in enumerate(zip(means, means[1:]), start=2)]
    return float(np.median(per)) if per else float(means[0])


def _train_once(dev, net, size, amp, steps, a, out, batch=4, log_every=1):
    from training.train.config import LossConfig, TrainConfig
    from training.train.loop import train

    cfg = TrainConfig(name=f"{net}_{size}_{amp}", net=net, size=size, simulator="aat", lens=str(LENS), steps=steps,
                      batch_size=batch, lr=1e-4, checkpoint_every=10 ** 6, log_every=log_every,
                      loss=LossConfig(level_weights=(8.0, 4.0)), num_workers=0).validate()
    data = RandomStacks(max(64, steps * batch), 64 if a.quick else 128)
    res = train(cfg, out, train_set=data, progress=False, device=dev, amp=amp)
    return res, [json.loads(r) for r in (Path(out) / "log.jsonl").read_text().splitlines()]


def bench_train(dev, a) -> None:
    rows = []
    amps = ["off", "bf16", "fp16"] if dev.type == "cuda" else ["off", "bf16"]
    for spec in a.nets.split(","):
        net, size = spec.split(":")
        times = {}
        for where, amp in [("cpu", "off")] + [(dev, m) for m in amps]:
            steps = (2 if size == "full" else 4) if str(where) == "cpu" else 20
            with tempfile.TemporaryDirectory() as tmp:
                _, log = _train_once(torch.device(where) if isinstance(where, str) else where, net, size, amp,
                                     steps, a, tmp)
            times[(str(where), amp)] = _step_seconds(log)
        base = times[("cpu", "off")]
        for (where, amp), t in times.items():
            rows.append([f"{net} {size}", where, amp, t, base / t])
    px = 64 if a.quick else 128
    _table(f"Training loop, s per step (batch 4, 8 x {px} x {px})", ["net", "device", "amp", "s / step",
                                                                  "cpu fp32 / this"], rows)


def bench_amp(dev, a) -> None:
    rows = []
    amps = ["bf16", "fp16"] if dev.type == "cuda" else ["bf16"]
    steps = 20 if a.quick else 60
    for spec in a.nets.split(","):
        net, size = spec.split(":")
        curves = {}
        for amp in ["off"] + amps:
            with tempfile.TemporaryDirectory() as tmp:
                _, log = _train_once(dev, net, size, amp, steps, a, tmp)
            curves[amp] = np.array([r["total"] for r in log])
        w = 10
        ref = curves["off"][: steps // w * w].reshape(-1, w).mean(1)
        for amp in amps:
            m = curves[amp][: steps // w * w].reshape(-1, w).mean(1)
            rows.append([f"{net} {size}", amp, steps, float(np.max(np.abs(m - ref) / ref)),
                         float(abs(curves[amp][0] - curves["off"][0]) / curves["off"][0])])
    _table("Mixed precision: loss curve vs float32", ["net", "amp", "steps", "max rel. diff of 10-step means",
                                                      "first-step rel. diff"], rows)


def bench_export(dev, a) -> None:
    from training.train.export import export_checkpoint

    rows = []
    for spec in a.nets.split(","):
        net, size = spec.split(":")
        with tempfile.TemporaryDirectory() as tmp:
            _train_once(dev, net, size, "off", 3, a, Path(tmp) / "run")
            _, err = export_checkpoint(Path(tmp) / "run" / "model.pt", Path(tmp) / "m.onnx")
        rows.append([f"{net} {size}", str(dev), err])
    _table("Export of a device-trained checkpoint", ["net", "trained on", "ORT vs torch (relative)"], rows)


def bench_ddp(dev, a) -> None:
    """Under torchrun: seconds per step with every process (NCCL on GPUs, gloo on CPUs), batch 4 per process."""
    from training.devices.distributed import init_distributed

    rank, world, _ = init_distributed(dev)
    rows = []
    for spec in a.nets.split(","):
        net, size = spec.split(":")
        with tempfile.TemporaryDirectory() as tmp:  # only rank 0 writes (and reads back) its log
            _, log = _train_once(dev, net, size, "off", 20, a, Path(tmp) / "run")
        if rank == 0:
            rows.append([f"{net} {size}", world, 4 * world, _step_seconds(log)])
    if rank == 0:
        _table(f"DDP over {world} processes ({'NCCL' if dev.type == 'cuda' else 'gloo'})",
               ["net", "processes", "effective batch", "s / step"], rows)
        print("Scaling efficiency = the same net's s / step on one device (section train, batch 4) / this s / step.")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="auto", help="the device to compare with the CPU (default auto)")
    ap.add_argument("--sections", default="trace,render,psf_fit,train,amp,export",
                    help=f"comma-separated, of {', '.join(SECTIONS)} (ddp: under torchrun only)")
    ap.add_argument("--nets", default="dfvnet:small,aifnet:small,dfvnet:full,aifnet:full",
                    help="net:size pairs for train, amp and export")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--fit-seconds", type=float, default=20.0)
    ap.add_argument("--cache", default=str(ROOT / "cache"), help="where traced PSF datasets are cached")
    ap.add_argument("--quick", action="store_true", help="small sizes: a smoke run of the script")
    a = ap.parse_args(argv)
    from training.devices.select import resolve_device

    dev = resolve_device(a.device)
    sections = [s.strip() for s in a.sections.split(",") if s.strip()]
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        ap.error(f"unknown sections {sorted(unknown)}")
    if "ddp" in sections and int(os.environ.get("WORLD_SIZE", "1")) < 2:
        ap.error("--sections ddp runs under torchrun (WORLD_SIZE > 1)")
    if int(os.environ.get("RANK", "0")) == 0:
        name = torch.cuda.get_device_name(dev) if dev.type == "cuda" else dev.type
        print(f"bench_devices: {dev} ({name}), torch {torch.__version__}, {torch.get_num_threads()} CPU threads")
    for s in sections:
        globals()[f"bench_{s}"](dev, a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
