"""aat-infer end to end on synthetic DNG/PNG captures with a tiny contract-following ONNX model."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
from deploy_fixtures import (
    build_tiny_dff,
    render_stack,
    tiny_model_path,
    write_dng_capture,
    write_png_capture,
)

from aat_deploy.capture.folder import read_capture
from aat_deploy.cli import infer as infer_cli
from aat_deploy.errors import CaptureError, ModelError, OutputError
from aat_deploy.infer.geometry import align_stack
from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.pipeline import Options, run_capture
from aat_deploy.io.marker import MARKER

FOCUS = [0.6, 0.8, 1.2, 2.0, 3.0, 4.5]
F32_EPS = float(np.finfo(np.float32).eps)


def _first(batch, column):
    """First row of a column, unwrapped from rerun's one-element component lists."""
    v = batch.column(column).to_pylist()[0]
    while isinstance(v, list) and len(v) == 1:
        v = v[0]
    return v


@pytest.fixture(scope="module")
def model(model_path):
    return DfFModel(model_path, threads=1)


@pytest.fixture
def dng_capture(tmp_path):
    return write_dng_capture(tmp_path / "scene", FOCUS)


def test_outputs_and_summary(model, dng_capture, tmp_path):
    out = tmp_path / "out"
    s = run_capture(dng_capture, model, out, Options(quiet=True))
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [MARKER, "aif.png",
         "depth_m.npy", "depth_m.tif", "depth_mm.png", "depth_color.png", "recording.rrd", "std_m.npy",
         "std_mm.png", "std_color.png", "points.ply", "camera.json", "summary.json"])
    depth = np.load(out / "depth_m.npy")
    assert depth.dtype == np.float32 and depth.shape == (48, 64)
    mm = cv2.imread(str(out / "depth_mm.png"), cv2.IMREAD_UNCHANGED)
    # half a millimetre of rounding, plus float32's own in depth * 1000 (half an ulp of the largest)
    assert mm.dtype == np.uint16
    assert np.abs(mm.astype(float) - depth * 1000.0).max() <= 0.5 + 1000 * depth.max() * F32_EPS
    aif = cv2.imread(str(out / "aif.png"), cv2.IMREAD_UNCHANGED)
    assert aif.dtype == np.uint8 and aif.shape == (48, 64, 3)
    assert np.load(out / "std_m.npy").shape == (48, 64)
    # the near half (0.8 m) comes out nearer than the far half (3 m), inside the focus range
    assert depth[:, :28].mean() < 1.2
    assert depth[:, 36:].mean() > 2.0
    slack = 2 * len(FOCUS) * F32_EPS * FOCUS[-1]  # a float32 convex combination of the focus distances
    assert FOCUS[0] - slack <= depth.min() and depth.max() <= FOCUS[-1] + slack
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["focus_m"] == pytest.approx(FOCUS)
    assert all(f["focus_source"] == "EXIF SubjectDistance" for f in on_disk["frames"])
    assert on_disk["model"]["aat.lens_name"] == model.lens_name and on_disk["model"]["path"]
    assert set(on_disk["timings_s"]) >= {"metadata", "decode", "geometry", "normalise", "infer", "write", "record",
                                         "total"}
    assert sorted(on_disk["outputs"]) == sorted(p.name for p in out.iterdir() if p.name != MARKER)
    assert on_disk["warnings"] == [] and s["ground_truth"]["pixels"] == 48 * 64


def test_recording_content(model, dng_capture, tmp_path):
    from rerun.chunk import RrdReader

    out = tmp_path / "out"
    run_capture(dng_capture, model, out, Options(quiet=True))
    chunks = list(RrdReader(out / "recording.rrd").stream().collect().stream())
    by_entity: dict[str, list] = {}
    for c in chunks:
        by_entity.setdefault(str(c.entity_path), []).append(c.to_record_batch())
    for e in ("/world/camera", "/world/camera/frames", "/world/camera/depth", "/world/camera/aif",
              "/world/camera/std_m", "/world/points", "/focus_m", "/world/camera/gt_depth"):
        assert e in by_entity, f"{e} missing from the recording"
    frames = by_entity["/world/camera/frames"][0]
    assert frames.num_rows == len(FOCUS) and "focus" in frames.schema.names
    assert frames.column("focus").to_pylist() == list(range(len(FOCUS)))
    scal = by_entity["/focus_m"][0].column("Scalars:scalars").to_pylist()
    assert [v[0] for v in scal] == pytest.approx(FOCUS)
    depth = by_entity["/world/camera/depth"][0]
    assert _first(depth, "DepthImage:meter") == pytest.approx(1.0)
    buf = np.frombuffer(bytes(_first(depth, "DepthImage:buffer")), np.float32)
    np.testing.assert_allclose(buf.reshape(48, 64), np.load(out / "depth_m.npy"))
    pin = next(b for b in by_entity["/world/camera"] if "Pinhole:image_from_camera" in b.schema.names)
    k = np.array(_first(pin, "Pinhole:image_from_camera")).reshape(3, 3)
    assert k.max() == pytest.approx(50.0 / 0.540, rel=1e-5)  # focal length mm / pixel pitch mm
    pts = by_entity["/world/points"][0].column("Points3D:positions").to_pylist()[0]
    pts = pts[0] if len(pts) == 1 else pts
    assert len(pts) == 48 * 64


def test_png_capture_with_sidecar_and_padding(tmp_path, tmp_path_factory):
    """Sensor 60x44 is not a multiple of 8: the runtime pads (reflect) and crops back."""
    m = DfFModel(tiny_model_path(tmp_path_factory, "tiny_60x44.onnx", **{"aat.sensor_px": [60, 44]}), threads=1)
    cap = write_png_capture(tmp_path / "pngs", FOCUS, h=66, w=90)  # 15:11 like 60x44, resized
    s = run_capture(cap, m, tmp_path / "o", Options(quiet=True))
    assert np.load(tmp_path / "o" / "depth_m.npy").shape == (44, 60)
    assert all(f["focus_source"] == "capture.json" for f in s["frames"])
    assert s["input_size_px"] == [90, 66] and s["output_size_px"] == [60, 44]


def test_sidecar_overrides_exif(model, dng_capture, tmp_path):
    (dng_capture / "capture.json").write_text(json.dumps(
        {"frames": [{"file": f"frame_{i:02d}.dng", "focus_m": f * 1.01} for i, f in enumerate(FOCUS)]}))
    cap = read_capture(dng_capture)
    assert [f.focus_source for f in cap.frames] == ["capture.json"] * len(FOCUS)
    assert [f.focus_m for f in cap.frames] == pytest.approx([f * 1.01 for f in FOCUS])


def test_frames_sorted_by_focus(model, tmp_path):
    names = ["c.dng", "a.dng", "b.dng"]
    cap = write_dng_capture(tmp_path / "shuffled", [2.0, 0.7, 1.1], names=names)
    s = run_capture(cap, model, tmp_path / "o", Options(quiet=True))
    assert [f["file"] for f in s["frames"]] == ["a.dng", "b.dng", "c.dng"]
    assert s["focus_m"] == pytest.approx([0.7, 1.1, 2.0])


def test_tiling_matches_whole_image(model, dng_capture, tmp_path):
    whole = run_capture(dng_capture, model, tmp_path / "a", Options(quiet=True, record=False))
    tiled = run_capture(dng_capture, model, tmp_path / "b", Options(quiet=True, record=False, tile=32))
    a, b = np.load(tmp_path / "a" / "depth_m.npy"), np.load(tmp_path / "b" / "depth_m.npy")
    # the tiny net sees 7x7 px: away from tile borders (most pixels) the same sums, up to float32 rounding in
    # other kernels for other shapes (~1e-6); blending keeps the rest within a few % (0.1 % seen)
    rel = np.abs(a - b) / a
    assert np.median(rel) < 1e-5 and rel.mean() < 0.05
    assert whole["tile"] is None and tiled["tile"] == 32


def test_align_undoes_breathing():
    """A 2 % zoom of one frame (focus breathing) is undone: the aligned frame is closer to the unzoomed one."""
    h, w = 48, 64
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    rng = np.random.default_rng(1)
    tex = np.full((h, w, 3), 0.4, np.float32)
    for _ in range(12):  # smooth structured texture (real scenes are not white noise)
        fx, fy = rng.uniform(-0.35, 0.35, 2)
        tex += np.sin(fx * xx + fy * yy + rng.uniform(0, 6.28))[..., None] * rng.uniform(0.02, 0.06, 3)
    depth = np.full((h, w), 3.0, np.float32)
    depth[:, :32] = 0.8
    frames = render_stack(tex, depth, [0.7, 0.9, 1.2])
    truth = frames[0]
    zoom = np.float32([[1.02, 0, -0.32 * 2], [0, 1.02, -0.24 * 2]])  # about the centre
    frames[0] = cv2.warpAffine(truth, zoom, (w, h), borderMode=cv2.BORDER_REFLECT)
    out, info = align_stack(frames, ref=1)
    assert info[0]["converged"] and info[1]["matrix"] == [[1, 0, 0], [0, 1, 0]]
    inner = (slice(4, -4), slice(4, -4))
    before = np.abs(frames[0] - truth)[inner].mean()
    after = np.abs(out[0] - truth)[inner].mean()
    assert after < 0.6 * before
    assert np.mean([info[0]["matrix"][0][0], info[0]["matrix"][1][1]]) == pytest.approx(1.02, rel=0.01)


def test_align_switch_in_pipeline(model, dng_capture, tmp_path):
    s = run_capture(dng_capture, model, tmp_path / "o", Options(quiet=True, record=False, align=True))
    assert len(s["align"]) == len(FOCUS) and s["timings_s"]["align"] >= 0


def test_existing_output_needs_force(model, dng_capture, tmp_path):
    out = tmp_path / "out"
    run_capture(dng_capture, model, out, Options(quiet=True, record=False))
    with pytest.raises(OutputError, match="exists"):
        run_capture(dng_capture, model, out, Options(quiet=True, record=False))
    run_capture(dng_capture, model, out, Options(quiet=True, record=False, force=True))  # its own earlier output
    (out / "notes.txt").write_text("the user's")
    with pytest.raises(OutputError, match="holds 'notes.txt', which aat-infer did not write"):
        run_capture(dng_capture, model, out, Options(quiet=True, record=False, force=True))
    assert (out / "notes.txt").read_text() == "the user's"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary folders left


def test_failure_leaves_no_output(model, dng_capture, tmp_path):
    (dng_capture / "frame_03.dng").write_bytes((dng_capture / "frame_03.dng").read_bytes()[:3000])
    with pytest.raises(CaptureError):
        run_capture(dng_capture, model, tmp_path / "out", Options(quiet=True))
    assert not (tmp_path / "out").exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


@pytest.mark.parametrize("case, message", [
    ("empty", "empty capture folder"),
    ("one", "at least two"),
    ("duplicate", "duplicate focus distance"),
    ("missing", "no focus distance"),
    ("sizes", "different sizes"),
    ("truncated_dng", "frame_01.dng"),
    ("truncated_png", "truncated PNG"),
    ("garbage", "img_1.png"),
    ("bad_sidecar", "capture.json"),
    ("sidecar_missing_file", "does not exist"),
    ("too_many_frames", "frames"),
])
def test_validation_errors(case, message, model, tmp_path):
    d = tmp_path / case
    if case == "empty":
        d.mkdir()
        (d / "notes.txt").write_text("x")
    elif case == "one":
        write_dng_capture(d, [1.0])
    elif case == "duplicate":
        write_dng_capture(d, [1.0, 2.0, 1.0])
    elif case == "missing":
        write_png_capture(d, [1.0, 2.0], sidecar=False)
    elif case == "sizes":
        write_png_capture(d, [1.0, 2.0])
        cv2.imwrite(str(d / "img_1.png"), np.zeros((40, 50, 3), np.uint16))
    elif case == "truncated_dng":
        write_dng_capture(d, [1.0, 2.0])
        (d / "frame_01.dng").write_bytes((d / "frame_01.dng").read_bytes()[:5000])
    elif case == "truncated_png":
        write_png_capture(d, [1.0, 2.0])
        (d / "img_1.png").write_bytes((d / "img_1.png").read_bytes()[:500])
    elif case == "garbage":
        write_png_capture(d, [1.0, 2.0])
        (d / "img_1.png").write_bytes(b"not a png at all" * 10 + b"IEND" + b"\0" * 8)
    elif case == "bad_sidecar":
        write_png_capture(d, [1.0, 2.0])
        (d / "capture.json").write_text('{"frames": [{"file": "img_0.png", "focus_m": -1}]}')
    elif case == "sidecar_missing_file":
        write_png_capture(d, [1.0, 2.0])
        (d / "capture.json").write_text('{"frames": [{"file": "nope.png", "focus_m": 1}, '
                                        '{"file": "img_0.png", "focus_m": 2}]}')
    elif case == "too_many_frames":
        write_png_capture(d, [0.5 + 0.1 * i for i in range(17)], h=24, w=32)
    with pytest.raises(CaptureError, match=message) as exc:
        run_capture(d, model, tmp_path / "out", Options(quiet=True))
    assert "\n" not in str(exc.value) and str(d) in str(exc.value)


def test_focus_outside_range_warns(model, tmp_path):
    cap = write_dng_capture(tmp_path / "far", [1.0, 2.0, 8.0])
    s = run_capture(cap, model, tmp_path / "o", Options(quiet=True, record=False))
    assert any("outside the model's range" in w and "8 m" in w for w in s["warnings"])


def test_other_lens_warns_and_strict_fails(model, tmp_path):
    cap = write_dng_capture(tmp_path / "other", [0.7, 1.4, 2.8], lens="Other 35mm f/2", focal_length_mm=35.0)
    s = run_capture(cap, model, tmp_path / "o", Options(quiet=True, record=False))
    assert any("is not the model's lens" in w for w in s["warnings"])
    assert any("focal length 35 mm" in w for w in s["warnings"])
    with pytest.raises(CaptureError, match="--strict"):
        run_capture(cap, model, tmp_path / "o2", Options(quiet=True, record=False, strict=True))


def test_model_errors(tmp_path):
    with pytest.raises(ModelError, match="no such model"):
        DfFModel(tmp_path / "nope.onnx")
    (tmp_path / "bad.onnx").write_bytes(b"garbage")
    with pytest.raises(ModelError, match="not a loadable ONNX"):
        DfFModel(tmp_path / "bad.onnx")
    build_tiny_dff(tmp_path / "psf.onnx", {"aat.kind": "psf_surrogate"})
    with pytest.raises(ModelError, match="not an aat depth-from-focus model"):
        DfFModel(tmp_path / "psf.onnx")


def test_cli_batch_continues_after_failure(model_path, dng_capture, tmp_path, capsys):
    bad = tmp_path / "bad"
    bad.mkdir()
    rc = infer_cli.main([str(dng_capture), str(bad), "--model", str(model_path), "--out", str(tmp_path / "o"),
                         "--threads", "1", "-q", "--no-recording"])
    err = capsys.readouterr().err
    assert rc == 1
    assert "FAILED" in err and "empty capture folder" in err and "Traceback" not in err
    assert (tmp_path / "o" / "scene" / "depth_m.npy").is_file()
    assert infer_cli.main([str(dng_capture), "--model", str(model_path), "--out", str(tmp_path / "o" / "scene"),
                           "-q"]) == 1  # exists without --force
    assert "--force" in capsys.readouterr().err


def test_cli_scripts_installed(model_path, dng_capture, tmp_path):
    """The console scripts run (single capture: --out is the output folder itself); bad model: exit 2."""
    out = tmp_path / "single"
    r = subprocess.run([sys.executable, "-m", "aat_deploy.cli.infer", str(dng_capture), "--model", str(model_path),
                        "--out", str(out), "--threads", "1"], check=False, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert (out / "recording.rrd").is_file() and "->" in r.stdout
    r = subprocess.run([sys.executable, "-m", "aat_deploy.cli.infer", str(dng_capture), "--model",
                        str(tmp_path / "missing.onnx")], check=False, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "missing.onnx" in r.stderr


def test_progress_covers_inference_tiles_and_writing(model, dng_capture, tmp_path, capsys):
    run_capture(dng_capture, model, tmp_path / "a", Options())
    err = capsys.readouterr().err
    assert "decode" in err and f"inference, {len(FOCUS)} frames of 64x48 px" in err and "writing outputs" in err
    run_capture(dng_capture, model, tmp_path / "b", Options(tile=32))
    err = capsys.readouterr().err
    assert "inference in tiles of 32 px" in err and "0/6" in err  # a bar over 2 x 3 tiles of 32 px
    run_capture(dng_capture, model, tmp_path / "c", Options(tile=32, quiet=True))
    assert capsys.readouterr().err == ""
