"""The virtual camera writes capture folders that the runtime reads like a real camera's."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch
from conftest import ROOT

from aat_deploy.capture.folder import read_capture
from aat_deploy.capture.raw import load_raw
from aat_deploy.capture.virtual import BLACK_LEVEL, WHITE_LEVEL, mosaic_rggb, to_dn
from aat_deploy.io.color import linear_to_srgb
from aat_deploy.lens.io import load_lens
from aat_deploy.render import effects as fx
from training.cli.render import main as render_main
from training.render.simulator import Simulator
from training.render.sources import OnnxPSF


def test_mosaic_and_dn():
    rgb = np.stack([np.full((4, 4), v) for v in (0.1, 0.5, 0.9)])
    m = mosaic_rggb(rgb)
    assert m[0, 0] == 0.1 and m[0, 1] == 0.5 and m[1, 0] == 0.5 and m[1, 1] == 0.9  # exact: mosaicking copies
    span = WHITE_LEVEL - BLACK_LEVEL
    assert to_dn(np.array([0.0, 1.0, 2.0, 0.01, -0.01, -1.0])).tolist() == [
        BLACK_LEVEL, WHITE_LEVEL, WHITE_LEVEL, BLACK_LEVEL + round(0.01 * span), BLACK_LEVEL - round(0.01 * span), 0]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("scene")
    h, w = 320, 480  # scaled x2 to the RF50's 640 x 960 sensor
    yy, xx = np.mgrid[0:h, 0:w]
    lin = (0.25 + 0.2 * np.sin(xx / 7.0)[..., None] * np.array([1.0, 0.6, 0.3])
           + 0.15 * np.cos(yy / 11.0)[..., None]).astype(np.float32)
    cv2.imwrite(str(d / "rgb.png"), np.round(linear_to_srgb(lin)[..., ::-1] * 255).astype(np.uint8))
    depth = np.where(xx < w // 2, 1.2, 3.0).astype(np.float32)
    depth[:8, :8] = 0  # unknown
    np.save(d / "depth.npy", depth)
    return d


def test_aat_render_writes_a_capture_the_runtime_reads(scene, tmp_path, capsys):
    out = tmp_path / "cap"
    args = [str(scene / "rgb.png"), str(scene / "depth.npy"), "--lens", str(ROOT / "lenses/canon_rf50mm_f1.8.json"),
            "--focus-m", "2,1.2", "--out", str(out), "--psf", str(ROOT / "models/psf_rf50.onnx")]
    assert render_main(args) == 0
    cap = read_capture(out)
    assert sorted(f.focus_m for f in cap.frames) == [1.2, 2.0]  # exact: EXIF rationals 6/5, 2/1 -> float
    assert all("SubjectDistance" in f.focus_source for f in cap.frames)
    assert cap.gt_depth_m is not None and cap.gt_aif is not None
    gt = np.load(out / "gt_depth_m.npy")
    assert gt.shape == (640, 960) and gt[:16, :16].max() == 0
    assert np.allclose(np.unique(gt[20:, :]), [1.2, 3.0])
    mm = cv2.imread(str(out / "gt_depth_mm.png"), cv2.IMREAD_UNCHANGED)
    assert mm.dtype == np.uint16 and np.array_equal(mm, np.round(gt * 1000).astype(np.uint16))
    info = json.loads((out / "virtual_camera.json").read_text())
    assert info["effects"] == ["aberrations"] and info["psf"].endswith("psf_rf50.onnx")
    # Pixels: the developed RAW equals the rendered frame (demosaicking aside) in linear units.
    lens = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
    sim = Simulator(lens, OnnxPSF(ROOT / "models/psf_rf50.onnx", lens), fx.parse(["aberrations"]))
    srgb = cv2.imread(str(scene / "rgb.png"))[..., ::-1].astype(np.float32) / 255
    from aat_deploy.gt.holes import fill_holes
    from aat_deploy.infer.geometry import fit_rgbd_to_sensor
    from aat_deploy.io.color import srgb_to_linear

    rgb, depth = fit_rgbd_to_sensor(srgb_to_linear(srgb), np.load(scene / "depth.npy"), (640, 960))
    ref = sim.render_stack(torch.from_numpy(rgb.transpose(2, 0, 1).copy()), torch.from_numpy(fill_holes(depth)),
                           [1.2]).frames[0].numpy()
    near = next(f.path for f in cap.frames if f.focus_m == 1.2)
    got, _ = load_raw(near)
    inner = (slice(40, -40), slice(40, -40))
    for c in range(3):
        r = float(got[inner][..., c].mean() / ref[c][inner].mean())
        assert abs(r - 1) < 0.02, (c, r)
    # the existing folder is not overwritten
    with pytest.raises(SystemExit, match="exists"):
        render_main(args)


def test_list_effects(capsys):
    with pytest.raises(SystemExit) as e:  # an option like --version: exits before the required arguments
        render_main(["--list-effects"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for name in fx.names():
        assert name in out


def test_bad_input_is_one_line_and_force_replaces_atomically(scene, tmp_path):
    lens = str(ROOT / "lenses/canon_rf50mm_f1.8.json")
    base = [str(scene / "rgb.png"), str(scene / "depth.npy"), "--focus-m", "1", "--out", str(tmp_path / "c")]
    bad_lens = tmp_path / "bad.json"
    bad_lens.write_text("{not json")
    with pytest.raises(SystemExit, match=r"aat-render: error: .*bad\.json"):
        render_main(base + ["--lens", str(bad_lens)])
    with pytest.raises(SystemExit, match="aat-render: error: unknown effect 'fog'"):
        render_main(base + ["--lens", lens, "--effects", "fog"])
    with pytest.raises(SystemExit, match="aat-render: error: .*nothing.npy: no such depth file"):
        render_main([str(scene / "rgb.png"), str(tmp_path / "nothing.npy"), "--lens", lens, "--focus-m", "1",
                     "--out", str(tmp_path / "c")])
    assert not (tmp_path / "c").exists()  # nothing half-written
    out = tmp_path / "c"
    out.mkdir()
    (out / "mine.txt").write_text("user data")
    with pytest.raises(SystemExit, match="exists"):
        render_main(base + ["--lens", lens, "--thin-lens"])
    assert (out / "mine.txt").read_text() == "user data"
    with pytest.raises(SystemExit, match="not an earlier aat-render output"):  # --force replaces only its own
        render_main(base + ["--lens", lens, "--thin-lens", "--force"])
    assert (out / "mine.txt").read_text() == "user data"
    (out / "mine.txt").unlink()  # an empty folder may be replaced, and then an earlier capture
    assert render_main(base + ["--lens", lens, "--thin-lens", "--force"]) == 0
    assert render_main(base + ["--lens", lens, "--thin-lens", "--force"]) == 0  # an earlier aat-render output
    (out / "extra.txt").write_text("added to the last render by its owner")
    with pytest.raises(SystemExit, match="holds 'extra.txt', which aat-render did not write"):
        render_main(base + ["--lens", lens, "--thin-lens", "--force"])  # issue 31: never lost with --force
    assert (out / "extra.txt").exists() and len(list(out.glob("*.dng"))) == 1
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary left behind


def test_tiff_frames_skip_the_raw_pipeline(tmp_path):
    """frame_format="tiff": float32 linear frames exactly as rendered, focus distances from capture.json."""
    from aat_deploy.capture.virtual import write_capture

    lens = load_lens(ROOT / "lenses" / "canon_rf50mm_f1.8.json")
    frames = np.random.default_rng(0).random((3, 3, 8, 12)).astype(np.float32)
    out = write_capture(tmp_path / "cap", frames, [0.5, 1.0, 2.5], lens, np.ones((8, 12), np.float32), frames[0],
                        {}, frame_format="tiff")
    cap = read_capture(out)
    assert [f.focus_m for f in cap.frames] == pytest.approx([0.5, 1.0, 2.5])
    assert not list(out.glob("*.dng"))
    from aat_deploy.capture.raw import load_frame
    assert np.array_equal(load_frame(out / "frame_02.tif")[0].transpose(2, 0, 1), frames[2])
    with pytest.raises(ValueError, match="frame_format"):
        write_capture(tmp_path / "x", frames, [0.5, 1.0, 2.5], lens, None, None, {}, frame_format="png")


@pytest.mark.parametrize("peak", [0.5, 0.8, 0.95, 1.0])
def test_frames_develop_on_one_scale_whatever_their_brightest_pixel(tmp_path, peak):
    """LibRaw by default rescales a RAW whose brightest pixel exceeds 0.75 of the white level to that pixel
    (`adjust_maximum_thr`): frames of one stack then come out on different scales, by their content (the shipped
    sample's near frames 1.29 x too bright, which the diagnosis read as an exposure change and a focus error,
    issue 32). The runtime develops every frame against the file's white level."""
    from aat_deploy.capture.dng import write_dng
    from aat_deploy.capture.virtual import SENSOR_DNG

    yy, xx = np.mgrid[0:64, 0:96]
    lin = np.stack([0.2 + 0.1 * np.sin(xx / 5.0)] * 3).astype(np.float32)
    lin[:, 30:34, 40:44] = peak  # the frame's brightest spot
    path = tmp_path / "f.dng"
    write_dng(path, to_dn(mosaic_rggb(lin)), **SENSOR_DNG, subject_distance_m=1.0, focal_length_mm=50.0,
              f_number=2.0, make="aat", model="test", lens_model="test")
    got, _ = load_raw(path)
    inner = (slice(8, -8), slice(8, 28))  # away from the spot and the borders
    r = float(got[inner].mean() / lin.transpose(1, 2, 0)[inner].mean())
    assert abs(r - 1) < 0.01, r
