"""Fingerprints (SHA-256 of the bytes) of outputs a restructuring must leave unchanged, to compare two checkouts.

    OMP_WAIT_POLICY=PASSIVE python -m scripts.output_fingerprints [--out fingerprints.json] [--only twin,infer_focus]
        [--checkout DIR]

Computes, from the checkout it runs in (about a minute on 2 cores):
- `aat-infer captures/sample_rf50 --model models/reproduce/dff_dfvnet_aat.onnx`: depth_m.npy, std_m.npy, aif.png;
- `aat-infer captures/sample_rf50 --method focus --lens canon_rf50mm_f1.8`: depth_m.npy, confidence.npy;
- rendered training stacks (`FocalStackDataset.render`, item 0 and 1): the AAT simulator with vignetting and noise
  on a photo-textured scene, and the thin-lens simulator;
- a whole-sensor held-out RGB-D stack (`heldout.rgbd_item`: fit to the sensor, hole filling, normalisation);
- the torch-free twin renderer (`optical_stack` + `post_frame`) through the shipped PSF surrogate;
- thin-lens blur and PSF window sizes (`thin_lens_blur_px`, `KernelSpec.scale`), the numpy and torch Gaussian
  baselines' kernels.
Prints a table (output, first 16 hex digits); --out also writes the full digests as JSON. Two checkouts agree bit
for bit when their tables are equal. --only computes the named groups alone (cheap enough to bisect one output);
--checkout computes them from another checkout's code and data (e.g. a `git worktree` at an older commit, as far back
as this script's functions exist there). The changes explained so far: BENCHMARKS.md, "Output fingerprints".
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(os.environ.get("AAT_FINGERPRINTS_ROOT") or Path(__file__).resolve().parents[1])  # see --checkout


def _digest(a) -> str:
    if isinstance(a, (bytes, bytearray)):
        return hashlib.sha256(a).hexdigest()
    a = np.ascontiguousarray(np.asarray(a))
    return hashlib.sha256(f"{a.dtype.str}{a.shape}".encode() + a.tobytes()).hexdigest()


def _infer(out: dict, only: set[str] | None = None) -> None:
    runs = {"infer_dfvnet": ["--model", str(ROOT / "models/reproduce/dff_dfvnet_aat.onnx")],
            "infer_focus": ["--method", "focus", "--lens", "canon_rf50mm_f1.8"]}
    with tempfile.TemporaryDirectory(prefix="aat_fingerprints_") as tmp:
        for name, extra in runs.items():
            if only is None or name in only:
                _infer_one(out, Path(tmp), name, extra)


def _infer_one(out: dict, tmp: Path, name: str, extra: list[str]) -> None:
    d = tmp / name
    subprocess.run([sys.executable, "-m", "aat_deploy.cli.infer", str(ROOT / "captures/sample_rf50"), *extra,
                    "--out", str(d), "-q", "--threads", "1"], check=True, cwd=ROOT,
                   env={**os.environ, "PYTHONPATH": str(ROOT)})
    for f in ("depth_m.npy", "std_m.npy", "aif.png", "confidence.npy"):
        if (d / f).is_file():
            out[f"{name}/{f}"] = _digest((d / f).read_bytes())


def _stacks(out: dict) -> None:
    from training.data.stacks import FocalStackDataset, StackDataConfig

    cfgs = {"stack_aat_vign_noise": StackDataConfig(simulator="aat", effects=("vignetting", "noise"), height=64,
                                                     width=96, stack_size=5, photo_fraction=1.0, seed=7),
            "stack_thin": StackDataConfig(simulator="thin_lens", height=64, width=64, stack_size=4, seed=3)}
    for name, cfg in cfgs.items():
        ds = FocalStackDataset(cfg)
        for i in (0, 1):
            for k, v in sorted(ds.render(i).items()):
                out[f"{name}/{i}/{k}"] = _digest(v)


def _heldout(out: dict) -> None:
    from training.data.stacks import FocalStackDataset, StackDataConfig
    from training.train.heldout import rgbd_item

    ds = FocalStackDataset(StackDataConfig(simulator="aat", stack_size=4, height=64, width=64))
    rng = np.random.default_rng(5)
    rgb = rng.random((500, 700, 3), dtype=np.float32)
    gt = np.where(rng.random((500, 700)) < 0.05, 0, rng.uniform(0.6, 5.0, (500, 700))).astype(np.float32)
    for k, v in zip(("stack", "focus_m", "gt"), rgbd_item(ds, rgb, gt)):
        out[f"heldout_rgbd/{k}"] = _digest(v)


def _twin(out: dict) -> None:
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render import effects as fx
    from aat_deploy.render.optical import optical_stack
    from aat_deploy.render.sources import GaussianSource, OnnxSource

    lens = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
    src = OnnxSource(ROOT / "models/psf_rf50.onnx", lens, threads=1)
    ctx = fx.SimContext(lens, (640, 960), (100, 200), src, src.focus_table(), src.exit_pupil_z_mm())
    rng = np.random.default_rng(0)
    rgb = rng.random((3, 48, 64), dtype=np.float32)
    depth = np.repeat(np.linspace(0.7, 4.0, 64, dtype=np.float32)[None], 48, 0)
    effects = fx.parse("aberrations,vignetting,sensor_tilt,focus_breathing,noise,focus_metadata")
    focus = fx.twin_focus(effects, [0.8, 1.5, 3.0], ctx, rng)
    frames = optical_stack(effects, GaussianSource(lens), rgb, depth, focus, ctx)
    frames = [fx.post_frame(effects, f, float(d), ctx, rng) for f, d in zip(frames, focus)]
    out["twin/frames"] = _digest(np.stack(frames))


def _blur(out: dict) -> None:
    import torch

    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.thin_lens import thin_lens_blur_px
    from aat_deploy.psf.kernel import KernelSpec
    from aat_deploy.render.sources import GaussianSource
    from training.psf.surrogates import GaussianPSF

    lens = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
    d = np.geomspace(0.3, 50, 97)[:, None]
    f = np.geomspace(0.4, 20, 13)[None]
    out["thin_lens_blur_px"] = _digest(thin_lens_blur_px(lens, d, f))
    out["kernel_scale"] = _digest(KernelSpec(size=11, margin_px=4.0).scale(lens, d, f))
    dd, ff = (np.broadcast_to(a, (97, 13)).ravel().astype(np.float32) for a in (d, f))
    k, s = GaussianSource(lens)(0.0, 0.0, dd, ff)
    out["gaussian_numpy/kernels"], out["gaussian_numpy/scale"] = _digest(k), _digest(s)
    q = torch.from_numpy(np.stack([np.zeros_like(dd), np.zeros_like(dd), dd, ff], -1))
    g = GaussianPSF(lens, KernelSpec(), 0.3, 50.0)
    with torch.no_grad():
        out["gaussian_torch/kernels"] = _digest(g(q).numpy())
        out["gaussian_torch/blur_px"] = _digest(g.blur_px(q[:, 2], q[:, 3]).numpy())


GROUPS = ("infer_dfvnet", "infer_focus", "stacks", "heldout", "twin", "blur")


def _in_checkout(root: Path, only: str | None, out: Path | None) -> int:
    """Run this file again with `root`'s packages first on the path (`python -c` puts its working folder first)."""
    args = (["--only", only] if only else []) + (["--out", str(out.resolve())] if out else [])
    code = "import runpy, sys; sys.argv[0] = sys.argv.pop(1); runpy.run_path(sys.argv[0], run_name='__main__')"
    env = {**os.environ, "PYTHONPATH": str(root), "AAT_FINGERPRINTS_ROOT": str(root)}
    return subprocess.run([sys.executable, "-c", code, __file__, *args], cwd=root, env=env, check=False).returncode


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="also write the full digests as JSON here")
    ap.add_argument("--only", help=f"comma-separated groups to compute (of {', '.join(GROUPS)}); default all")
    ap.add_argument("--checkout", type=Path, help="the checkout whose code and data to fingerprint (default this one)")
    args = ap.parse_args(argv)
    only = None if args.only is None else set(args.only.split(","))
    if only is not None and not only <= set(GROUPS):
        ap.error(f"--only: unknown group(s) {', '.join(sorted(only - set(GROUPS)))}; known: {', '.join(GROUPS)}")
    if args.checkout is not None:
        if not (args.checkout / "aat_deploy").is_dir():
            ap.error(f"--checkout {args.checkout}: no aat_deploy/ there")
        return _in_checkout(args.checkout.resolve(), args.only, args.out)
    import torch

    torch.set_num_threads(1)
    out: dict[str, str] = {}
    _infer(out, only)
    for name, fn in (("stacks", _stacks), ("heldout", _heldout), ("twin", _twin), ("blur", _blur)):
        if only is None or name in only:
            fn(out)
    print("| output | sha256 (first 16) |\n|---|---|")
    for k, v in out.items():
        print(f"| {k} | {v[:16]} |")
    if args.out:
        args.out.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
