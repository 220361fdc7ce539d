"""A torchrun worker for tests/training/train/test_devices.py (not a test module): trains the tiny DFVNet config
in OUT under torchrun; with `die`, rank 1 of the first attempt dies before step 4 (a lost process or node), so
torchrun --max-restarts starts the workers again and they resume from last.pt.

    python -m torch.distributed.run --standalone --nproc_per_node=2 --max-restarts=3 elastic_worker.py OUT [die]
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # tests/: training_fixtures

from training_fixtures import TwoPlaneStacks, train_config  # noqa: E402

from training.train import loop  # noqa: E402
from training.train.config import LossConfig  # noqa: E402


def _die_with_the_agent() -> None:
    """Linux: this worker is killed when torchrun's agent ends (torchrun starts workers in sessions of their own,
    so a test that kills a hung torchrun would otherwise leave them behind)."""
    try:
        ctypes.CDLL("libc.so.6").prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def main() -> None:
    _die_with_the_agent()
    torch.set_num_threads(1)
    out, die = Path(sys.argv[1]), sys.argv[2:] == ["die"]
    attempt = int(os.environ.get("TORCHELASTIC_RESTART_COUNT", "0"))
    if die and attempt == 0 and os.environ["RANK"] == "1":
        real = loop.lr_at

        def lr_then_die(step, *a, **kw):
            if step == 3:
                os._exit(1)  # no clean-up, as a lost machine
            return real(step, *a, **kw)

        loop.lr_at = lr_then_die
    cfg = train_config(net="dfvnet", steps=5, checkpoint_every=2, loss=LossConfig(level_weights=(2.0, 1.0)))
    loop.train(cfg, out, train_set=TwoPlaneStacks(n=8), resume=True, progress=False, device="cpu")


if __name__ == "__main__":
    main()
