"""The one progress reporter of the runtime's commands (aat-infer's decoding and tiles, aat-eval's batch,
aat-diagnose's stages): a tqdm bar on stderr, a line per step where tqdm is missing, nothing when quiet; `say` for a
stage without steps to count. Results go to stdout, progress never does."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator


class Progress:
    """A bar over `total` steps of `unit` (None: opened by the first `to(done, total)`, e.g. a model's tiles).
    leave=False clears it when done (a stage inside a longer run)."""

    def __init__(self, total: int | None = None, desc: str = "", unit: str = "step", quiet: bool = False,
                 leave: bool = True):
        self.total, self.done, self.desc, self.unit, self.quiet, self.leave = total, 0, desc, unit, quiet, leave
        self.bar = None
        if total is not None:
            self._open(total)

    def _open(self, total: int) -> None:
        self.total = total
        if self.quiet:
            return
        try:
            from tqdm import tqdm
        except ImportError:
            return
        self.bar = tqdm(total=total, desc=self.desc, unit=self.unit, file=sys.stderr, dynamic_ncols=True,
                        leave=self.leave)

    def step(self, what: str = "") -> None:
        """One step done; `what` names it (the bar's postfix, or the line without tqdm)."""
        self.done += 1
        if self.bar is not None:
            if what:
                self.bar.set_postfix_str(what[-40:], refresh=False)
            self.bar.update(1)
        elif not self.quiet and what:
            print(f"{self.desc} [{self.done}/{self.total}] {what}", file=sys.stderr, flush=True)

    def to(self, done: int, total: int) -> None:
        """progress(done, total) for callers that count themselves (DfFModel.infer's tiles)."""
        if self.total is None:
            self._open(total)
        if self.bar is not None:
            self.bar.update(done - self.bar.n)
        self.done = done
        if done >= total:
            self.close()

    __call__ = to

    def note(self, line: str) -> None:
        """A line on stderr that does not break the bar."""
        if self.bar is not None:
            self.bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def track(items: Iterable, total: int, desc: str, unit: str = "step", quiet: bool = False,
          leave: bool = False) -> Iterator:
    """The items, with a bar stepping as each is taken."""
    bar = Progress(total, desc, unit, quiet, leave)
    try:
        for item in items:
            yield item
            bar.step()
    finally:
        bar.close()


def say(quiet: bool, msg: str) -> None:
    """A progress line on stderr for a stage without steps to count (one onnxruntime call, writing files)."""
    if not quiet:
        print(f"  {msg}", file=sys.stderr, flush=True)
