"""SIGINT / SIGTERM during a command: `Interrupted`, and the memory of the signal that survives a lost exception.

The commands (aat_deploy.cli.common.run_guarded) raise a signal in the main thread as `Interrupted`, so every
`finally` and atomic writer removes what it had started. CPython runs a Python signal handler wherever the main
thread next checks for signals, and that can be inside a finalizer: an unclosed file's implicit close (its flush
checks for signals), a `__del__` (tqdm bars, image files), a weakref callback. An exception raised there is
discarded (at most "Exception ignored in ..." on stderr) and the run went on as if no signal had come: a scheduler's
SIGTERM finished the run instead of stopping it. So the handler also records the signal (`note`), and the writers of
outputs call `raise_if_interrupted()` before they commit (aat_deploy.io.atomic): after a signal nothing is committed,
the temporaries are deleted and the command exits 128 + the signal at the next commit whatever discarded it.
"""

from __future__ import annotations

import signal

_received: list[int] = []  # the signals of the running command (main thread only: Python runs handlers there)


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM, raised in the main thread so every `finally` and atomic writer removes what it had
    started (aat_deploy.io.atomic)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def note(signum: int) -> None:
    """Remember that `signum` arrived (the signal handler, before it raises)."""
    _received.append(signum)


def received() -> int | None:
    """The first signal that arrived since `clear()`, or None."""
    return _received[0] if _received else None


def clear() -> None:
    """Forget earlier signals (a command starts or ended)."""
    _received.clear()


def raise_if_interrupted() -> None:
    """Raise Interrupted if a signal arrived, also when the exception its handler raised was discarded."""
    if _received:
        raise Interrupted(_received[0])
