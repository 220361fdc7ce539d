"""aat-view in a real browser: Debian's headless Chromium loads the served rerun web viewer and the recording's
entities appear in the viewer's Streams panel.

The viewer is an egui app drawn on a <canvas>, so the page's DOM holds no entity names. rerun's web page keeps its
`WebHandle` as `window._handle`, and `WebHandle.inspect(bytes)` answers egui_inspection requests (MessagePack):
`"GetTree"` returns the AccessKit tree egui builds every frame, the same tree a screen reader reads: every row of
the Streams panel is a button labelled with an entity path part ("world/", "camera/", "depth"), next to a
disclosure triangle. `ApplyEvents` with AccessKit action requests presses those triangles (as a screen reader
user would), so the whole entity tree becomes visible. The test rebuilds entity paths from the rows' indentation
(a row's parent is the nearest row above it that is indented less) and compares them with the entity paths
rerun's RRD reader finds in the same `.rrd`.

A control recording with other entities shows that the check reads what the viewer loaded: its rows appear,
ours do not.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]  # the repository
CHROMIUM = Path("/usr/bin/chromium")  # Debian's chromium package (installed by .ci/run)
# As root in a container: no sandbox; no GPU (WebGL through SwiftShader); no background traffic, which the
# closed network would refuse.
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
LOAD_TIMEOUT_S = 180  # generous: SwiftShader on 2 shared cores draws a frame in 0.3-10 s

pytestmark = pytest.mark.skipif(not CHROMIUM.is_file(),
                                reason=f"{CHROMIUM} not installed (Debian package chromium; .ci/run installs it)")


# ---------------------------------------------------------------------------------------------------- egui tree

def _inspect(page, request):
    """One egui_inspection request through rerun's WebHandle; the decoded MessagePack reply."""
    import msgpack

    reply = page.evaluate("async (b) => Array.from(await window._handle.inspect(new Uint8Array(b)))",
                          list(msgpack.packb(request)))
    return msgpack.unpackb(bytes(reply), raw=False, strict_map_key=False)


def egui_tree(page) -> dict[int, tuple[str, dict]]:
    """The viewer's current AccessKit tree: node id -> (role, properties)."""
    reply = _inspect(page, "GetTree")
    assert "Tree" in reply, reply
    update = reply["Tree"][2]  # Tree {step, pixels_per_point, accesskit: TreeUpdate {nodes, ...}}
    return {} if update is None else {nid: (node[0], node[-1]) for nid, node in update[0]}


def _subtree(nodes, root) -> list[int]:
    out, todo = [], [root]
    while todo:
        n = todo.pop()
        out.append(n)
        todo.extend(c for c in nodes[n][1].get("children", []) if c in nodes)
    return out


def _panel(nodes, label: str) -> list[int]:
    roots = [n for n, (_, p) in nodes.items() if p.get("label") == label]
    return _subtree(nodes, roots[0]) if roots else []


def _press(page, node: int, action: str = "click", data=None) -> None:
    """An AccessKit action on one node, applied by the next egui frame."""
    req = {"action": action, "targetTree": bytes(16), "targetNode": node, "data": data}
    reply = _inspect(page, {"ApplyEvents": {"events": [{"AccessKitActionRequest": req}]}})
    assert not (isinstance(reply, dict) and "Error" in reply), reply


def stream_rows(nodes) -> list[dict]:
    """Entity rows of the Streams panel, top to bottom: {label, x, y, triangle, expanded}. A row is a button
    sharing its container with a disclosure triangle (component rows have none)."""
    parent = {c: n for n, (_, p) in nodes.items() for c in p.get("children", [])}
    rows = []
    for n in _panel(nodes, "_streams_tree"):
        role, p = nodes[n]
        if role != "button" or "bounds" not in p or n not in parent:
            continue
        sib = [c for c in nodes[parent[n]][1].get("children", []) if c in nodes]
        tri = [c for c in sib if nodes[c][0] == "disclosureTriangle"]
        if tri:
            rows.append({"label": p.get("label", ""), "x": p["bounds"][0], "y": p["bounds"][1], "triangle": tri[0],
                         "expanded": bool(nodes[tri[0]][1].get("expanded"))})
    return sorted(rows, key=lambda r: r["y"])


def shown_entity_paths(rows) -> set[str]:
    """Entity paths the Streams panel shows, from the rows' indentation."""
    stack: list[tuple[float, str]] = []  # (x, path) of the rows above that are still open
    paths = set()
    for r in rows:
        while stack and stack[-1][0] >= r["x"]:
            stack.pop()
        name = r["label"].strip("/")
        path = (stack[-1][1] if stack else "") + ("/" + name if name else "")
        if name and not name.startswith("__"):  # "__properties": the recording's properties, not an entity
            paths.add(path)
        stack.append((r["x"], path))
    return paths


def _time_panel_splitter(nodes) -> int | None:
    """The handle between the viewport and the time panel (which holds the Streams tree)."""
    panel = [p["bounds"] for _, p in nodes.values() if p.get("label") == "Time panel" and "bounds" in p]
    for n, (role, p) in nodes.items():
        if role == "splitter" and p.get("orientation") == "horizontal" and panel and "bounds" in p \
                and abs(p["bounds"][1] - panel[0][1]) < 8:
            return n
    return None


def viewer_entities(page, url: str, want: set[str]) -> tuple[set[str], list[str]]:
    """Open `url`; give the time panel most of the window (so every Streams row is laid out), open every entity
    that has children, until the Streams panel shows all of `want`; returns (entity paths shown, view names)."""
    page.goto(url)
    deadline = time.time() + LOAD_TIMEOUT_S
    page.wait_for_function("window._handle !== undefined && typeof window._handle.inspect === 'function'",
                           timeout=LOAD_TIMEOUT_S * 1000)
    shown: set[str] = set()
    nodes: dict = {}
    enlarged = False
    while time.time() < deadline:  # one egui frame per round: frames are slow under SwiftShader
        assert not page.evaluate("window._handle.has_panicked()"), page.evaluate("window._handle.panic_message()")
        nodes = egui_tree(page)
        split = None if enlarged else _time_panel_splitter(nodes)
        if split is not None:
            _press(page, split, "setValue", {"numericValue": float(nodes[split][1].get("maxNumericValue", 0.8))})
            enlarged = True
            continue
        rows = stream_rows(nodes)
        closed = [r for r in rows if r["label"].endswith("/") and not r["expanded"]]
        for r in closed:
            _press(page, r["triangle"])
        shown = shown_entity_paths(rows)
        if not closed and shown and want <= shown:
            break
        time.sleep(0.5)
    views = [nodes[n][1].get("label") or "" for n in _panel(nodes, "Viewport") if nodes[n][0] == "pane"]
    return shown, views


# ------------------------------------------------------------------------------------------------- fixtures

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Served:
    """`aat-view RECORDING.rrd` running on free ports; `url` is the one it printed."""

    def __init__(self, rrd: Path):
        web, grpc = _free_port(), _free_port()
        self.proc = subprocess.Popen([sys.executable, "-m", "aat_deploy.cli.view", str(rrd), "--port", str(web),
                                      "--grpc-port", str(grpc)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, cwd=ROOT, start_new_session=True)
        line = self.proc.stdout.readline()
        self.url = next((w for w in line.split() if w.startswith("http://127.0.0.1:")), None)
        assert self.url, f"aat-view printed no URL: {line!r}"
        deadline = time.time() + 60  # the URL is printed before rerun listens
        while True:
            try:
                urllib.request.urlopen(self.url, timeout=5).close()
                break
            except OSError:
                assert self.proc.poll() is None and time.time() < deadline, "aat-view's server did not come up"
                time.sleep(0.3)

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGTERM)  # aat-view stops its rerun child on SIGTERM
            self.proc.wait(timeout=30)


def rrd_entity_paths(rrd: Path) -> set[str]:
    """Entity paths in the recording, read back with rerun's RRD reader (recording properties left out)."""
    from rerun.chunk import RrdReader

    chunks = RrdReader(rrd).stream().collect().stream()
    return {str(c.entity_path) for c in chunks if not str(c.entity_path).startswith("/__")}


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """The runtime's recording of a small DNG capture (48x64, 3 frames; the 480x640 sample's 26 MB recording
    takes minutes to draw with SwiftShader on a busy 2-core machine)."""
    from deploy_fixtures import tiny_model_path, write_dng_capture

    from aat_deploy.infer.model import DfFModel
    from aat_deploy.infer.pipeline import Options, run_capture

    tmp = tmp_path_factory.mktemp("browser")
    cap = write_dng_capture(tmp / "cap", [0.7, 1.2, 2.5])
    run_capture(cap, DfFModel(tiny_model_path(tmp_path_factory), threads=1), tmp / "out", Options(quiet=True))
    return tmp / "out" / "recording.rrd"


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw, tempfile.TemporaryDirectory() as profile:
        ctx = pw.chromium.launch_persistent_context(profile, executable_path=str(CHROMIUM), headless=True,
                                                    args=CHROMIUM_ARGS, viewport={"width": 1280, "height": 800})
        try:
            yield ctx
        finally:
            ctx.close()


def _look(browser, rrd: Path, want: set[str]) -> tuple[set[str], list[str]]:
    served = Served(rrd)
    page = browser.new_page()
    try:
        return viewer_entities(page, served.url, want)
    finally:
        page.close()
        served.stop()


# ---------------------------------------------------------------------------------------------------- tests

def test_viewer_shows_the_recordings_entities(browser, recording):
    expected = rrd_entity_paths(recording)
    ours = {"/world/camera", "/world/camera/frames", "/world/camera/depth", "/world/camera/aif",
            "/world/camera/std_m", "/world/camera/gt_depth", "/world/points", "/focus_m"}
    assert ours <= expected, f"the recording lacks {sorted(ours - expected)}"
    shown, views = _look(browser, recording, expected)
    assert expected <= shown, f"not shown in the viewer: {sorted(expected - shown)}; shown: {sorted(shown)}"
    assert shown <= expected | {"/world"}, f"shown but not in the recording: {sorted(shown - expected)}"
    # the viewer opened on the recording's own layout (aat_deploy.infer.recording.blueprint): its views by name
    layout = {"focal stack", "depth (m from sensor)", "all-in-focus", "3-D points", "uncertainty (m)",
              "ground truth depth", "focus distance (m)"}
    assert layout <= set(views), f"the recording's blueprint is not the viewer's layout: {views}"


def test_viewer_check_sees_another_recording(browser, tmp_path):
    """Control: a recording with other entities shows those, and none of ours."""
    import numpy as np
    import rerun as rr

    rrd = tmp_path / "other.rrd"
    rec = rr.RecordingStream(application_id="aat-control", recording_id="control")
    rec.save(str(rrd))
    rec.log("elsewhere/thing", rr.Points3D(np.zeros((3, 3), np.float32)), static=True)
    rec.flush()
    rec.disconnect()
    assert rrd_entity_paths(rrd) == {"/elsewhere/thing"}
    shown, _ = _look(browser, rrd, {"/elsewhere/thing"})
    assert shown == {"/elsewhere", "/elsewhere/thing"}, shown
