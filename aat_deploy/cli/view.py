"""aat-view: look at a recording.rrd in rerun's web viewer, served on this machine only (127.0.0.1).

    aat-view RECORDING.rrd [--port 9090] [--grpc-port 9876]      # serve, print the URL, Ctrl-C to stop
    aat-view RECORDING.rrd --screenshot out.png                   # render a picture headless (needs Vulkan)

rerun binds all interfaces by default; aat-view always passes --bind 127.0.0.1.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .common import parser

HOST = "127.0.0.1"


def rerun_command() -> list[str]:
    """The rerun CLI shipped with rerun-sdk, run through this Python (no PATH shims)."""
    return [sys.executable, "-m", "rerun"]


def viewer_url(web_port: int, grpc_port: int) -> str:
    return f"http://{HOST}:{web_port}/?url=rerun%2Bhttp%3A%2F%2F{HOST}%3A{grpc_port}%2Fproxy"


def serve_command(rrd: Path, web_port: int, grpc_port: int) -> list[str]:
    return [*rerun_command(), "--serve-web", str(rrd), "--bind", HOST, "--web-viewer-port", str(web_port),
            "--port", str(grpc_port)]


def _check_rrd(path: Path) -> str | None:
    """Why `path` cannot be served, or None: it must be a file rerun reads whole (magic bytes, then every chunk:
    a file with the right magic and garbage after it was served before, to a blank viewer)."""
    import warnings

    from ..io.files import file_kind

    kind = file_kind(path)
    if kind is not None:
        return f"{path}: no such file" if kind == "missing" else f"{path}: is {kind}, expected a recording (.rrd)"
    with open(path, "rb") as f:
        if f.read(4) not in (b"RRF2", b"RRF0", b"RRF1"):
            return f"{path}: not a rerun recording (.rrd)"
    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a file without its footer: rerun warns, then reads it whole
            reader = RrdReader(path)
            if not reader.recordings():
                return f"{path}: a rerun file without a recording"
            for _ in reader.stream():
                pass
    except Exception as e:  # noqa: BLE001 (rerun's reader raises RuntimeError/ValueError from Rust)
        why = str(e).splitlines()[0][:160] if str(e) else type(e).__name__
        return f"{path}: not a readable rerun recording ({why})"
    return None


def port_in_use(port: int, host: str = HOST) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex((host, port)) == 0


def wait_listening(proc: subprocess.Popen, port: int, timeout_s: float = 60.0, host: str = HOST) -> bool:
    """True once something accepts connections on host:port; False if `proc` exits or time runs out first
    (the URL is printed only when the page can load)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if proc.poll() is not None:
            return False
        if port_in_use(port, host):
            return True
        time.sleep(0.2)
    return False


def _stop(proc: subprocess.Popen) -> None:
    """Stop the viewer and what it spawned (its own process group)."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=5)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def screenshot(rrd: Path, out: Path, window: str = "1280x800", timeout_s: float = 120) -> str | None:
    """Render `rrd` headless to `out`; returns an error message or None."""
    env = dict(os.environ, WGPU_BACKEND=os.environ.get("WGPU_BACKEND", "vulkan"))
    with tempfile.TemporaryDirectory() as tmp:
        shot = Path(tmp) / "shot.png"
        cmd = [*rerun_command(), str(rrd), "--headless", "--screenshot-to", str(shot), "--window-size", window,
               "--port", "0"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        try:
            log, _ = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            _stop(proc)
            return f"{rrd}: the headless viewer did not finish within {timeout_s:.0f} s"
        if proc.returncode != 0 or not shot.is_file():
            last = [ln for ln in log.decode(errors="replace").splitlines() if ln.strip()][-1:] or ["no output"]
            return (f"{rrd}: headless screenshot failed (needs a Vulkan driver, e.g. Debian mesa-vulkan-drivers): "
                    f"{last[0][:200]}")
        out.write_bytes(shot.read_bytes())
    return None


def main(argv: list[str] | None = None) -> int:
    ap = parser("aat-view", __doc__.split("\n")[0])
    ap.add_argument("recording", type=Path, metavar="RECORDING.rrd")
    ap.add_argument("--port", type=int, default=9090, help="web viewer port (default 9090)")
    ap.add_argument("--grpc-port", type=int, default=9876, help="data (gRPC) port the page connects to")
    ap.add_argument("--screenshot", type=Path, metavar="OUT.png", help="render a picture headless and exit")
    args = ap.parse_args(argv)
    for flag, port in (("--port", args.port), ("--grpc-port", args.grpc_port)):
        if not 1 <= port <= 65535:
            print(f"aat-view: error: {flag} {port} is not a TCP port (1..65535)", file=sys.stderr)
            return 2
    err = _check_rrd(args.recording)
    if err:
        print(f"aat-view: error: {err}", file=sys.stderr)
        return 1
    if args.screenshot:
        err = screenshot(args.recording, args.screenshot)
        if err:
            print(f"aat-view: error: {err}", file=sys.stderr)
            return 1
        print(args.screenshot)
        return 0
    def _interrupt(*_):
        raise KeyboardInterrupt

    for port in (args.port, args.grpc_port):
        if port_in_use(port):  # else rerun's own error arrives after a URL that shows someone else's page
            print(f"aat-view: error: {HOST}:{port} is already in use; pick another with --port/--grpc-port",
                  file=sys.stderr)
            return 1
    signal.signal(signal.SIGTERM, _interrupt)  # a terminated aat-view stops its viewer too
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(serve_command(args.recording, args.port, args.grpc_port), stdout=subprocess.DEVNULL,
                                stderr=log, start_new_session=True)
        stopped = False
        try:
            if wait_listening(proc, args.port):
                print(f"serving {args.recording} at {viewer_url(args.port, args.grpc_port)}  (Ctrl-C to stop)",
                      flush=True)
            elif proc.poll() is None:
                print(f"aat-view: error: the viewer did not open {HOST}:{args.port} within 60 s", file=sys.stderr)
                return 1
            proc.wait()
        except KeyboardInterrupt:
            stopped = True
        finally:
            _stop(proc)
        if not stopped and proc.returncode != 0:
            log.seek(0)
            tail = [ln for ln in log.read().decode(errors="replace").splitlines() if ln.strip()][-1:] or [""]
            print(f"aat-view: error: rerun exited with {proc.returncode}: {tail[0][:200]}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
