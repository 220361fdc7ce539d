"""What every aat command shares: `--version`, `-q/--quiet`, one exit status convention stated in `--help`, and a
one-line message instead of a traceback when a command needs the `train` extra (torch) that is not installed."""

from __future__ import annotations

import argparse
import signal
import sys

from .. import DISTRIBUTION, __version__, interrupt
from ..interrupt import Interrupted  # noqa: F401 (where the commands' callers have found it)

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
EXIT_STATUS = ("exit status: 0 all done; 1 some capture or file failed (one line each, the others still ran); "
               "2 usage error or nothing could be run; 130 interrupted (Ctrl-C), 143 terminated (SIGTERM)")


def run_guarded(prog: str, main, argv) -> int:
    """main(argv) with SIGINT and SIGTERM raised as Interrupted, so an interrupted run leaves no temporary folder
    behind; the interruption is one line and the exit status 128 + the signal (130 Ctrl-C, 143 SIGTERM), never a
    traceback, also during start-up (commands import their heavy modules inside main for that). The signal is also
    remembered (aat_deploy.interrupt): when a finalizer discards the exception (CPython's "Exception ignored in"),
    the run still stops at its next commit of an output instead of finishing as if no signal had come."""

    def handler(signum, frame):
        interrupt.note(signum)
        raise Interrupted(signum)

    def unraisable(u):  # an Interrupted discarded by a finalizer: remembered above, not a traceback
        if not isinstance(u.exc_value, Interrupted):
            old_hook(u)

    old, old_hook = {}, sys.unraisablehook
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, handler)
    except ValueError:  # not the main thread (a library caller): its own signal handling stays
        pass
    if old:
        interrupt.clear()
        sys.unraisablehook = unraisable
    try:
        return main(argv)
    except KeyboardInterrupt:
        sig = interrupt.received() or signal.SIGINT
        what = "interrupted" if sig == signal.SIGINT else "terminated"
        print(f"{prog}: {what} ({signal.Signals(sig).name})", file=sys.stderr, flush=True)
        return 128 + int(sig)
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
        if old:
            sys.unraisablehook = old_hook
            interrupt.clear()


def version_text(prog: str) -> str:
    return f"{prog} {__version__} ({DISTRIBUTION})"


def parser(prog: str, description: str, *, quiet: bool = True, **kw) -> argparse.ArgumentParser:
    """An ArgumentParser with --version, -q/--quiet (unless quiet=False: commands with subcommands give it to each
    subcommand, see add_quiet) and the exit status as its epilog."""
    ap = argparse.ArgumentParser(prog=prog, description=description, epilog=EXIT_STATUS, **kw)
    ap.add_argument("--version", action="version", version=version_text(prog))
    if quiet:
        add_quiet(ap)
    return ap


def add_quiet(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress output: results, warnings and errors only")


def subparser(sub, name: str, help: str, **kw) -> argparse.ArgumentParser:
    """A subcommand parser with -q/--quiet and the exit status epilog."""
    p = sub.add_parser(name, help=help, description=help, epilog=EXIT_STATUS, **kw)
    add_quiet(p)
    return p


def add_reader_options(ap: argparse.ArgumentParser) -> None:
    """The options of commands that read capture folders: the pixel limit and following links out of a folder."""
    from ..capture.imagefile import DEFAULT_MAX_MEGAPIXELS, ENV_MAX_MEGAPIXELS
    from ..io.files import OUTSIDE_LINKS_FLAG

    ap.add_argument("--max-megapixels", type=float, default=None, metavar="MP",
                    help="refuse frames whose header claims more pixels than this, before decoding (default "
                         f"${ENV_MAX_MEGAPIXELS} or {DEFAULT_MAX_MEGAPIXELS:g}: a damaged or hostile header can claim "
                         "gigapixels)")
    ap.add_argument(OUTSIDE_LINKS_FLAG, action="store_true",
                    help="follow symlinks that lead out of a capture folder (refused by default)")


def check_reader_options(ap: argparse.ArgumentParser, args) -> None:
    """ap.error for a --max-megapixels that is not a positive number."""
    import math

    if args.max_megapixels is not None and not (args.max_megapixels > 0 and math.isfinite(args.max_megapixels)):
        ap.error("--max-megapixels must be a positive number")


def threads_option(prog: str, ap: argparse.ArgumentParser, threads: int | None) -> int | None:
    """--threads checked (>= 1) and bounded to the machine's cores, saying so when it is lowered."""
    from ..machine import machine_cores

    if threads is None:
        return None
    if threads < 1:
        ap.error("--threads must be >= 1")
    cores = machine_cores()
    if threads > cores:
        print(f"{prog}: note: --threads {threads}: this machine has {cores} core(s); using {cores}", file=sys.stderr)
        return cores
    return threads


def install_hint(extra: str = "train") -> str:
    return f'pip install "{DISTRIBUTION}[{extra}]"'


class _ListAction(argparse.Action):
    """An option like --version: prints a list and exits 0 before the required arguments are checked."""

    def __init__(self, option_strings, dest, lister=None, help=None):
        super().__init__(option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, nargs=0, help=help)
        self.lister = lister

    def __call__(self, parser, namespace, values, option_string=None):
        self.lister()
        parser.exit(EXIT_OK)


def add_list_option(ap: argparse.ArgumentParser, flag: str, lister, help: str) -> None:
    """`flag` prints with lister() and exits, so positionals and options the command needs stay required."""
    ap.add_argument(flag, action=_ListAction, lister=lister, help=help)


def print_effects() -> None:
    """The simulator's registered effects, one line each (aat-render and aat-diagnose --list-effects)."""
    from aat_deploy.render import effects as fx

    for name, desc in fx.describe().items():
        print(f"{name:16s} {desc}")


TRAIN_MODULES = {"torch", "onnx", "onnxscript", "skimage", "PIL"}  # what the train extra brings


def run_or_hint(prog: str, main, argv) -> int:
    """main(argv), but a missing train-extra module is one line saying how to install it (exit 2), not a
    traceback."""
    try:
        return main(argv)
    except ModuleNotFoundError as e:
        root = (e.name or "").split(".")[0]
        if root not in TRAIN_MODULES:
            raise
        import sys

        print(f"{prog}: needs the train extra ({root} is not installed): {install_hint()}  "
              "(CPU-only torch: README, Install)", file=sys.stderr)
        return EXIT_USAGE
