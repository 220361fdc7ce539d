"""`aat-train`: train a DfF network from a config file, or run the whole chain from a lens file.

    aat-train --config configs/dff_aifnet_aat.json [--out runs/NAME] [--resume] [--steps N] [--init M.onnx]
              [--device auto|cpu|cuda[:N]|mps] [--amp [bf16|fp16]]
    aat-train --lens LENS.json|.zmx --sensor-mm W,H --resolution W,H --out DIR [--net dfv|aif] [--size small|full]
              [--focus-range-m NEAR,FAR] [--stack N] [--effects a,b] [--init M.onnx|ckpt.pt] [--psf PSF.onnx]
              [--preset tiny|small|paper] [--steps N] [--lr LR] [--no-baseline] [--force]
    torchrun --nproc_per_node=2 --no-python aat-train ...      (or: torchrun ... -m training.cli.train ...)

--device: where torch runs (auto: a GPU if there is one); under torchrun each process takes the GPU of its
LOCAL_RANK and the processes talk over NCCL (gloo on CPUs). --amp: bf16 / fp16 autocast for the nets.
docs/training.md, "On GPUs and clusters", has the commands for one GPU, many GPUs and SLURM.

--config: re-running with --resume after a kill continues from the last checkpoint; without --resume an
existing run directory is refused.
--lens: lens check, PSF surrogate, AAT and thin-lens training, ONNX export, held-out evaluation and a report, all
in DIR (training/chain). Re-running the same command continues where it stopped and skips finished stages;
different settings on an existing DIR are refused unless --force, which reruns only the stages they change.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

from aat_deploy.cli.common import parser, run_or_hint
from aat_deploy.shipped import resolve
from training.devices.options import add_amp_argument, add_device_argument
from training.nets import registry

ROOT = Path(__file__).resolve().parents[2]


def _pair(kind):
    def parse(text: str):
        try:
            v = [kind(t) for t in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected two comma-separated numbers, got {text!r}") from None
        if len(v) != 2:
            raise argparse.ArgumentTypeError(f"expected two comma-separated numbers, got {text!r}")
        return tuple(v)
    return parse


def _names(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def build_parser() -> argparse.ArgumentParser:
    p = parser("aat-train", "Train depth-from-focus networks (AiFNet / DFVNet): from a training config, or the whole "
               "chain from a lens file. Needs the train extra.", quiet=False)
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--config", help="training config JSON (configs/dff_*.json)")
    mode.add_argument("--lens", help="lens file (.json, .zmx, .txt): run the whole lens-to-model chain into --out")
    p.add_argument("--out", help="run directory (--config: default runs/<config name>; --lens: required)")
    p.add_argument("--resume", action="store_true", help="--config: continue from <out>/last.pt if present "
                   "(--lens runs always continue)")
    p.add_argument("--steps", type=int, help="number of optimizer steps (overrides the config / preset)")
    p.add_argument("--init", help="start from these weights: an exported DfF .onnx or a model.pt / last.pt")
    add_device_argument(p)
    add_amp_argument(p)
    p.add_argument("-q", "--quiet", "--no-progress", dest="no_progress", action="store_true",
                   help="no progress bars: results, warnings and errors only")
    g = p.add_argument_group("lens-to-model chain (--lens)")
    g.add_argument("--sensor-mm", type=_pair(float), metavar="W,H", help="sensor size in mm (default: the lens file's)")
    g.add_argument("--resolution", type=_pair(int), metavar="W,H",
                   help="working resolution in px, what the model and aat-infer use (default: the lens file's)")
    nets = registry.aliases(chain_only=True)  # the nets the chain trains, by name or short name
    g.add_argument("--net", choices=list(nets), help="network (default: dfv, or --init's)")
    g.add_argument("--size", choices=sorted({z for n in set(nets.values()) for z in registry.NETS[n].sizes}),
                   help="network size (default: small, or --init's)")
    g.add_argument("--focus-range-m", type=_pair(float), default=(0.5, 10.0), metavar="NEAR,FAR",
                   help="focus distances, metres from the sensor (default 0.5,10)")
    g.add_argument("--stack", type=int, help="frames per stack (default: the preset's, 5 tiny / 8 otherwise)")
    g.add_argument("--effects", type=_names, default=[], metavar="A,B",
                   help="extra simulator effects for training and evaluation (aat-render --list-effects)")
    g.add_argument("--psf", help="reuse this PSF surrogate (.onnx made for the same lens and sensor): no PSF fit")
    g.add_argument("--preset", default="small", choices=["tiny", "small", "paper"],
                   help="data, fit and training sizes (default small)")
    g.add_argument("--lr", type=float, help="learning rate (default: the preset's; x0.1 with --init)")
    g.add_argument("--seed", type=int, default=0, help="seed of data and initialisation (default 0)")
    g.add_argument("--no-baseline", action="store_true", help="skip the thin-lens baseline (no comparison)")
    g.add_argument("--force", action="store_true", help="accept changed settings on an existing --out")
    return p


def apply_overrides(cfg, args: argparse.Namespace):
    """Command-line overrides of config fields (returns a new, validated config)."""
    changes = {}
    if args.steps is not None:
        changes["steps"] = args.steps
    if getattr(args, "init", None):
        changes["init"] = str(Path(args.init).resolve())
    return dataclasses.replace(cfg, **changes).validate() if changes else cfg


def refuse_inputs_in(out, inputs) -> bool:
    """True (after a one-line error) if the run folder is, contains or lies inside an input file: its stages
    would overwrite it (e.g. --init RUN/dff_dfvnet_aat.onnx --out RUN). Checked before any work."""
    from aat_deploy.errors import OutputError
    from aat_deploy.io.guard import check_no_overlap

    try:
        check_no_overlap(out, [p for p in inputs if p])
    except OutputError as e:
        print(f"aat-train: error: {e}", file=sys.stderr)
        return True
    return False


def main_config(args: argparse.Namespace) -> int:
    from training.train.config import ConfigError, load_config

    try:
        cfg = apply_overrides(load_config(args.config), args)
    except ConfigError as e:
        print(f"aat-train: {e}", file=sys.stderr)
        return 2
    from training.nets.warm_start import InitError
    from training.train.loop import train

    out = Path(args.out) if args.out else ROOT / "runs" / cfg.name
    if refuse_inputs_in(out, [args.config, cfg.init]):
        return 2
    try:
        res = train(cfg, out, resume=args.resume, progress=not args.no_progress, device=args.device, amp=args.amp)
    except (FileExistsError, ValueError, FileNotFoundError, InitError) as e:
        # exit 2: the inputs are wrong and a retry cannot help (scripts/train_dfv_aat.sh stops on it)
        print(f"aat-train: {e}", file=sys.stderr)
        return 2
    if int(os.environ.get("RANK", "0")) == 0:
        state = "finished" if res.finished else "stopped"
        spd = f", {res.seconds_per_step:.3f} s/step" if res.seconds_per_step else ""
        print(f"{cfg.name}: {state} at step {res.step}/{cfg.steps}{spd}; run in {out}")
        if res.val_metrics:
            print(json.dumps(res.val_metrics))
    return 0


def chain_options(args: argparse.Namespace):
    from training.chain.config import ChainOptions

    return ChainOptions(lens=args.lens, out=args.out, sensor_mm=args.sensor_mm, resolution=args.resolution,
                        net=args.net, size=args.size, focus_range_m=args.focus_range_m, stack=args.stack,
                        effects=args.effects, init=args.init, psf=args.psf, preset=args.preset, steps=args.steps,
                        lr=args.lr, baseline=not args.no_baseline, seed=args.seed)


def main_lens(args: argparse.Namespace) -> int:
    if not args.out:
        print("aat-train: --lens needs --out DIR (the run folder)", file=sys.stderr)
        return 2
    from aat_deploy.lens.io import LensFileError
    from training.chain.config import ChainConfigError, resolve
    from training.chain.runner import ChainError, run_chain
    from training.nets.warm_start import InitError

    if refuse_inputs_in(args.out, [args.lens, args.init, args.psf]):
        return 2
    try:
        cfg = resolve(chain_options(args))
    except ChainConfigError as e:
        print(f"aat-train: {e}", file=sys.stderr)
        return 2
    try:
        res = run_chain(cfg, args.out, force=args.force, progress=not args.no_progress, device=args.device,
                        amp=args.amp)
    except (ChainError, LensFileError, InitError, FileNotFoundError, ValueError) as e:
        print(f"aat-train: {str(e).splitlines()[0]}", file=sys.stderr)
        return 1
    if int(os.environ.get("RANK", "0")) == 0:
        ran = [k for k, v in res.actions.items() if v != "skipped"]
        print(f"{args.out}: done ({len(ran)} stage{'s' if len(ran) != 1 else ''} run, "
              f"{len(res.actions) - len(ran)} up to date); see {Path(args.out) / 'report.md'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_or_hint("aat-train", _main, argv)


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    from training.devices.select import DeviceError, resolve_device

    try:
        resolve_device(args.device)  # a missing GPU is a usage error, before any work
    except DeviceError as e:
        print(f"aat-train: error: {e}", file=sys.stderr)
        return 2
    if args.lens:
        args.lens = str(resolve(args.lens, "lenses"))  # a path, or a shipped lens's name
    if args.psf:
        args.psf = str(resolve(args.psf, "models"))
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    return main_lens(args) if args.lens else main_config(args)


if __name__ == "__main__":
    sys.exit(main())
