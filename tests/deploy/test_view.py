"""aat-view serves rerun's web viewer on 127.0.0.1 only and prints the URL; aat-capture inspect output."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from deploy_fixtures import tiny_model_path, write_dng_capture

from aat_deploy.cli import capture as capture_cli
from aat_deploy.cli import view as view_cli
from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.pipeline import Options, run_capture


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _listening(port: int) -> list[str]:
    """Local addresses listening on `port` (from /proc/net/tcp*)."""
    out = []
    for name in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(name) as f:
                lines = f.read().splitlines()[1:]
        except OSError:
            continue
        for ln in lines:
            parts = ln.split()
            addr, st = parts[1], parts[3]
            ip, p = addr.rsplit(":", 1)
            if st == "0A" and int(p, 16) == port:
                out.append(ip)
    return out


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("view")
    cap = write_dng_capture(tmp / "cap", [0.7, 1.2, 2.5])
    run_capture(cap, DfFModel(tiny_model_path(tmp_path_factory), threads=1), tmp / "out", Options(quiet=True))
    return tmp / "out" / "recording.rrd"


def test_serve_binds_localhost_only(recording):
    web, grpc = _free_port(), _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "aat_deploy.cli.view", str(recording), "--port", str(web),
                             "--grpc-port", str(grpc)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        line = proc.stdout.readline()
        assert f"http://127.0.0.1:{web}/" in line and f"127.0.0.1%3A{grpc}" in line
        # the URL is printed only once the page loads: no polling between the line and the first request
        with socket.create_connection(("127.0.0.1", web), timeout=2):
            pass
        deadline = time.time() + 60
        while time.time() < deadline and not (_listening(web) and _listening(grpc)):
            time.sleep(0.3)
        loopback = {"0100007F", "00000000000000000000000001000000"}
        assert _listening(web) and set(_listening(web)) <= loopback, _listening(web)
        assert _listening(grpc) and set(_listening(grpc)) <= loopback, _listening(grpc)
        page = urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=20).read().decode(errors="replace")
        assert "<html" in page.lower()
    finally:
        os.kill(proc.pid, signal.SIGTERM)  # aat-view stops its rerun child on SIGTERM
        proc.wait(timeout=20)
    deadline = time.time() + 10
    while time.time() < deadline and (_listening(web) or _listening(grpc)):
        time.sleep(0.2)
    assert not _listening(web) and not _listening(grpc), "viewer still running after aat-view stopped"


def test_view_rejects_non_recording(tmp_path, capsys):
    bad = tmp_path / "x.rrd"
    bad.write_bytes(b"hello")
    assert view_cli.main([str(bad)]) == 1
    assert "not a rerun recording" in capsys.readouterr().err
    assert view_cli.main([str(tmp_path / "missing.rrd")]) == 1


def test_view_refuses_a_busy_port(recording, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert view_cli.main([str(recording), "--port", str(port), "--grpc-port", str(_free_port())]) == 1
    err = capsys.readouterr()
    assert f"127.0.0.1:{port} is already in use" in err.err and "serving" not in err.out


def test_wait_listening_gives_up_when_the_server_dies():
    proc = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    assert not view_cli.wait_listening(proc, _free_port(), timeout_s=20)
    assert proc.returncode == 3


def test_serve_command_binds_loopback(tmp_path):
    cmd = view_cli.serve_command(tmp_path / "r.rrd", 9090, 9876)
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1"


def test_inspect_json_and_text(recording, capsys):
    cap = recording.parent.parent / "cap"
    assert capture_cli.main(["inspect", str(cap), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["focus_m"] for r in rows] == pytest.approx([0.7, 1.2, 2.5])
    for r in rows:
        assert {"file", "focus_m", "focus_source", "make", "model", "lens"} <= set(r)
        assert (r["make"], r["model"], r["focus_source"]) == ("aat", "virtual camera", "EXIF SubjectDistance")
        assert (r["width"], r["height"]) == (64, 48)
    assert capture_cli.main(["inspect", str(cap / "frame_00.dng")]) == 0
    text = capsys.readouterr().out
    assert re.search(r"focus 0\.7 m\s+from EXIF SubjectDistance", text)
    assert capture_cli.main(["inspect", str(cap / "nope.dng")]) == 1
    err = capsys.readouterr().err
    assert "nope.dng" in err and "Traceback" not in err


def _vulkan_cpu_driver() -> bool:
    """Mesa's lavapipe (Debian mesa-vulkan-drivers, installed by .ci/run): Vulkan without a GPU."""
    # a glob is a generator, always truthy: ask whether it yields a file
    return any(next(Path(d).glob("lvp_icd*.json"), None) is not None
               for d in ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d"))


def test_screenshot_writes_a_picture(recording, tmp_path, capsys):
    """With a Vulkan driver (Mesa's lavapipe draws on the CPU) the headless viewer writes a PNG of the viewer."""
    import cv2

    if not _vulkan_cpu_driver():
        pytest.skip("no Vulkan driver: Debian packages mesa-vulkan-drivers and libvulkan1 (.ci/run installs them)")
    out = tmp_path / "view.png"
    assert view_cli.main([str(recording), "--screenshot", str(out)]) == 0, capsys.readouterr().err
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = cv2.imread(str(out))
    assert img.shape[0] >= 400 and img.shape[1] >= 600 and img.std() > 5  # a drawn viewer, not a blank


def test_screenshot_without_vulkan_is_one_clear_line(recording, tmp_path, capsys, monkeypatch):
    """Without a Vulkan driver aat-view says so on one line and writes nothing. The Vulkan loader is pointed at a
    driver list that does not exist, so this runs whether or not a driver is installed."""
    for var in ("VK_ICD_FILENAMES", "VK_DRIVER_FILES"):  # the loader's old and new names for it
        monkeypatch.setenv(var, str(tmp_path / "no_driver.json"))
    out = tmp_path / "view.png"
    assert view_cli.main([str(recording), "--screenshot", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "screenshot failed" in err and "Vulkan" in err
    assert not out.exists()
