"""Bad input never loses a user's files and never stops a batch (issue 18).

The matrix: each case runs a command on a bad input next to a good capture and checks the exit code, exactly one
error line naming the file, that the batch went on, and that the inputs and earlier outputs are byte-identical
afterwards (the trees are hashed before and after). Then property-based tests (hypothesis) for the readers users
feed: mutated DNG/TIFF headers, capture.json, gt.json and maker-note blocks, where any exception other than the
project's own error types is a bug. `tests/fuzz_readers.py` runs the long sweep (BENCHMARKS.md).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import LENSES, SHARED
from deploy_fixtures import (
    ENTRY_KINDS,
    GOOD_KINDS,
    SIDECAR_KINDS,
    SKIPPED_UNLISTED,
    canon_jpeg,
    claim_size,
    fuzz_seeds,
    random_capture,
    tree_hash,
    write_dng_capture,
    write_jpeg_capture,
    write_png_capture,
)
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from aat_deploy.capture import exiftool
from aat_deploy.capture.exif import read_metadata
from aat_deploy.capture.folder import read_capture
from aat_deploy.cli import eval as eval_cli
from aat_deploy.cli import infer as infer_cli
from aat_deploy.cli import view as view_cli
from aat_deploy.errors import CaptureError
from aat_deploy.gt.read import find_gt, load_ground_truth
from aat_deploy.infer.model import DfFModel
from aat_deploy.io import marker

FOCUS = [0.6, 1.0, 2.0]
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


# -- helpers ---------------------------------------------------------------------------------------------------
def infer(args, capsys) -> tuple[int, list[str], str]:
    """aat-infer in this process: (exit code, stderr lines that report a failure or error, stdout)."""
    rc = infer_cli.main([str(a) for a in args] + ["--threads", "1", "-q", "--no-recording"])
    cap = capsys.readouterr()
    bad = [ln for ln in cap.err.splitlines() if any(w in ln for w in ("FAILED", "error", "failed"))]
    assert "Traceback" not in cap.err
    return rc, bad, cap.out


@pytest.fixture
def good(tmp_path):
    """A good capture (batch partner) and an earlier output that must survive every case untouched."""
    cap = write_dng_capture(tmp_path / "good", FOCUS)
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / "summary.json").write_text('{"earlier": true}')
    marker.write(earlier, "aat-infer", complete=True)  # as a finished aat-infer run leaves it
    return cap, earlier


def with_meta(src: Path, dst: Path, **over) -> Path:
    """A copy of an ONNX model with some aat.* metadata replaced (values JSON-encoded unless str)."""
    import onnx

    m = onnx.load(str(src))
    props = {p.key: p.value for p in m.metadata_props}
    props.update({k.replace("__", "."): v if isinstance(v, str) else json.dumps(v) for k, v in over.items()})
    del m.metadata_props[:]
    for k, v in props.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    onnx.save(m, str(dst))
    return dst


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# -- 1, 3: output folders that are, contain or lie inside an input, or the current folder -----------------------
@pytest.mark.parametrize("case", ["is_capture", "contains_capture", "inside_capture", "symlink_to_capture",
                                  "contains_model", "cwd"])
def test_output_overlapping_an_input_is_refused_before_any_work(case, model_path, good, tmp_path, capsys,
                                                                 monkeypatch):
    cap, earlier = good
    bad = write_dng_capture(tmp_path / "parent" / "cap", FOCUS)
    model = model_path
    force = ["--force"]
    if case == "is_capture":
        out = bad
    elif case == "contains_capture":
        out = tmp_path / "parent"
    elif case == "inside_capture":
        out, force = bad / "results", []
    elif case == "symlink_to_capture":
        out = tmp_path / "link"
        out.symlink_to(bad, target_is_directory=True)
    elif case == "contains_model":
        model = shutil.copy(model_path, tmp_path / "parent" / "m.onnx")
        out = tmp_path / "parent"
    else:  # --out . from inside an earlier output (EBUSY traceback before)
        out = Path(".")
        monkeypatch.chdir(earlier)
    before = tree_hash(tmp_path / "parent", cap, earlier)
    calls = []
    import aat_deploy.infer.frames as frames_mod  # the one frame reader

    real = frames_mod.load_frame
    monkeypatch.setattr(frames_mod, "load_frame", lambda p: calls.append(Path(p)) or real(p))
    rc, bad_lines, _ = infer([bad, "--model", model, "--out", out, *force], capsys)
    assert rc == 1
    assert len(bad_lines) == 2 and "1 of 1" in bad_lines[1]  # one line for the capture, then the count
    assert str(out) in bad_lines[0] and any(w in bad_lines[0] for w in ("input", "current folder"))
    assert not calls  # refused before decoding anything
    assert tree_hash(tmp_path / "parent", cap, earlier) == before


def test_eval_and_diagnose_refuse_an_output_over_their_inputs(model_path, good, tmp_path, capsys):
    cap, earlier = good
    root = tmp_path / "root"
    shutil.copytree(cap, root / "a")
    before = tree_hash(root, cap, earlier)
    for out in (root, root / "a", root / "a" / "eval"):
        rc = eval_cli.main([str(root), "--model", str(model_path), "--out", str(out), "--force", "-q"])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and str(out) in err[0], err
    from aat_deploy.cli import diagnose as diagnose_cli

    rc = diagnose_cli.main([str(root), "--model", str(model_path), "--out", str(root), "--force", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "contains the input" not in err[0] and "is the input" in err[0], err
    assert tree_hash(root, cap, earlier) == before


def test_render_gt_and_train_refuse_outputs_over_inputs(tmp_path, capsys):
    from aat_deploy.cli import gt as gt_cli
    from training.cli import render as render_cli
    from training.cli import train as train_cli

    scene = tmp_path / "scene"
    scene.mkdir()
    import cv2

    cv2.imwrite(str(scene / "rgb.png"), np.full((24, 36, 3), 128, np.uint8))
    np.save(scene / "depth.npy", np.full((24, 36), 2.0, np.float32))
    lens = LENSES / "canon_rf50mm_f1.8.json"
    before = tree_hash(scene)
    with pytest.raises(SystemExit, match=r"aat-render: error: .*scene: (contains|is) the input"):
        render_cli.main([str(scene / "rgb.png"), str(scene / "depth.npy"), "--lens", str(lens), "--focus-m", "1",
                         "--out", str(scene), "--force"])
    # aat-gt render: the pose file named like the JSON it writes beside gt_depth_mm.png
    (scene / "gt_depth_m.json").write_text(json.dumps({"R": np.eye(3).tolist(), "t": [0, 0, 0]}))
    (scene / "mesh.ply").write_text("ply\nformat ascii 1.0\nend_header\n")
    before = tree_hash(scene)
    rc = gt_cli.main(["render", str(scene / "mesh.ply"), "--pose", str(scene / "gt_depth_m.json"), "--lens",
                      str(lens), "--out", str(scene / "gt_depth_mm.png"), "--force", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "gt_depth_m.json: is the input" in err[0], err
    # aat-train: a run folder holding its own --init/--psf/--lens would overwrite it
    rc = train_cli.main(["--lens", str(scene / "lens.json"), "--out", str(scene)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "contains the input" in err[0], err
    assert tree_hash(scene) == before


def test_force_replaces_only_an_earlier_output(model_path, good, tmp_path, capsys):
    cap, earlier = good
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    before = tree_hash(mine, cap)
    rc, bad, _ = infer([cap, "--model", model_path, "--out", mine, "--force"], capsys)
    assert rc == 1 and len(bad) == 2 and "not an earlier aat-infer output" in bad[0]
    assert tree_hash(mine, cap) == before
    rc, bad, _ = infer([cap, "--model", model_path, "--out", earlier, "--force"], capsys)
    assert rc == 0 and not bad and json.loads((earlier / "summary.json").read_text())["capture"] == str(cap)


# -- issue 31, 1: --force deleted any folder holding a file named like a tool's marker ---------------------------
def _users_folder(d: Path, name: str) -> Path:
    """The issue's case: a folder with a file named like an output (summary.json ...), the user's thesis and a
    subfolder of work."""
    d.mkdir()
    (d / name).write_text("{}")
    (d / "thesis.txt").write_text("x")
    (d / "chapters").mkdir()
    (d / "chapters" / "one.tex").write_text("years of work")
    return d


def test_force_never_replaces_a_folder_that_merely_holds_an_output_name(model_path, good, tmp_path, capsys):
    """Before: aat-infer/aat-eval/aat-diagnose --force and DepthResult.save(force=True) deleted such a folder
    whole (its summary.json/metrics.json/diagnosis.json was taken as proof that it was theirs)."""
    from aat_deploy.api import depth_from_focus
    from aat_deploy.cli import diagnose as diagnose_cli

    cap, earlier = good
    folders = {k: _users_folder(tmp_path / k, n) for k, n in (("infer", "summary.json"), ("eval", "metrics.json"),
                                                              ("diagnose", "diagnosis.json"), ("api", "summary.json"))}
    before = tree_hash(*folders.values(), cap)
    rc, bad, _ = infer([cap, "--model", model_path, "--out", folders["infer"], "--force"], capsys)
    assert rc == 1 and len(bad) == 2 and "is not an earlier aat-infer output (no .aat-output.json;" in bad[0], bad
    rc = eval_cli.main([str(cap), "--model", str(model_path), "--out", str(folders["eval"]), "--force", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "not an earlier aat-eval output" in err[0], err
    rc = diagnose_cli.main([str(cap), "--model", str(model_path), "--out", str(folders["diagnose"]), "--force",
                            "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "not an earlier aat-diagnose output" in err[0], err
    from deploy_fixtures import render_stack, synthetic_scene

    tex, depth = synthetic_scene()
    res = depth_from_focus(render_stack(tex, depth, FOCUS), FOCUS, DfFModel(model_path, threads=1))
    with pytest.raises(ValueError, match="not an earlier aat-infer output"):
        res.save(folders["api"], force=True)
    assert tree_hash(*folders.values(), cap) == before


def test_force_replaces_an_earlier_output_only_while_it_holds_nothing_else(model_path, good, tmp_path, capsys):
    """An earlier output's marker lists what its run wrote: a file added or changed since keeps the folder, an
    output of another tool is refused, and the check is repeated when the old folder is swapped out (a file added
    while the run worked is not lost)."""
    from aat_deploy.errors import OutputError
    from aat_deploy.io.atomic import atomic_folder

    cap, earlier = good
    out = tmp_path / "o"
    assert infer([cap, "--model", model_path, "--out", out], capsys)[0] == 0
    assert infer([cap, "--model", model_path, "--out", out, "--force"], capsys)[0] == 0  # its own: replaced
    (out / "notes").mkdir()
    (out / "notes" / "n.txt").write_text("mine")
    rc, bad, _ = infer([cap, "--model", model_path, "--out", out, "--force"], capsys)
    assert rc == 1 and "holds 'notes' and 1 more, which aat-infer did not write" in bad[0], bad
    shutil.rmtree(out / "notes")
    (out / "camera.json").write_text('{"edited": "by the user"}')
    rc, bad, _ = infer([cap, "--model", model_path, "--out", out, "--force"], capsys)
    assert rc == 1 and "'camera.json' changed since aat-infer wrote it" in bad[0], bad
    assert json.loads((out / "camera.json").read_text()) == {"edited": "by the user"}
    rc = eval_cli.main([str(cap), "--model", str(model_path), "--out", str(earlier), "--force", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and "is an output of aat-infer, not of aat-eval" in err[0], err
    # a file added to the old output while this run worked: found when it is swapped out, the old folder put back
    late = tmp_path / "late"
    with atomic_folder(late, False, "aat-infer") as tmp:
        (tmp / "a.npy").write_bytes(b"1")
    with pytest.raises(OutputError, match="holds 'added.txt', which aat-infer did not write"):
        with atomic_folder(late, True, "aat-infer") as tmp:
            (tmp / "a.npy").write_bytes(b"2")
            (late / "added.txt").write_text("written meanwhile")
    assert (late / "added.txt").read_text() == "written meanwhile" and (late / "a.npy").read_bytes() == b"1"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".late.")]


def test_an_output_from_before_the_marker_is_refused_in_one_line_saying_what_to_do(model_path, good, tmp_path,
                                                                                  capsys):
    """Issue 31 leftover: outputs written before the marker existed have none, so --force refuses them. The refusal
    is one line that names the folder, says why (no marker; outputs before 2026-11-25 have none) and what to do;
    nothing is deleted, by the command, the Python API, or the re-check when the folder is swapped out."""
    from aat_deploy.api import depth_from_focus
    from aat_deploy.errors import OutputError
    from aat_deploy.io.atomic import atomic_folder

    cap, earlier = good
    old = {}
    for tool in ("infer", "eval"):  # an output as such a version left it: everything but the marker
        old[tool] = tmp_path / f"old_{tool}"
        if tool == "infer":
            assert infer([cap, "--model", model_path, "--out", old[tool]], capsys)[0] == 0
        else:
            assert eval_cli.main([str(cap), "--model", str(model_path), "--out", str(old[tool]), "-q"]) == 0
            capsys.readouterr()
        (old[tool] / marker.MARKER).unlink()
    before = tree_hash(*old.values(), cap)

    def said(line: str, folder: Path, tool: str) -> bool:
        return line.count(str(folder)) == 1 and "\n" not in line and all(s in line for s in (
            f"{folder}: is not an earlier {tool} output (no .aat-output.json; outputs written before 2026-11-25 "
            "have none)", "nothing was deleted: choose another output folder, or rename this one and run again"))

    rc, bad, _ = infer([cap, "--model", model_path, "--out", old["infer"], "--force"], capsys)
    assert rc == 1 and said(bad[0], old["infer"], "aat-infer"), bad
    rc = eval_cli.main([str(cap), "--model", str(model_path), "--out", str(old["eval"]), "--force", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and said(err[0], old["eval"], "aat-eval"), err
    from deploy_fixtures import render_stack, synthetic_scene

    tex, depth = synthetic_scene()
    res = depth_from_focus(render_stack(tex, depth, FOCUS), FOCUS, DfFModel(model_path, threads=1))
    with pytest.raises(ValueError) as e:
        res.save(old["infer"], force=True)
    assert said(str(e.value), old["infer"], "aat-infer"), e.value
    with pytest.raises(OutputError) as e:  # the re-check at the swap: the marker gone while this run worked
        with atomic_folder(tmp_path / "late", False, "aat-infer") as tmp:
            (tmp / "summary.json").write_text("{}")
        with atomic_folder(tmp_path / "late", True, "aat-infer") as tmp:
            (tmp_path / "late" / marker.MARKER).unlink()
    assert said(str(e.value), tmp_path / "late", "aat-infer") and (tmp_path / "late" / "summary.json").exists()
    assert tree_hash(*old.values(), cap) == before


# -- issue 31, 2 and 3: decompression bombs in frames and ground truth ---------------------------------------------
@pytest.mark.parametrize("fmt", ["jpeg", "png", "tiff"])
@pytest.mark.parametrize("method", ["model", "focus"])
def test_a_header_claiming_20000_x_20000_px_is_refused_before_decoding(fmt, method, model_path, good, tmp_path,
                                                                         capsys, monkeypatch):
    """Before: a 700-byte JPEG claiming 20000 x 20000 px drove aat-infer to 23.5 GB until the kernel killed it;
    a 20000 x 20000 PNG failed with "out of memory (try --tile 256)", no file named. Now one line naming the file
    and the size, before any decoder sees it, and the batch goes on."""
    cap, earlier = good
    bad = write_png_capture(tmp_path / "bad", FOCUS)
    if fmt == "jpeg":
        bad = write_jpeg_capture(tmp_path / "badj", FOCUS, names=["img_0.png", "img_1.png", "img_2.png"])
    name = "img_1.png" if fmt != "tiff" else "img_1.tif"
    raw = (bad / "img_1.png").read_bytes()
    if fmt == "tiff":
        raw = cv2.imencode(".tif", cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_UNCHANGED))[1].tobytes()
        (bad / "img_1.png").unlink()
        doc = json.loads((bad / "capture.json").read_text())
        doc["frames"][1]["file"] = name
        (bad / "capture.json").write_text(json.dumps(doc))
    (bad / name).write_bytes(claim_size(raw, 20000, 20000))
    assert (bad / name).stat().st_size < 40_000
    decoded = []
    import aat_deploy.capture.raw as raw_mod

    real_decode = cv2.imdecode
    monkeypatch.setattr(raw_mod.cv2, "imdecode", lambda b, f: decoded.append(len(b)) or real_decode(b, f))
    before = tree_hash(bad, cap, earlier)
    args = ["--model", model_path] if method == "model" else ["--method", "focus"]
    rc, lines, out = infer([bad, cap, *args, "--out", tmp_path / "o"], capsys)
    assert rc == 1 and len(lines) == 2, lines
    assert f"{bad / name}: its header claims 20000 x 20000 px (400 MP), beyond the limit of 200 MP" in lines[0]
    assert "--max-megapixels" in lines[0] and "AAT_MAX_MEGAPIXELS" in lines[0]
    assert f"{cap} ->" in out and "1 of 2" in lines[1]  # the batch went on
    assert not decoded or all(n != (bad / name).stat().st_size for n in decoded)  # never handed to a decoder
    assert tree_hash(bad, cap, earlier) == before


def test_pixel_limit_is_a_setting_said_the_same_by_inspect_and_read_stack(good, tmp_path, capsys, monkeypatch):
    """The limit is documented and can be lowered or raised: --max-megapixels, AAT_MAX_MEGAPIXELS, max_megapixels=;
    aat-capture inspect says the same line; read_stack raises the project's error (a ValueError), not MemoryError."""
    from aat_deploy.api import read_stack
    from aat_deploy.cli import capture as capture_cli

    cap, earlier = good
    bomb = write_jpeg_capture(tmp_path / "bomb", FOCUS)
    (bomb / "img_2.jpg").write_bytes(claim_size((bomb / "img_2.jpg").read_bytes(), 20000, 20000))
    assert capture_cli.main(["inspect", str(bomb)]) == 1
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and f"{bomb / 'img_2.jpg'}: its header claims 20000 x 20000 px" in err[0], err
    with pytest.raises(ValueError, match=r"img_2.jpg: its header claims 20000 x 20000 px \(400 MP\)") as e:
        read_stack(bomb)
    assert not isinstance(e.value, MemoryError)
    # the 64 x 48 px frames of the good capture (0.003 MP) against a lowered limit: flag, environment, API
    rc, lines, _ = infer([cap, "--model", "rf50_dfvnet_aat", "--max-megapixels", "0.001", "--out", tmp_path / "o"],
                         capsys)
    assert rc == 1 and "64 x 48 px (0 MP), beyond the limit of 0.001 MP" in lines[0], lines
    monkeypatch.setenv("AAT_MAX_MEGAPIXELS", "0.001")
    assert capture_cli.main(["inspect", str(cap)]) == 1
    assert "beyond the limit of 0.001 MP" in capsys.readouterr().err
    with pytest.raises(ValueError, match="beyond the limit of 0.001 MP"):
        read_stack(cap)
    assert read_stack(cap, max_megapixels=1)[0].shape == (3, 48, 64, 3)  # the argument wins over the environment
    monkeypatch.setenv("AAT_MAX_MEGAPIXELS", "500")
    assert capture_cli.main(["inspect", str(bomb)]) == 0  # raised: the header's 400 MP is allowed (not decoded)
    capsys.readouterr()
    with pytest.raises(SystemExit):
        infer_cli.main([str(cap), "--model", "x", "--max-megapixels", "-1"])
    assert "--max-megapixels must be a positive number" in capsys.readouterr().err


@pytest.mark.parametrize("what", ["npy", "png"])
def test_ground_truth_header_bomb_is_one_line_and_the_eval_batch_goes_on(what, model_path, good, tmp_path, capsys):
    """Before: a ground-truth file whose header claims 200000 x 200000 stopped aat-eval's whole batch with a
    traceback and no output, and aat-gt check printed the same traceback."""
    from aat_deploy.cli import gt as gt_cli

    cap, earlier = good
    root = tmp_path / "root"
    shutil.copytree(cap, root / "a_bad")
    shutil.copytree(cap, root / "b_good")
    bad = root / "a_bad"
    if what == "npy":
        header = "{'descr': '<f4', 'fortran_order': False, 'shape': (200000, 200000), }"
        header += " " * (117 - len(header)) + "\n"
        (bad / "gt_depth_m.npy").write_bytes(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode()
                                             + b"\0" * 64)
        target = bad / "gt_depth_m.npy"
    else:
        (bad / "gt_depth_m.npy").unlink()
        target = bad / "gt_depth_mm.png"
        target.write_bytes(claim_size(target.read_bytes(), 200000, 200000))
    before = tree_hash(root)
    rc = eval_cli.main([str(root), "--model", str(model_path), "--out", str(tmp_path / "e"), "-q", "--threads", "1",
                        "--no-recording"])
    err = capsys.readouterr().err
    fails = [ln for ln in err.splitlines() if "FAILED" in ln]
    assert rc == 1 and "Traceback" not in err and len(fails) == 1, err
    assert "a_bad" in fails[0] and f"{target}: its header claims 200000 x 200000 px" in fails[0]
    rep = json.loads((tmp_path / "e" / "metrics.json").read_text())
    assert [r["capture"] for r in rep["per_capture"] if r["status"] == "ok"] == ["b_good"]  # the batch went on
    assert gt_cli.main(["check", str(bad), str(root / "b_good")]) == 1
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    errs = [ln for ln in out.err.splitlines() if ln.startswith("aat-gt: error")]
    assert len(errs) == 1 and f"{target}: its header claims 200000 x 200000 px" in errs[0]
    assert "b_good" in out.out
    assert tree_hash(root) == before


# -- issue 31, 7: symlinks out of the capture folder ----------------------------------------------------------------
@pytest.mark.parametrize("link", ["frame", "sidecar", "ground_truth", "frame_in_sidecar"])
def test_links_out_of_the_capture_are_not_followed(link, model_path, good, tmp_path, capsys, monkeypatch):
    """Before: `ln -s /etc/shadow cap/frame_07.dng` was followed and parsed by the EXIF reader, exiftool and LibRaw,
    and an image reached that way ended up in aif.png and the recording. Now refused before anything is read
    through the link, unless --allow-outside-links."""
    cap, earlier = good
    outside = write_dng_capture(tmp_path / "elsewhere", [0.6, 1.0, 2.0, 3.0])
    bad = write_dng_capture(tmp_path / "bad", FOCUS)
    if link == "frame":
        (bad / "frame_07.dng").symlink_to(outside / "frame_03.dng")
        named = bad / "frame_07.dng"
    elif link == "sidecar":
        (outside / "capture.json").write_text(json.dumps({"frames": [
            {"file": f"frame_{i:02d}.dng", "focus_m": f} for i, f in enumerate(FOCUS)]}))
        (bad / "capture.json").symlink_to(outside / "capture.json")
        named = bad / "capture.json"
    elif link == "ground_truth":
        (bad / "gt_depth_m.npy").unlink()
        (bad / "gt_depth_m.npy").symlink_to(outside / "gt_depth_m.npy")
        named = bad / "gt_depth_m.npy"
    else:
        (bad / "sub").symlink_to(outside, target_is_directory=True)  # a folder link on the way
        (bad / "capture.json").write_text(json.dumps({"frames": [
            {"file": "frame_00.dng", "focus_m": 0.6}, {"file": "sub/frame_03.dng", "focus_m": 3.0}]}))
        named = bad / "sub" / "frame_03.dng"
    read = []
    import aat_deploy.capture.folder as folder
    import aat_deploy.capture.raw as raw_mod

    real_meta, real_frame = folder.read_metadata, folder.read_input_bytes
    monkeypatch.setattr(folder, "read_metadata", lambda p, **k: read.append(Path(p)) or real_meta(p, **k))
    monkeypatch.setattr(folder, "read_input_bytes", lambda p: read.append(Path(p)) or real_frame(p))
    monkeypatch.setattr(raw_mod, "read_input_bytes", lambda p: read.append(Path(p)) or real_frame(p))
    before = tree_hash(bad, outside, cap, earlier)
    rc, lines, out = infer([bad, cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 1 and len(lines) == 2, lines
    assert f"{named}: a link out of the folder (to {os.path.realpath(named)}); not followed" in lines[0]
    assert "--allow-outside-links" in lines[0] and f"{cap} ->" in out
    assert not any(p.resolve().is_relative_to(outside.resolve()) for p in read)  # nothing read through the link
    rc, lines, out = infer([bad, "--model", model_path, "--out", tmp_path / "o2", "--allow-outside-links"], capsys)
    assert rc == 0 and not lines  # the user's explicit choice
    assert tree_hash(bad, outside, cap, earlier) == before


# -- issue 31, 6: the same frame twice; a JPEG cut short with an end marker appended -----------------------------------
@pytest.mark.parametrize("how", ["hardlink", "symlink"])
def test_the_same_frame_listed_twice_through_a_link_is_refused(how, model_path, good, tmp_path, capsys):
    cap, earlier = good
    bad = write_png_capture(tmp_path / "bad", FOCUS)
    (bad / "img_2.png").unlink()
    if how == "hardlink":
        os.link(bad / "img_0.png", bad / "img_2.png")
    else:
        (bad / "img_2.png").symlink_to("img_0.png")
    rc, lines, out = infer([bad, cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 1 and len(lines) == 2 and f"{bad / 'img_2.png'}: the same file as img_0.png (a link)" in lines[0]
    assert f"{cap} ->" in out


def test_a_jpeg_cut_short_with_an_end_marker_appended_is_refused(model_path, good, tmp_path, capsys):
    """Before: a JPEG cut to a third with FF D9 appended passed the end-marker check and was used grey-padded. The
    decoder is now asked whether the data ran out (libjpeg-turbo's warnings, strict)."""
    cap, earlier = good
    bad = write_jpeg_capture(tmp_path / "bad", FOCUS, h=240, w=320)
    whole = (bad / "img_1.jpg").read_bytes()
    (bad / "img_1.jpg").write_bytes(whole[:len(whole) // 3] + b"\xff\xd9")
    rc, lines, out = infer([bad, cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 1 and len(lines) == 2, lines
    assert f"{bad / 'img_1.jpg'}: damaged or truncated JPEG (Corrupt JPEG data: premature end of data segment)" \
        in lines[0]
    # bytes a camera left before the end marker lose nothing: a warning libjpeg gives, not refused
    from aat_deploy.capture.raw import load_frame

    (tmp_path / "junk.jpg").write_bytes(whole[:-2] + b"\0\0\0\xff\xd9")
    (tmp_path / "whole.jpg").write_bytes(whole)
    assert np.array_equal(load_frame(tmp_path / "junk.jpg")[0], load_frame(tmp_path / "whole.jpg")[0])


# -- issue 34, 3: image files read by content, not by name -----------------------------------------------------------
def test_a_stack_of_jpeg_files_named_png_runs_like_the_same_stack_named_jpg(model_path, tmp_path, capsys):
    """Before: "truncated image file" (the format was taken from the name)."""
    named_png = write_jpeg_capture(tmp_path / "misnamed", FOCUS, names=["a.png", "b.png", "c.png"])
    named_jpg = write_jpeg_capture(tmp_path / "named", FOCUS, names=["a.jpg", "b.jpg", "c.jpg"])
    assert (named_png / "a.png").read_bytes() == (named_jpg / "a.jpg").read_bytes()
    rc, lines, out = infer([named_png, named_jpg, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 0 and not lines, lines
    a, b = (np.load(tmp_path / "o" / n / "depth_m.npy") for n in ("misnamed", "named"))
    assert np.array_equal(a, b)


@pytest.mark.parametrize("case", ["png_named_jpg", "dng_named_tif", "tiff_named_dng", "dng_named_jpeg"])
def test_frames_are_decoded_by_their_content_whatever_their_name(case, tmp_path):
    from aat_deploy.capture.raw import load_frame

    png = write_png_capture(tmp_path / "p", FOCUS)
    dng = write_dng_capture(tmp_path / "d", FOCUS)
    src = {"png_named_jpg": png / "img_1.png", "dng_named_tif": dng / "frame_01.dng",
           "dng_named_jpeg": dng / "frame_01.dng"}.get(case)
    if case == "tiff_named_dng":  # a plain 16-bit TIFF named like a RAW: LibRaw declines it, OpenCV reads it
        src = tmp_path / "plain.tif"
        src.write_bytes(cv2.imencode(".tif", cv2.imread(str(png / "img_1.png"), cv2.IMREAD_UNCHANGED))[1].tobytes())
    name = {"png_named_jpg": "x.jpg", "dng_named_tif": "x.tif", "tiff_named_dng": "x.dng", "dng_named_jpeg": "x.jpeg"}
    misnamed = tmp_path / name[case]
    misnamed.write_bytes(src.read_bytes())
    got, info = load_frame(misnamed)
    want, want_info = load_frame(src)
    assert np.array_equal(got, want) and info == want_info


@pytest.mark.parametrize("content, expect", [
    (b"<!DOCTYPE html><html>not an image</html>", "unknown content, not a JPEG, PNG, TIFF or camera RAW file "
                                                  "(starts with 3c 21 44 4f 43 54 59 50)"),
    (b"\0\0\0\x18ftypheic\0\0\0\0mif1heic" + b"\0" * 64, "is a HEIF/HEIC/AVIF image, which aat does not read"),
    (b"RIFF\0\0\0\0WEBPVP8 " + b"\0" * 64, "is a WebP image, which aat does not read"),
])
def test_unknown_content_is_one_line_naming_the_file(content, expect, model_path, good, tmp_path, capsys):
    from aat_deploy.cli import capture as capture_cli

    cap, earlier = good
    bad = write_png_capture(tmp_path / "bad", FOCUS)
    (bad / "img_1.png").write_bytes(content)
    rc, lines, out = infer([bad, cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 1 and len(lines) == 2 and f"{bad / 'img_1.png'}: {expect}" in lines[0], lines
    assert f"{cap} ->" in out
    assert capture_cli.main(["inspect", str(bad / "img_1.png")]) == 1  # one file, any name
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{bad / 'img_1.png'}: {expect}" in err[0], err


@pytest.mark.parametrize("orientation", range(1, 9))
def test_jpeg_orientation_is_applied_as_opencv_applies_it(orientation, tmp_path):
    """JPEG frames are decoded by libjpeg-turbo in strict mode (simplejpeg), which leaves the EXIF orientation
    to us: the same upright pixels as OpenCV's decoder (the one used before), for each of the eight values."""
    from aat_deploy.capture.raw import load_frame
    from aat_deploy.io.color import srgb_to_linear

    img = np.random.default_rng(orientation).integers(0, 256, (24, 40, 3), np.uint8)
    jpg = cv2.imencode(".jpg", cv2.GaussianBlur(img, (0, 0), 1.5), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    tiff = b"II*\0" + struct.pack("<I", 8) + struct.pack("<H", 1) + struct.pack("<HHII", 0x0112, 3, 1, orientation) \
        + struct.pack("<I", 0)
    app1 = b"Exif\0\0" + tiff
    f = tmp_path / "o.jpg"
    f.write_bytes(jpg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpg[2:])
    want = cv2.imdecode(np.frombuffer(f.read_bytes(), np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
    got, info = load_frame(f)
    assert want.shape[:2] == ((24, 40) if orientation < 5 else (40, 24))
    assert info == {"bits": 8} and np.array_equal(got, srgb_to_linear(want.astype(np.float32) / 255.0))


# -- 2: two captures with the same folder name -------------------------------------------------------------------
def test_same_folder_name_gets_distinct_outputs(model_path, tmp_path, capsys):
    a = write_dng_capture(tmp_path / "x" / "cap", FOCUS)
    b = write_png_capture(tmp_path / "y" / "cap", FOCUS)
    before = tree_hash(tmp_path / "x", tmp_path / "y")
    rc, bad, out = infer([a, b, "--model", model_path, "--out", tmp_path / "o", "--force"], capsys)
    assert rc == 0 and not bad
    s1 = json.loads((tmp_path / "o" / "cap" / "summary.json").read_text())
    s2 = json.loads((tmp_path / "o" / "cap_2" / "summary.json").read_text())
    assert (s1["capture"], s2["capture"]) == (str(a), str(b))  # the first result was not replaced
    assert f"{b} -> {tmp_path / 'o' / 'cap_2'}" in out  # the summary names where each went
    assert tree_hash(tmp_path / "x", tmp_path / "y") == before


# -- 4, 5, 7: one line per failing capture, the batch goes on ------------------------------------------------------
def _bad_capture(case: str, d: Path) -> str:
    """Make a bad capture folder in d; returns the text the one error line must contain."""
    if case == "sidecar_outside":  # capture.json names files outside the folder: refused before reading them
        write_png_capture(d, FOCUS)
        (d.parent / "secret.png").write_bytes((d / "img_0.png").read_bytes())
        (d / "capture.json").write_text(json.dumps({"frames": [
            {"file": "../secret.png", "focus_m": 0.6}, {"file": str(d / "img_1.png"), "focus_m": 1.0}]}))
        return "capture.json: frames[0] file '../secret.png' is not inside the capture folder"
    if case == "sidecar_absolute":
        write_png_capture(d, FOCUS)
        (d / "capture.json").write_text(json.dumps({"frames": [
            {"file": str((d / "img_0.png").resolve()), "focus_m": 0.6}, {"file": "img_1.png", "focus_m": 1.0}]}))
        return "is not inside the capture folder"
    if case == "deep_json":  # RecursionError before
        write_png_capture(d, FOCUS)
        (d / "capture.json").write_text('{"frames": ' + "[" * 100_000 + "]" * 100_000 + "}")
        return "capture.json: not valid JSON (nested too deeply)"
    if case == "huge_focus":
        write_png_capture(d, FOCUS)
        (d / "capture.json").write_text(json.dumps({"frames": [
            {"file": "img_0.png", "focus_m": 4e9}, {"file": "img_1.png", "focus_m": 1.0}]}))
        return "capture.json: frames[0] ('img_0.png') needs focus_m > 0 in metres, at most 1000"
    if case == "exif_focus_beyond_1km":
        write_dng_capture(d, [0.6, 1.0, 5000.0])
        return "frame_02.dng: focus distance 5000 m (EXIF SubjectDistance) is not usable (beyond 1000 m"
    if case == "sidecar_fifo":
        write_png_capture(d, FOCUS)
        os.mkfifo(d / "img_9.png")
        (d / "capture.json").write_text(json.dumps({"frames": [
            {"file": "img_0.png", "focus_m": 0.6}, {"file": "img_9.png", "focus_m": 1.0}]}))
        return "lists img_9.png, which is a FIFO"
    if case == "only_odd_frames":  # one real frame, the rest dangling/FIFO/device/folder: named in the error
        write_dng_capture(d, [0.6])
        (d / "a.dng").symlink_to(d / "nowhere.dng")
        os.mkfifo(d / "b.dng")
        (d / "c.dng").symlink_to("/dev/null")
        (d / "d.dng").mkdir()
        return "a.dng (a dangling symlink), b.dng (a FIFO), c.dng (a device), d.dng (a folder)"
    raise AssertionError(case)


@pytest.mark.parametrize("case", ["sidecar_outside", "sidecar_absolute", "deep_json", "huge_focus",
                                  "exif_focus_beyond_1km", "sidecar_fifo", "only_odd_frames"])
def test_bad_capture_is_one_line_and_the_batch_goes_on(case, model_path, good, tmp_path, capsys, monkeypatch):
    cap, earlier = good
    bad = tmp_path / "bad"
    expect = _bad_capture(case, bad)
    read = []
    import aat_deploy.capture.folder as folder

    real = folder.read_metadata
    monkeypatch.setattr(folder, "read_metadata", lambda p, **k: read.append(Path(p)) or real(p, **k))
    before = tree_hash(bad, cap, earlier)
    rc, lines, out = infer([bad, cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 1
    assert len(lines) == 2 and f"FAILED {bad}" in lines[0] and expect in lines[0], lines
    assert "1 of 2" in lines[1]
    assert (tmp_path / "o" / "good" / "summary.json").is_file() and f"{cap} ->" in out  # the batch went on
    assert all(p.resolve().is_relative_to(bad.resolve()) or p.resolve().is_relative_to(cap.resolve())
               for p in read)  # nothing outside a capture folder was read
    assert tree_hash(bad, cap, earlier) == before


@pytest.mark.parametrize("case", ["subfolder_frames", "non_utf8_frame_name", "non_utf8_capture_name",
                                  "odd_entries_next_to_frames"])
def test_unusual_but_valid_captures_run(case, model_path, good, tmp_path, capsys):
    """KeyError (capture.json naming raw/frame_00.dng) and UnicodeEncodeError (a non-UTF-8 byte in a name)
    stopped the batch before; these captures are fine and run. Entries named like frames that are not files are
    reported in a warning, not silently dropped."""
    cap, earlier = good
    name = os.fsdecode(b"caf\xe9") if case == "non_utf8_capture_name" else "bad"
    bad = write_dng_capture(tmp_path / "made", FOCUS).rename(tmp_path / name)
    if case == "subfolder_frames":
        (bad / "raw").mkdir()
        for i in range(3):
            (bad / f"frame_{i:02d}.dng").rename(bad / "raw" / f"frame_{i:02d}.dng")
        (bad / "capture.json").write_text(json.dumps({"frames": [
            {"file": f"raw/frame_{i:02d}.dng", "focus_m": f} for i, f in enumerate(FOCUS)]}))
    elif case == "non_utf8_frame_name":
        (bad / "frame_00.dng").rename(bad / os.fsdecode(b"fr\xffme_00.dng"))
    elif case == "odd_entries_next_to_frames":
        (bad / "x.dng").symlink_to(bad / "gone.dng")
        os.mkfifo(bad / "y.dng")
    before = tree_hash(bad, cap, earlier)
    rc = infer_cli.main([str(bad), str(cap), "--model", str(model_path), "--out", str(tmp_path / "o"),
                         "--threads", "1", "-q"])  # with the recording: rerun gets the names too
    err = capsys.readouterr().err
    assert rc == 0 and "FAILED" not in err and "Traceback" not in err, err
    assert (tmp_path / "o" / name / "summary.json").is_file()
    rrd = (tmp_path / "o" / name / "recording.rrd").read_bytes()
    assert rrd[:4] == b"RRF2" and len(rrd) > 10_000
    if case == "odd_entries_next_to_frames":
        warn = [ln for ln in err.splitlines() if "not regular files" in ln]
        assert len(warn) == 1 and "x.dng (a dangling symlink), y.dng (a FIFO)" in warn[0]
    assert tree_hash(bad, cap, earlier) == before


def test_unexpected_exception_is_one_line_with_its_type(model_path, good, tmp_path, capsys, monkeypatch):
    """The per-capture boundary: an exception that is not the project's own (a bug not found yet) becomes one
    line naming the capture and the exception type, and the batch goes on."""
    cap, earlier = good
    bad = write_dng_capture(tmp_path / "bad", FOCUS)
    import aat_deploy.infer.pipeline as pipeline

    real = pipeline.read_capture

    def boom(folder, **kw):
        if Path(folder).name == "bad":
            raise ZeroDivisionError("float division by zero")
        return real(folder, **kw)

    monkeypatch.setattr(pipeline, "read_capture", boom)
    rc, lines, out = infer([bad, cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 1 and len(lines) == 2
    assert f"FAILED {bad}: unexpected ZeroDivisionError: float division by zero" in lines[0]
    assert (tmp_path / "o" / "good" / "summary.json").is_file()


def test_unwritable_output_fails_before_decoding(model_path, good, tmp_path, capsys, monkeypatch):
    """PermissionError/NotADirectoryError came after decoding and inference and stopped the batch."""
    cap, earlier = good
    blocker = tmp_path / "file"
    blocker.write_text("a file where a folder should be")
    calls = []
    import aat_deploy.infer.frames as frames_mod  # the one frame reader

    real = frames_mod.load_frame
    monkeypatch.setattr(frames_mod, "load_frame", lambda p: calls.append(Path(p)) or real(p))
    outs = [blocker / "out"]
    if os.geteuid() != 0:  # root writes into a read-only folder anyway
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o555)
        outs.append(ro / "out")
    for out in outs:
        rc, lines, _ = infer([cap, "--model", model_path, "--out", out], capsys)
        assert rc == 1 and len(lines) == 2 and str(out) in lines[0] and ("not writable" in lines[0]
                                                                         or "cannot be created" in lines[0])
        assert not calls
    assert blocker.read_text() == "a file where a folder should be"


@pytest.mark.parametrize("key, value", [("aat.pixel_um", 0), ("aat.sensor_px", [0, 48]), ("aat.sensor_px", [-64, 48]),
                                        ("aat.focus_range_m", [float("nan"), 5.0]), ("aat.focus_range_m", [5.0, 0.5]),
                                        ("aat.focal_length_mm", "abc"), ("aat.size_multiple", True),
                                        ("aat.stack_min", 5.5), ("aat.sensor_mm", [36, -24])])
def test_bad_model_metadata_is_one_line_naming_the_key(key, value, model_path, good, tmp_path, capsys):
    cap, earlier = good
    bad = with_meta(model_path, tmp_path / "bad.onnx", **{key.replace(".", "__"): value})
    before = tree_hash(cap, earlier)
    rc = infer_cli.main([str(cap), "--model", str(bad), "--out", str(tmp_path / "o"), "--threads", "1", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "bad.onnx" in err[0] and key in err[0], err
    assert not (tmp_path / "o").exists() and tree_hash(cap, earlier) == before


# -- 8: ground truth in the wrong units ----------------------------------------------------------------------------
def test_infer_checks_ground_truth_units(model_path, tmp_path, capsys):
    cap = write_dng_capture(tmp_path / "mm", FOCUS)
    np.save(cap / "gt_depth_m.npy", np.load(cap / "gt_depth_m.npy") * 1000)  # millimetres saved as metres
    rc, lines, _ = infer([cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert rc == 0 and s["ground_truth"] is None  # was "MAE 3133 m"
    assert any("gt_depth_m.npy" in w and "wrong units" in w and "millimetres" in w for w in s["warnings"])


def test_damaged_npy_header_is_a_clean_error(model_path, tmp_path, capsys):
    """Found by tests/fuzz_readers.py: np.load parses a .npy header with Python's tokenizer, and an
    unbalanced bracket raised tokenize.TokenError (not a ValueError) out of aat-eval's reader and aat-infer."""
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    raw = bytearray((cap / "gt_depth_m.npy").read_bytes())
    raw[raw.index(b"), }")] = ord(" ")  # the shape tuple loses its closing bracket
    (cap / "gt_depth_m.npy").write_bytes(bytes(raw))
    with pytest.raises(CaptureError, match=r"gt_depth_m.npy: unreadable"):
        load_ground_truth(find_gt(cap))
    rc, lines, _ = infer([cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert rc == 0 and any("gt_depth_m.npy: unreadable" in w and "ground truth ignored" in w for w in s["warnings"])


# -- 9: ports and stale temporary folders --------------------------------------------------------------------------
@pytest.mark.parametrize("flag, port", [("--port", 0), ("--port", 70000), ("--grpc-port", -1)])
def test_view_port_out_of_range(flag, port, tmp_path, capsys):
    rrd = tmp_path / "r.rrd"
    rrd.write_bytes(b"RRF2" + b"\0" * 64)
    assert view_cli.main([str(rrd), flag, str(port)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag in err[0] and "1..65535" in err[0]


def test_stale_partial_folders_of_dead_runs_are_cleaned(model_path, good, tmp_path, capsys):
    """Marked temporaries of dead processes are swept, whatever output they were for (issue 31: before, only a
    rerun to the same name removed them); a running process's, and any folder without our marker, are kept."""
    cap, earlier = good
    out = tmp_path / "o"
    dead, alive = dead_pid(), os.getppid()
    stale = [tmp_path / f".o.tmp-{dead}", tmp_path / f".o.old-{dead}", tmp_path / f".other.tmp-{dead}"]
    keep = [tmp_path / f".o.tmp-{alive}", tmp_path / f".users.tmp-{dead}",  # running; not ours (no marker)
            tmp_path / f".shared.tmp-{dead}"]  # another host's run in a shared folder: its pid means nothing here
    for d in stale + keep:
        d.mkdir()
        (d / "depth_m.npy").write_bytes(b"partial")
        if d != keep[1]:
            marker.write(d, "aat-infer", complete=".old-" in d.name)
    doc = json.loads((keep[2] / marker.MARKER).read_text())
    (keep[2] / marker.MARKER).write_text(json.dumps({**doc, "host": "another-host"}))
    rc, lines, _ = infer([cap, "--model", model_path, "--out", out], capsys)
    assert rc == 0 and not lines
    assert not any(d.exists() for d in stale) and all(d.exists() for d in keep)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == sorted(d.name for d in keep)


# -- issue 31, 5: SIGTERM / Ctrl-C ----------------------------------------------------------------------------------
HARNESS = """
import sys, time
sys.path.insert(0, {root!r})
import {module} as target
real = target.{name}
def held(*a, **k):
    out = real(*a, **k) if {after} else None
    with open({flag!r}, "w") as f:  # closed here: a handler run by an unclosed file's implicit close is discarded
        f.write("in")
    end = time.monotonic() + 120
    while time.monotonic() < end:  # short sleeps: a signal that lands just before one starts waits 50 ms, not 120 s
        time.sleep(0.05)
    return out if {after} else real(*a, **k)
target.{name} = held
from aat_deploy.cli.infer import main
sys.exit(main(sys.argv[1:]))
"""


def _run_until(tmp_path, module, name, after, argv, sig):
    """aat-infer in a subprocess, held inside module.name (after it ran, or before); send `sig` once it is there.
    Returns (exit status, stderr lines). The signal can land between the flag file's creation and the hold, so the
    flag is closed explicitly (a handler run by an unclosed file's implicit close raises inside a finalizer, and
    CPython discards that) and the hold sleeps in 50 ms steps (a handler pending when a sleep starts runs when it
    ends). Before, `open(flag).write()` and one `time.sleep(120)` failed this test under load: the run went on and
    exited 120 s later, past the 60 s below."""
    import signal as _signal
    import time

    flag = tmp_path / "reached"
    code = HARNESS.format(root=str(Path(__file__).resolve().parents[2]), module=module, name=name, after=after,
                          flag=str(flag))
    proc = subprocess.Popen([sys.executable, "-c", code, *map(str, argv)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    end = time.monotonic() + 120
    while not flag.exists() and proc.poll() is None and time.monotonic() < end:
        time.sleep(0.05)
    assert flag.exists(), proc.communicate()
    proc.send_signal(getattr(_signal, sig))
    _, err = proc.communicate(timeout=60)
    return proc.returncode, [ln for ln in err.splitlines() if ln.strip()]


@pytest.mark.parametrize("sig, status", [("SIGTERM", 143), ("SIGINT", 130)])
def test_a_signal_while_outputs_are_written_leaves_no_temporary_folder(sig, status, model_path, good, tmp_path):
    """Before: SIGTERM while the outputs were written left a hidden partial .OUT.tmp-PID/ every time."""
    cap, earlier = good
    out = tmp_path / "runs" / "o"
    before = tree_hash(cap, earlier)
    rc, err = _run_until(tmp_path, "aat_deploy.infer.pipeline", "write_outputs", True,
                         [cap, "--model", model_path, "--out", out, "-q", "--threads", "1"], sig)
    assert rc == status and err == [f"aat-infer: {'terminated' if sig == 'SIGTERM' else 'interrupted'} ({sig})"], err
    assert not out.exists() and list(out.parent.iterdir()) == []  # no .o.tmp-PID left behind
    assert tree_hash(cap, earlier) == before


DISCARDED = """
import signal, sys
sys.path.insert(0, {root!r})
import aat_deploy.infer.pipeline as target
real = target.write_outputs
class Finalized:
    def __del__(self):  # as an unclosed file whose implicit close runs the handler: CPython discards its exception
        signal.raise_signal(signal.{sig})
def written(*a, **k):
    out = real(*a, **k)
    Finalized()
    return out
target.write_outputs = written
from aat_deploy.cli.infer import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("sig, status", [("SIGTERM", 143), ("SIGINT", 130)])
def test_a_signal_whose_exception_a_finalizer_discards_still_stops_the_run(sig, status, model_path, good, tmp_path):
    """Before: a signal whose handler ran inside a finalizer (a `__del__`, an unclosed file's close) was lost: CPython
    discards the exception, the run finished and committed its outputs with exit status 0 and an "Exception ignored"
    traceback (the CI flake of the test above was this, in its harness)."""
    cap, earlier = good
    out = tmp_path / "runs" / "o"
    before = tree_hash(cap, earlier)
    code = DISCARDED.format(root=str(Path(__file__).resolve().parents[2]), sig=sig)
    proc = subprocess.run([sys.executable, "-c", code, str(cap), "--model", str(model_path), "--out", str(out), "-q",
                           "--threads", "1"], capture_output=True, text=True, timeout=120)
    err = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == status and err == [
        f"aat-infer: {'terminated' if sig == 'SIGTERM' else 'interrupted'} ({sig})"], (proc.returncode, err)
    assert not out.exists() and list(out.parent.iterdir()) == []  # nothing committed, no .o.tmp-PID left behind
    assert tree_hash(cap, earlier) == before


def test_ctrl_c_during_start_up_is_one_line_and_exit_130(model_path, good, tmp_path):
    """Before: Ctrl-C while the command was starting printed a 30-line traceback."""
    cap, earlier = good
    for module, name in (("aat_deploy.shipped", "resolve"), ("aat_deploy.infer.model", "DfFModel.__init__")):
        rc, err = _run_until(tmp_path, module, name, False, [cap, "--model", model_path, "--out", tmp_path / "o", "-q"],
                             "SIGINT")
        assert rc == 130 and err == ["aat-infer: interrupted (SIGINT)"], err
        (tmp_path / "reached").unlink()


# -- issue 31, 8: aat-gt check as strict as aat-eval ----------------------------------------------------------------
def test_gt_check_refuses_another_aspect_ratio_and_takes_shipped_model_names(good, tmp_path, capsys):
    """Before: aat-gt check accepted 1920 x 320 ground truth for 960 x 640 frames (aat-eval refuses it), and
    `--model rf50_dfvnet_aat_field` was "no such model file" while listed as usable."""
    from aat_deploy.cli import gt as gt_cli

    cap, earlier = good
    wide = tmp_path / "wide"
    shutil.copytree(cap, wide)
    (wide / "gt_depth_mm.png").unlink()
    np.save(wide / "gt_depth_m.npy", np.full((16, 96), 2.0, np.float32))  # 6:1 for 64 x 48 (4:3) frames
    before = tree_hash(wide, cap)
    assert gt_cli.main(["check", str(wide), str(cap), "--model", "rf50_dfvnet_aat_field"]) == 1
    out = capsys.readouterr()
    errs = [ln for ln in out.err.splitlines() if ln.startswith("aat-gt: error")]
    assert len(errs) == 1 and (f"{wide / 'gt_depth_m.npy'}: ground truth is 96x16 px, the frames are 64x48 px: a "
                               "different aspect ratio") in errs[0], out.err
    assert "no such model file" not in out.err and "frames 64x48 px" in out.out  # the good capture was checked
    assert tree_hash(wide, cap) == before


# -- issue 31, 4: --threads bounded to the machine --------------------------------------------------------------------
def test_threads_beyond_the_machine_are_bounded_and_said(model_path, good, tmp_path, capsys, monkeypatch):
    """Before: --threads 100000 was accepted (16 GB, still running after 5 minutes)."""
    import aat_deploy.machine as machine

    cap, earlier = good
    monkeypatch.setattr(machine.os, "sched_getaffinity", lambda pid: {0, 1})  # a 2-core machine, whatever runs this
    made = []
    import aat_deploy.infer.model as model_mod

    real = model_mod.ort.InferenceSession
    monkeypatch.setattr(model_mod.ort, "InferenceSession",
                        lambda p, o, **k: made.append(o.intra_op_num_threads) or real(p, o, **k))
    rc = infer_cli.main([str(cap), "--model", str(model_path), "--out", str(tmp_path / "o"), "-q", "--no-recording",
                         "--threads", "100000"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 0 and err == ["aat-infer: note: --threads 100000: this machine has 2 core(s); using 2"], err
    assert made == [2]
    assert DfFModel(model_path, threads=10 ** 6).session.get_session_options().intra_op_num_threads == 2  # the API


# -- issue 31, 9: messages that did not name the file or the problem -------------------------------------------------
def test_nan_or_inf_in_a_float_tiff_frame_names_the_file(model_path, good, tmp_path, capsys):
    """Before: "unexpected ValueError: normalise_stack: the stack contains NaN or inf"."""
    cap, earlier = good
    bad = tmp_path / "bad"
    bad.mkdir()
    frames = []
    for i, f in enumerate(FOCUS):
        img = np.full((48, 64, 3), 0.5, np.float32)
        if i == 1:
            img[3, 4, 1], img[5, 6] = np.nan, np.inf
        cv2.imwrite(str(bad / f"f{i}.tif"), img)
        frames.append({"file": f"f{i}.tif", "focus_m": f})
    (bad / "capture.json").write_text(json.dumps({"frames": frames}))
    rc, lines, out = infer([bad, cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 1 and f"{bad / 'f1.tif'}: 2 pixel(s) are NaN or infinite" in lines[0], lines
    assert f"{cap} ->" in out


def _full_tmpfs(path: Path, size: str):
    path.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs to fill ({r.stderr.decode().strip()[:100]}): needs root with "
                    "CAP_SYS_ADMIN; the short-write message is tested without it")
    return path


def test_a_full_disk_is_one_line_naming_the_output_and_leaves_nothing(model_path, good, tmp_path, capsys,
                                                                        monkeypatch):
    """Before: "unexpected OSError: 614400 requested and 524256 written" (numpy's short write on a full disk)."""
    cap, earlier = good
    import aat_deploy.infer.outputs as outputs

    def short_write(*a, **k):
        raise OSError("614400 requested and 524256 written")

    with monkeypatch.context() as m:
        m.setattr(outputs.np, "save", short_write)
        rc, lines, _ = infer([cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 1 and (f"{tmp_path / 'o'}: could not write the outputs (no space left on the device (614400 bytes "
                        "to write, 524256 written)); nothing was left there") in lines[0], lines
    assert not [p for p in tmp_path.iterdir() if p.name.startswith((".o.", "o"))]
    disk = _full_tmpfs(tmp_path / "disk", "96k")
    try:
        rc, lines, _ = infer([cap, "--model", model_path, "--out", disk / "o"], capsys)
        assert rc == 1 and f"{disk / 'o'}: could not write the outputs (no space left on the device" in lines[0], lines
        assert list(disk.iterdir()) == []
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_out_on_a_mount_point_is_refused_before_any_work(model_path, good, tmp_path, capsys, monkeypatch):
    """Before: EBUSY only after all the work (a mount point cannot be renamed away)."""
    cap, earlier = good
    mnt = _full_tmpfs(tmp_path / "mnt", "4m")
    try:
        calls = []
        import aat_deploy.infer.frames as frames_mod  # the one frame reader

        real = frames_mod.load_frame
        monkeypatch.setattr(frames_mod, "load_frame", lambda p, *a: calls.append(p) or real(p, *a))
        rc, lines, _ = infer([cap, "--model", model_path, "--out", mnt, "--force"], capsys)
        assert rc == 1 and f"{mnt}: is a mount point, which cannot be replaced; choose a folder inside it" in lines[0]
        assert not calls
        rc, lines, _ = infer([cap, "--model", model_path, "--out", mnt / "o"], capsys)
        assert rc == 0 and (mnt / "o" / "summary.json").is_file()  # a folder inside it is fine
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


def _onnx_with_stack_rank(src: Path, dst: Path, rank: int) -> Path:
    """A model following the contract's names and metadata whose `stack` input has another rank."""
    import onnx
    from onnx import TensorProto, helper

    meta = {p.key: p.value for p in onnx.load(str(src)).metadata_props}
    dims = ["B", "S", "C", "H", "W"][:rank]
    g = helper.make_graph(
        [helper.make_node("Identity", ["stack"], ["aif"]),
         helper.make_node("ReduceMean", ["stack"], ["depth_m"], axes=[1], keepdims=0),
         helper.make_node("ReduceMean", ["stack"], ["std_m"], axes=[1], keepdims=0)], "wrong_rank",
        [helper.make_tensor_value_info("stack", TensorProto.FLOAT, dims),
         helper.make_tensor_value_info("focus_m", TensorProto.FLOAT, ["B", "S"])],
        [helper.make_tensor_value_info("aif", TensorProto.FLOAT, dims),
         helper.make_tensor_value_info("depth_m", TensorProto.FLOAT, dims[:1] + dims[2:]),
         helper.make_tensor_value_info("std_m", TensorProto.FLOAT, dims[:1] + dims[2:])])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 13)])
    for k, v in meta.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    onnx.save(m, str(dst))
    return dst


def test_model_and_recording_problems_are_said_at_load(model_path, good, tmp_path, capsys):
    """Before: a model with the wrong input rank failed per capture (exit 1); a folder as --model or as the .rrd
    was "no such file"; a garbage .rrd with valid magic bytes was served with no error."""
    cap, earlier = good
    bad = _onnx_with_stack_rank(model_path, tmp_path / "rank4.onnx", 4)
    for model, expect in ((bad, "rank4.onnx: input 'stack' has rank 4 ['B', 'S', 'C', 'H'], the contract says 5 "
                                "(B, S, 3, H, W)"),
                          (tmp_path, f"{tmp_path}: is a folder, expected an ONNX model file (.onnx)")):
        rc = infer_cli.main([str(cap), str(cap), "--model", str(model), "--out", str(tmp_path / "o"), "-q"])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and expect in err[0], err
    rrd = tmp_path / "r.rrd"
    rrd.write_bytes(b"RRF2" + bytes(range(256)) * 16)
    for path, expect in ((rrd, "r.rrd: not a readable rerun recording ("),
                         (tmp_path, f"{tmp_path}: is a folder, expected a recording (.rrd)")):
        assert view_cli.main([str(path)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and expect in err[0], err


def test_capture_json_with_a_byte_order_mark_is_read(model_path, tmp_path, capsys):
    """Before: a Python-internal message ("Unexpected UTF-8 BOM (decode using utf-8-sig)")."""
    cap = write_png_capture(tmp_path / "bom", FOCUS)
    (cap / "capture.json").write_bytes(b"\xef\xbb\xbf" + (cap / "capture.json").read_bytes())
    rc, lines, _ = infer([cap, "--model", model_path, "--out", tmp_path / "o"], capsys)
    assert rc == 0 and not lines, lines
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["focus_m"] == FOCUS


def test_a_newline_in_a_folder_name_keeps_every_message_on_one_line(model_path, tmp_path, capsys):
    """Before: the result line (and a failure line) split at the newline."""
    ok = write_png_capture(tmp_path / "two\nlines", FOCUS)
    bad = write_png_capture(tmp_path / "bad\nname", FOCUS)
    (bad / "img_1.png").write_bytes(b"nothing")
    rc = infer_cli.main([str(ok), str(bad), "--model", str(model_path), "--out", str(tmp_path / "o"), "-q",
                         "--no-recording", "--threads", "1"])
    cap = capsys.readouterr()
    assert rc == 1
    assert cap.out.splitlines() == [f"{tmp_path}/two\\nlines -> {tmp_path}/o/two\\nlines  "
                                    + cap.out.split("  ", 1)[1].strip()]
    fails = [ln for ln in cap.err.splitlines() if "FAILED" in ln]
    assert len(fails) == 1 and f"FAILED {tmp_path}/bad\\nname: {tmp_path}/bad\\nname/img_1.png: unknown content" \
        in fails[0]


def test_api_errors_are_one_line_value_errors(model_path):
    """Before: stack=None raised TypeError; a bad focus distance printed np.float64(...)."""
    from aat_deploy.api import depth_from_focus

    net = DfFModel(model_path, threads=1)
    with pytest.raises(ValueError, match=r"^stack: expected an \(S, H, W, 3\) array .*got NoneType$"):
        depth_from_focus(None, FOCUS, net)
    frames = np.full((3, 48, 64, 3), 0.5, np.float32)
    with pytest.raises(ValueError, match=r"^focus_m\[1\] = -1: not a focus distance in metres \(not positive\)$"):
        depth_from_focus(frames, np.array([0.6, -1.0, 2.0]), net)
    with pytest.raises(ValueError, match=r"^focus_m: expected one focus distance in metres per frame, got dict$"):
        depth_from_focus(frames, {"a": 1}, net)


# -- 10: Canon compacts record FocusDistanceLower = 0 --------------------------------------------------------------
@pytest.mark.parametrize("upper, lower, expected", [(216, 0, 2.16), (200, 100, 4 / 3), (65535, 546, 10.92),
                                                    (65535, 0, math.inf)])
def test_canon_lower_zero_means_not_recorded(upper, lower, expected, tmp_path):
    f = tmp_path / "IMG_0001.JPG"
    f.write_bytes(canon_jpeg(upper, lower))
    meta = read_metadata(f, use_exiftool=False)
    assert meta.focus_tags == {"FocusDistanceUpper": upper / 100, "FocusDistanceLower": lower / 100}
    assert meta.focus_m == pytest.approx(expected)
    assert ("Lower not recorded" in meta.focus_source) == (lower == 0)
    if not exiftool.available():
        pytest.skip("exiftool not installed (Debian package libimage-exiftool-perl): its answer not compared")
    et = json.loads(subprocess.run(["exiftool", "-j", "-n", "-FocusDistanceUpper", "-FocusDistanceLower", str(f)],
                                   capture_output=True, text=True, check=True).stdout)[0]
    assert (et["FocusDistanceUpper"], et["FocusDistanceLower"]) == (upper / 100, lower / 100)  # ExifTool's reading
    assert exiftool.read(f).focus_m == pytest.approx(expected)  # the exiftool fallback combines them the same way


@pytest.mark.parametrize("name", ["Canon.jpg", "Canon1DmkIII.jpg"])
def test_canon_sample_with_lower_zeroed_matches_exiftool(name, tmp_path):
    """Real Canon files (../shared/data) with every stored FocusDistanceLower set to 0 (ShotInfo [20], FileInfo
    [21], the 1D Mk III's CameraInfo 0x45): ExifTool reads 0 and the runtime uses Upper alone (before, the
    diopter midpoint with infinity: twice the distance)."""
    src = SHARED / "raw_exif_makernotes_exiftool" / name
    if not src.is_file():
        pytest.skip(f"{src} not present (no ../shared/data)")
    if not exiftool.available():
        pytest.skip("exiftool not installed (Debian package libimage-exiftool-perl)")
    from aat_deploy.capture.containers import find_blocks

    buf = bytearray(src.read_bytes())
    _, tb, first = find_blocks(bytes(buf)).tiffs[0]
    exif = tb.ifd(int(tb.number(tb.ifd(first), 0x8769)))
    note = tb.ifd(exif[0x927C].data_offset, absolute=True)
    for tag, index in ((0x0004, 20), (0x0093, 21)):  # int16u arrays, little-endian in these files
        if tag in note and len(note[tag].data) > 2 * index:
            struct.pack_into("<H", buf, note[tag].data_offset + 2 * index, 0)
    if 0x000D in note and "1D Mark III" in (tb.text(tb.ifd(first), 0x0110) or ""):
        struct.pack_into(">H", buf, note[0x000D].data_offset + 0x45, 0)
    f = tmp_path / name
    f.write_bytes(bytes(buf))
    et = json.loads(subprocess.run(["exiftool", "-j", "-n", "-FocusDistanceUpper", "-FocusDistanceLower", str(f)],
                                   capture_output=True, text=True, check=True).stdout)[0]
    assert et["FocusDistanceLower"] == 0
    meta = read_metadata(f, use_exiftool=False)
    assert meta.focus_tags == {"FocusDistanceUpper": et["FocusDistanceUpper"], "FocusDistanceLower": 0}
    upper = et["FocusDistanceUpper"]
    assert meta.focus_m == (math.inf if upper > 655.345 else pytest.approx(upper))


# -- property-based: the readers users feed -------------------------------------------------------------------------
def _mutate(buf: bytes, edits: list[tuple[int, int]], cut: int | None) -> bytes:
    b = bytearray(buf)
    for pos, val in edits:
        if b:
            b[pos % len(b)] = val
    return bytes(b[:cut] if cut is not None else b)


EDITS = st.lists(st.tuples(st.integers(0, 1 << 20), st.integers(0, 255)), max_size=12)
HEAD_EDITS = st.lists(st.tuples(st.integers(0, 511), st.integers(0, 255)), min_size=1, max_size=8)


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    """Files to mutate: a virtual-camera DNG, a Canon maker-note JPEG, a 16-bit PNG frame."""
    d = tmp_path_factory.mktemp("seeds")
    cap = write_dng_capture(d / "dng", [0.7, 1.4], h=24, w=32, gt=False)
    png = write_png_capture(d / "png", [0.7, 1.4], h=24, w=32)
    return {"dng": (cap / "frame_00.dng").read_bytes(), "jpg": canon_jpeg(216, 0),
            "png": (png / "img_0.png").read_bytes()}


@FUZZ
@given(kind=st.sampled_from(["dng", "jpg", "png"]), edits=st.one_of(EDITS, HEAD_EDITS),
       cut=st.one_of(st.none(), st.integers(0, 4096)))
@example(kind="dng", edits=[(32, 16)], cut=None)  # a width past OpenCV's limit: cv2.error escaped (found by CI)
def test_fuzz_frame_metadata_and_pixels(seeds, tmp_path, kind, edits, cut):
    """Mutated DNG/TIFF headers, JPEG maker notes and PNGs: read_metadata and load_frame give a result or a
    CaptureError, nothing else."""
    from aat_deploy.capture.raw import load_frame

    f = tmp_path / f"f.{kind}"
    f.write_bytes(_mutate(seeds[kind], edits, cut))
    for read in (lambda: read_metadata(f, use_exiftool=False), lambda: load_frame(f)):
        try:
            read()
        except CaptureError as e:
            assert "\n" not in str(e) and str(f) in str(e)


MAKERS = ["Canon", "NIKON CORPORATION", "OLYMPUS IMAGING CORP.", "KONICA MINOLTA", "CASIO COMPUTER CO.,LTD."]


@FUZZ
@given(make=st.sampled_from(MAKERS), note=st.binary(max_size=300), prefix=st.sampled_from(
    [b"", b"Nikon\0\x02\x10\0\0", b"Nikon\0\x01\0", b"OLYMPUS\0II\x03\0", b"OLYMP\0\x01\0", b"QVC\0\0\0"]))
def test_fuzz_maker_note_blocks(tmp_path, make, note, prefix):
    """Arbitrary maker-note blocks behind each maker's header: metadata or a note, never an exception."""
    jpg = bytearray(canon_jpeg(216, 0))
    mn_at = jpg.index(struct.pack("<H", 0x927C))  # the Exif IFD's MakerNote entry: point it at our bytes
    block = prefix + note
    tiff_at = jpg.index(b"II*\0")
    struct.pack_into("<I", jpg, mn_at + 4, len(block))
    struct.pack_into("<I", jpg, mn_at + 8, len(jpg) - 2 - tiff_at)  # appended before EOI
    body = bytes(jpg[:-2]).replace(b"Canon\0", make.encode()[:5] + b"\0", 1) + block + b"\xff\xd9"
    body = body[:4] + struct.pack(">H", len(body) - 6) + body[6:]  # APP1 length
    f = tmp_path / "mn.jpg"
    f.write_bytes(body)
    meta = read_metadata(f, use_exiftool=False)
    assert meta.focus_m is None or isinstance(meta.focus_m, float)


JSONISH = st.recursive(st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=12),
                       lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=4),
                       max_leaves=12)
FRAME_ENTRY = st.fixed_dictionaries({}, optional={
    "file": st.sampled_from(["img_0.png", "img_1.png", "../img_0.png", "/etc/hostname", "raw/x.png", "", "a\0b",
                             "img_0.png/", "C:\\x.png", "nope.png"]) | JSONISH,
    "focus_m": st.sampled_from([0.6, 1.0, 0, -1, 1e308, float("nan"), float("inf"), 4e9, 10 ** 400, True, "1"])
    | JSONISH})
SIDECAR = st.one_of(JSONISH, st.fixed_dictionaries({"frames": st.lists(FRAME_ENTRY, max_size=4) | JSONISH}))


@FUZZ
@given(doc=SIDECAR, raw=st.one_of(st.none(), st.binary(max_size=64)))
def test_fuzz_capture_json(seeds, tmp_path_factory, doc, raw):
    d = tmp_path_factory.mktemp("cj")
    for i in range(2):
        (d / f"img_{i}.png").write_bytes(seeds["png"])
    text = raw if raw is not None else json.dumps(doc, allow_nan=True).encode()
    (d / "capture.json").write_bytes(text)
    try:
        cap = read_capture(d, use_exiftool=False)
    except CaptureError as e:
        assert "\n" not in str(e) and str(d) in str(e)
    else:
        assert all(0 < f.focus_m <= 1000 and f.path.resolve().is_relative_to(d.resolve()) for f in cap.frames)


GT_DOC = st.one_of(JSONISH, st.fixed_dictionaries({}, optional={
    "depth": st.sampled_from(["gt_depth_m.npy", "gt_d.pfm", "../gt_depth_m.npy", "/etc/hostname", "gt_x.png",
                              "frame.png", "nope.npy"]) | JSONISH,
    "scale_to_m": st.sampled_from([1, 0.001, 0, -1, float("nan"), 10 ** 400, "1"]) | JSONISH,
    "mask": st.sampled_from(["gt_mask.png", "../m.png", "nope.png"]) | JSONISH}))
DEPTH_BYTES = st.binary(max_size=200)


@FUZZ
@given(doc=GT_DOC, depth=st.one_of(st.none(), DEPTH_BYTES), pfm=st.binary(max_size=80))
def test_fuzz_gt_json(tmp_path_factory, doc, depth, pfm):
    d = tmp_path_factory.mktemp("gt")
    arr = np.full((6, 8), 1.5, np.float32)
    np.save(d / "gt_depth_m.npy", arr)
    if depth is not None:
        (d / "gt_depth_m.npy").write_bytes(depth)
    (d / "gt_d.pfm").write_bytes(b"Pf\n8 6\n-1\n" + pfm)
    (d / "gt.json").write_text(json.dumps(doc, allow_nan=True))
    try:
        src = find_gt(d)
        if src is not None:
            gt = load_ground_truth(src)
            assert np.isfinite(gt.depth_m).any()
    except CaptureError as e:
        assert "\n" not in str(e) and str(d) in str(e)


def test_model_metadata_fuzz(model_path, tmp_path):
    """Every REQUIRED key given a hostile value: a ModelError naming the key, or a model with sane numbers."""
    values = [0, -1, 1e308, float("nan"), "x", True, None, [], [1], [1, 2, 3], {"a": 1}, [0, 0], [1e9, 1e9], 10 ** 30]
    keys = ["aat.size_multiple", "aat.stack_min", "aat.stack_max", "aat.sensor_px", "aat.focus_range_m",
            "aat.focal_length_mm", "aat.f_number", "aat.pixel_um", "aat.lens_name", "aat.sensor_mm"]
    for i, (k, v) in enumerate((k, v) for k in keys for v in values):
        p = with_meta(model_path, tmp_path / f"m{i}.onnx", **{k.replace(".", "__"): v})
        try:
            m = DfFModel(p, threads=1)
        except CaptureError as e:
            assert k in str(e) and "\n" not in str(e)
        else:
            assert m.focal_length_px > 0 and all(x > 0 for x in m.sensor_px) and m.size_multiple >= 1


# -- issue 31: random capture folders against the promises -----------------------------------------------------------


@pytest.fixture(scope="module")
def fuzz_env(tmp_path_factory):
    d = tmp_path_factory.mktemp("capfuzz")
    return fuzz_seeds(d / "seeds"), write_dng_capture(d / "good", FOCUS)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                  HealthCheck.too_slow])
@given(kinds=st.lists(st.sampled_from(ENTRY_KINDS), min_size=1, max_size=5), sidecar=st.sampled_from(SIDECAR_KINDS),
       junk=st.binary(min_size=1, max_size=64))
@example(kinds=["png_small", "png_small"], sidecar="list", junk=b"x")  # small frames, all the same size: a capture
def test_fuzz_capture_folders_keep_the_promises(fuzz_env, model_path, tmp_path_factory, capsys, kinds, sidecar,
                                                  junk):
    """Random capture folders (file kinds and contents, links out and within, sizes, sidecars) beside a good
    capture through aat-infer: exit status 0 or 1, a failure is exactly one line naming a file in the capture (or
    the capture), the batch goes on, the inputs are byte-identical afterwards, and no temporary is left."""
    seeds, good = fuzz_env
    tmp = tmp_path_factory.mktemp("case")
    cap = tmp / "cap"
    kinds = random_capture(cap, kinds, sidecar, seeds, tmp / "outside", junk)
    before = tree_hash(cap, tmp / "outside", good)
    out = tmp / "o"
    rc, lines, stdout = infer([cap, good, "--model", model_path, "--out", out], capsys)
    assert rc in (0, 1)
    assert f"{good} ->" in stdout and (out / "good" / "summary.json").is_file()  # the batch went on
    if rc == 1:
        assert len(lines) == 2 and lines[0].startswith(f"aat-infer: FAILED {cap}: ") and "1 of 2" in lines[1], lines
        why = lines[0][len(f"aat-infer: FAILED {cap}: "):]
        assert why.startswith(str(cap)) and "unexpected" not in why, why  # names the capture or a file in it
    else:
        assert not lines and (out / "cap" / "summary.json").is_file()
        # png_small is bad only beside frames of another size: frames all of one small size are a capture
        same_size = {"png_small"} if set(kinds) == {"png_small"} else set()
        assert set(kinds) <= GOOD_KINDS | same_size | (SKIPPED_UNLISTED if sidecar == "none" else set()), (kinds,
                                                                                                         sidecar)
        assert sidecar in ("none", "list", "list_bom")
    if set(kinds) <= GOOD_KINDS and sidecar in ("list", "list_bom") and len(kinds) >= 2:
        assert rc == 0, lines  # good frames of any format and name, listed with distinct focus distances, run
    assert tree_hash(cap, tmp / "outside", good) == before  # inputs unchanged
    stray = [p for p in out.rglob(".*") if p.name != ".aat-output.json"] + [
        p for p in tmp.iterdir() if p.name.startswith(".")]
    assert not stray, stray  # no temporary left


# -- issue 31 leftover: every command that reads captures takes the readers' flags ---------------------------------
READER_COMMANDS = [("aat_deploy.cli.infer", [], ["--model", "m"]), ("aat_deploy.cli.eval", [], ["--model", "m", "--out", "o"]),
                   ("aat_deploy.cli.diagnose", [], ["--model", "m", "--out", "o"]),
                   ("aat_deploy.cli.capture", ["inspect"], []), ("aat_deploy.cli.capture", ["init"], []),
                   ("aat_deploy.cli.gt", ["check"], []), ("aat_deploy.cli.calibrate", ["fit"], ["--out", "c.json"])]


@pytest.mark.parametrize("module, sub, required", READER_COMMANDS,
                         ids=[f"{m.rsplit('.', 1)[1]} {' '.join(s)}".strip() for m, s, _ in READER_COMMANDS])
def test_every_command_that_reads_captures_takes_the_reader_flags(module, sub, required, capsys):
    """Before: aat-diagnose, aat-gt check, aat-capture init and aat-calibrate fit had neither --max-megapixels nor
    --allow-outside-links (only $AAT_MAX_MEGAPIXELS worked); now one definition (cli.common.add_reader_options) is
    shared by all, with one check of the value."""
    import importlib

    main = importlib.import_module(module).main
    with pytest.raises(SystemExit) as e:
        main([*sub, "--help"])
    out = capsys.readouterr().out
    assert e.value.code == 0 and "--max-megapixels MP" in out and "--allow-outside-links" in out
    with pytest.raises(SystemExit) as e:
        main([*sub, "x", *required, "--max-megapixels", "-1"])
    assert e.value.code == 2 and "--max-megapixels must be a positive number" in capsys.readouterr().err


def test_gt_check_and_capture_init_obey_the_reader_flags(good, tmp_path, capsys):
    """aat-gt check and aat-capture init refuse a frame linked out of the folder unless --allow-outside-links, and
    a frame or ground truth beyond --max-megapixels, in one line naming the file; inputs unchanged."""
    from aat_deploy.cli import capture as capture_cli
    from aat_deploy.cli import gt as gt_cli

    cap, earlier = good
    outside = write_dng_capture(tmp_path / "elsewhere", [0.6, 1.0, 2.0, 3.0])
    bad = tmp_path / "bad"
    shutil.copytree(cap, bad)
    for p in bad.glob("frame_*.dng"):
        p.unlink()
    (bad / "frame_00.dng").symlink_to(outside / "frame_03.dng")
    named = bad / "frame_00.dng"
    before = tree_hash(bad, outside, cap)
    assert gt_cli.main(["check", str(bad)]) == 1
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and f"{named}: a link out of the folder" in err[0] and "--allow-outside-links" in err[0]
    assert gt_cli.main(["check", str(bad), "--allow-outside-links"]) == 0
    assert "frames 64x48 px" in capsys.readouterr().out
    assert gt_cli.main(["check", str(cap), "--max-megapixels", "0.001"]) == 1
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and str(cap) in err[0] and "megapixels" in err[0], err

    assert capture_cli.main(["init", str(bad), "--focus-m", "2.0"]) == 1
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and f"{named}: a link out of the folder" in err[0] and not (bad / "capture.json").exists()
    assert capture_cli.main(["init", str(bad), "--focus-m", "2.0", "--max-megapixels", "0.001"]) == 1
    assert not (bad / "capture.json").exists()
    assert capture_cli.main(["init", str(bad), "--focus-m", "2.0", "--allow-outside-links", "-q"]) == 0
    assert json.loads((bad / "capture.json").read_text())["frames"] == [{"file": "frame_00.dng", "focus_m": 2.0,
                                                                          "from": "--focus-m"}]
    (bad / "capture.json").unlink()
    assert tree_hash(bad, outside, cap) == before


def test_diagnose_obeys_the_reader_flags(model_path, good, tmp_path, capsys):
    """aat-diagnose reads its captures with the same pixel limit and link rule as aat-eval."""
    from aat_deploy.cli import diagnose as diagnose_cli

    cap, earlier = good
    outside = write_dng_capture(tmp_path / "elsewhere", FOCUS)
    root = tmp_path / "root"
    shutil.copytree(cap, root / "a")
    (root / "a" / "gt_depth_mm.png").unlink()
    (root / "a" / "gt_depth_mm.png").symlink_to(outside / "gt_depth_mm.png")
    before = tree_hash(root, outside)
    lens = ["--lens", str(LENSES / "canon_rf50mm_f1.8.json")]
    rc = diagnose_cli.main([str(root), "--model", str(model_path), *lens, "--out", str(tmp_path / "d"), "-q"])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 1 and len(err) == 1 and f"{root / 'a' / 'gt_depth_mm.png'}: a link out of the folder" in err[0], err
    rc = diagnose_cli.main([str(root), "--model", str(model_path), *lens, "--out", str(tmp_path / "d"), "-q",
                            "--allow-outside-links", "--max-megapixels", "0.001"])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 1 and len(err) == 1 and "megapixels" in err[0] and str(root / "a") in err[0], err
    assert not (tmp_path / "d").exists() and tree_hash(root, outside) == before


def test_asking_for_the_any_camera_model_by_name_says_it_is_not_shipped_and_what_to_run(tmp_path):
    """`--model dfv_aat` (the issue's usage line) while models/dfv_aat.onnx is not shipped: the one-line error says
    so and names the candidate that runs by path (which exists)."""
    from aat_deploy.errors import ModelError
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.shipped import NOT_YET_SHIPPED, shipped_dir

    models = shipped_dir("models")
    if (models / "dfv_aat.onnx").is_file():
        pytest.fail("models/dfv_aat.onnx is shipped now: drop it from shipped.NOT_YET_SHIPPED")
    with pytest.raises(ModelError) as e:
        DfFModel("dfv_aat")
    msg = str(e.value)
    assert "\n" not in msg and "not shipped yet" in msg and "models/reproduce/dfv_aat_route_v12_v10.onnx" in msg
    cand = NOT_YET_SHIPPED["dfv_aat"].rsplit(": ", 1)[1]
    assert (models.parent / cand).is_file()  # the candidate it names exists
    with pytest.raises(ModelError) as e:
        DfFModel(tmp_path / "other.onnx")
    assert "not shipped yet" not in str(e.value)
