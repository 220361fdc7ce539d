"""The any-camera model at run time (aat_deploy.anycam.model, the aat-infer and API paths): it is opened as such from
its metadata, takes its camera from --camera / a lens file / EXIF, refuses in one line what it cannot know, runs
on any stack size the model declares, and reduces the working size so the blur stays in its range."""

import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from aat_deploy.anycam.model import K_MAX_PX_PER_D, FocusMapModel, mapping_from_args, open_model, own_tiles  # noqa: E402
from aat_deploy.errors import CaptureError  # noqa: E402
from aat_deploy.infer.model import DfFModel  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
RF50 = ROOT / "lenses" / "canon_rf50mm_f1.8.json"


@pytest.fixture(scope="module")
def anycam_model(tmp_path_factory) -> Path:
    from training.nets.dfvaat import build
    from training.nets.export import export_focus_map_onnx, focus_map_metadata

    torch.manual_seed(0)
    m = build()
    path = tmp_path_factory.mktemp("anycam") / "dfv_aat.onnx"
    md = focus_map_metadata(m, effects=[], stack_range=(3, 16), config_hash="test", k_range=(0.3, 64))
    export_focus_map_onnx(m, path, md, check_shapes=[(1, 3, 32, 64)])
    return path


def test_opened_as_the_any_camera_model(anycam_model, model_path):
    assert isinstance(open_model(anycam_model), FocusMapModel)
    assert type(open_model(model_path)) is DfFModel  # a lens-specific model stays one


def test_infer_with_a_lens_map_matches_the_torch_net(anycam_model):
    from training.nets.dfvaat import build, predict

    torch.manual_seed(0)
    net = build().eval()
    model = FocusMapModel(anycam_model, mapping=mapping_from_args(lens=RF50))
    model = model.bound(model.mapping_optics(96), [0.6, 1.0, 2.0, 5.0])
    rng = np.random.default_rng(0)
    stack = rng.random((4, 3, 64, 96), dtype=np.float32)
    focus = np.array([0.6, 1.0, 2.0, 5.0], np.float32)
    out = model.infer(stack, focus)
    maps = model.maps(focus, 64, 96)
    assert maps.shape == (5, 64, 96)
    assert maps[0, 0, 0] < maps[0, 32, 48]  # the RF50's corners focus farther (fewer diopters) than its centre
    ref = predict(net, torch.from_numpy(stack)[None], torch.from_numpy(maps[None, :4]), torch.from_numpy(maps[None, 4:]))
    assert np.abs(out.depth_m - ref["depth_m"][0].numpy()).max() < 1e-3 * 5.0
    tiled = model.infer(stack, focus, tile=64, overlap=16)
    assert np.abs(tiled.depth_m - out.depth_m).mean() < 0.2  # tiles see less context, the same scene


def test_working_size_keeps_the_blur_in_range(anycam_model):
    model = FocusMapModel(anycam_model).configure(camera="85,1.4,4.0", max_side=4000)
    cap = type("Cap", (), {"path": "cap", "frames": [type("F", (), {"focus_m": f, "meta": None})() for f in (1, 3)]})
    bound = model.for_capture(cap, (4000, 6000))
    w, h = bound.working_size((4000, 6000))
    assert bound.optics.defocus_px_per_d(bound._focus_mid_m, w) <= K_MAX_PX_PER_D * 1.01
    assert w < 6000 and abs(w / h - 1.5) < 0.01
    assert FocusMapModel(anycam_model).configure(camera="4.3,1.8,1.4").for_capture(cap, (300, 400)) \
        .working_size((300, 400)) == (400, 300)  # a phone's blur is small: nothing to reduce


def _capture(tmp_path, n=4):
    from deploy_fixtures import write_dng_capture

    return write_dng_capture(tmp_path / "cap", [0.5, 0.8, 1.4, 3.0, 6.0][:n], h=64, w=96)


def test_aat_infer_refuses_without_a_sensor_size_and_runs_with_camera(anycam_model, tmp_path, capsys):
    from aat_deploy.cli.infer import main

    cap = _capture(tmp_path)
    assert main([str(cap), "--model", str(anycam_model), "--out", str(tmp_path / "o1"), "-q", "--no-recording"]) == 1
    err = capsys.readouterr().err
    line = [ln for ln in err.splitlines() if "FAILED" in ln][0]
    assert "sensor size" in line and "--camera" in line
    assert not (tmp_path / "o1").exists()
    assert main([str(cap), "--model", str(anycam_model), "--out", str(tmp_path / "o2"), "-q", "--no-recording",
                 "--camera", "50,1.8,100"]) == 0
    s = json.loads((tmp_path / "o2" / "summary.json").read_text())
    assert s["model"]["focus_mapping"]["optics"]["source"] == "--camera"
    d = np.load(tmp_path / "o2" / "depth_m.npy")
    assert d.shape == (64, 96) and np.isfinite(d).all() and d.min() >= 0.5 - 1e-3 and d.max() <= 6.0 + 1e-3


def test_aat_infer_with_a_lens_map_and_flags_for_the_wrong_model(anycam_model, model_path, tmp_path, capsys):
    from aat_deploy.cli.infer import main

    cap = _capture(tmp_path, 5)
    assert main([str(cap), "--model", str(anycam_model), "--lens", str(RF50), "--out", str(tmp_path / "o"), "-q",
                 "--no-recording"]) == 0
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["model"]["focus_mapping"]["mapping"] == "best_focus"
    with pytest.raises(SystemExit):
        main([str(cap), "--model", str(model_path), "--camera", "50,1.8,4", "--out", str(tmp_path / "x"), "-q"])
    assert "lens-specific" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(cap), "--method", "focus", "--camera", "50,1.8,4", "--out", str(tmp_path / "y"), "-q"])


def test_api_takes_the_camera_and_refuses_without(anycam_model):
    from aat_deploy.api import depth_from_focus

    rng = np.random.default_rng(1)
    stack = rng.random((3, 64, 96, 3)).astype(np.float32)
    with pytest.raises(ValueError, match="needs the camera"):
        depth_from_focus(stack, [0.5, 1.0, 2.0], anycam_model)
    r = depth_from_focus(stack, [2.0, 0.5, 1.0], anycam_model, camera=(50, 1.8, 100))
    assert r.depth_m.shape == (64, 96) and r.model["focus_mapping"]["mapping"] == "thin_lens"
    r = depth_from_focus(stack, [0.5, 1.0, 2.0], anycam_model, lens=RF50)
    assert r.model["focus_mapping"]["mapping"] == "best_focus"
    with pytest.raises(ValueError):
        depth_from_focus(stack, [0.5, 1.0, 2.0], anycam_model, lens=RF50, calibration="x.json")
    with pytest.raises(ValueError, match="2 frames|takes 3"):
        depth_from_focus(stack[:2], [0.5, 1.0], anycam_model, camera=(50, 1.8, 100))


def test_mapping_errors_are_one_line(tmp_path):
    with pytest.raises(CaptureError) as e:
        mapping_from_args(lens=tmp_path / "missing.json")
    assert "\n" not in str(e.value)


def test_frames_larger_than_the_training_images_run_as_tiles_of_that_size(tmp_path):
    """aat.tile_px (the largest images the net trained on, training.train.export): a larger frame runs as overlapping
    tiles of that side, exactly as infer(tile=...) does; a frame no larger runs whole; tile=0 asks for whole frames."""
    from training.nets.dfvaat import build
    from training.nets.export import export_focus_map_onnx, focus_map_metadata
    from training.train.export import largest_training_image_px

    assert largest_training_image_px({"height": 128, "width": 128, "crop": 0}) == 128
    assert largest_training_image_px({"height": 160, "width": 160, "crop": 96, "mosaic": 0.6}) == 96
    torch.manual_seed(0)
    path = tmp_path / "tiled.onnx"
    md = focus_map_metadata(build(), effects=[], stack_range=(3, 16), config_hash="test", k_range=(0.3, 64),
                            extra={"tile_px": "64"})
    export_focus_map_onnx(build(), path, md, check_shapes=[(1, 3, 32, 64)])
    model = FocusMapModel(path, mapping=mapping_from_args(lens=RF50))
    assert model.tile_px == 64
    focus = np.array([0.6, 1.0, 2.0, 5.0], np.float32)
    model = model.bound(model.mapping_optics(128), focus)
    stack = np.random.default_rng(1).random((4, 3, 96, 128), dtype=np.float32)
    auto = model.infer(stack, focus).depth_m
    assert own_tiles(64) == (64, 8)  # an eighth overlapping (BENCHMARKS: no worse than a quarter, 23 % cheaper)
    assert np.array_equal(auto, model.infer(stack, focus, tile=64, overlap=8).depth_m)
    assert not np.array_equal(auto, model.infer(stack, focus, tile=64, overlap=16).depth_m)
    assert not np.array_equal(auto, model.infer(stack, focus, tile=0).depth_m)
    small = stack[:, :, :64, :64]
    assert np.array_equal(model.infer(small, focus).depth_m, model.infer(small, focus, tile=0).depth_m)


def test_tiles_run_in_batches_give_what_they_give_one_by_one(tmp_path, monkeypatch):
    """DfFModel.infer runs equal tiles several to one batch of the graph's B axis (TILE_BATCH_PX): every sample is
    computed on its own, so depth, all-in-focus and spread are those of one tile per run (to float rounding), and
    progress still counts tiles."""
    import aat_deploy.infer.model as infer_model
    from training.nets.dfvaat import build
    from training.nets.export import export_focus_map_onnx, focus_map_metadata

    torch.manual_seed(3)
    path = tmp_path / "m.onnx"
    md = focus_map_metadata(build(), effects=[], stack_range=(3, 16), config_hash="test", k_range=(0.3, 64))
    export_focus_map_onnx(build(), path, md, check_shapes=[(1, 3, 32, 64)])
    focus = np.array([0.6, 1.0, 2.0, 5.0], np.float32)
    model = FocusMapModel(path, mapping=mapping_from_args(lens=RF50))
    model = model.bound(model.mapping_optics(160), focus)
    stack = np.random.default_rng(2).random((4, 3, 96, 160), dtype=np.float32)
    seen = []
    batched = model.infer(stack, focus, tile=64, overlap=16, progress=lambda d, t: seen.append((d, t)))
    assert infer_model.TILE_BATCH_PX // 64**2 >= 6 and seen == [(i, 6) for i in range(1, 7)]  # 2 x 3 tiles, 1 run
    monkeypatch.setattr(infer_model, "TILE_BATCH_PX", 1)  # one tile per run
    single = model.infer(stack, focus, tile=64, overlap=16)
    for a, b in ((batched.depth_m, single.depth_m), (batched.aif, single.aif), (batched.std_m, single.std_m)):
        assert np.abs(a - b).max() <= 1e-5 * np.abs(b).max()
