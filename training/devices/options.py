"""The command-line options every training-side command shares, torch-free (a parser must build, and --help
and --version answer, without torch): `--device` and `--amp`."""

from __future__ import annotations

import argparse

DEVICE_HELP = "where torch runs: auto (a GPU if there is one, else the CPU), cpu, cuda, cuda:N or mps (default auto)"
AMP_CHOICES = ("off", "auto", "bf16", "fp16")
AMP_HELP = ("mixed precision for the nets: bf16 or fp16 autocast (a bare --amp: bf16 where the device supports "
            "it, else fp16); the data and the loss stay float32 (default off)")


def add_device_argument(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--device", default="auto", metavar="auto|cpu|cuda[:N]|mps", help=DEVICE_HELP)


def add_amp_argument(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--amp", nargs="?", const="auto", default="off", choices=AMP_CHOICES, help=AMP_HELP)
