"""The real-stack gallery script (scripts/make_real_gallery.py): a method column added to its registry shows up in
the pictures and the page; display units of stacks without metric focus; the shared stacks when present."""

import importlib.util
import sys

import numpy as np
import pytest
from conftest import ROOT, SHARED


@pytest.fixture(scope="module")
def gallery():
    spec = importlib.util.spec_from_file_location("make_real_gallery", ROOT / "scripts/make_real_gallery.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["make_real_gallery"] = mod
    spec.loader.exec_module(mod)
    return mod


def toy_stack(gallery, kind="position"):
    """A textured plane whose in-focus frame runs from 0 (left) to 4 (right), frames blurred by defocus."""
    import cv2

    rng = np.random.default_rng(0)
    tex = rng.random((48, 80)).astype(np.float32)
    target = np.linspace(0, 4, 80)[None].repeat(48, 0)
    frames = []
    for k in range(5):
        sig = 0.3 + 1.5 * np.abs(target - k)
        lv = [cv2.GaussianBlur(tex, (0, 0), s) for s in np.linspace(0.3, 6.3, 16)]
        fr = np.choose(np.clip(np.rint((sig - 0.3) / 0.4).astype(int), 0, 15), lv)
        frames.append(np.repeat(fr[..., None], 3, 2))
    focus, off, sign = gallery._by_index(np.stack(frames))
    return gallery.RealStack("toy", "toy", "test", np.stack(frames).astype(np.float32), focus, "placeholders",
                             unit="frame", kind=kind, offset=off, sign=sign)


def test_frame_index_display_and_an_added_method_column(gallery, monkeypatch):
    st = toy_stack(gallery)
    col = gallery.focus_column(st, 640)
    idx = gallery.RealStack.display(st, col.depth)
    inner = np.isfinite(idx[:, 12:-12])
    assert inner.mean() > 0.5
    # the in-focus index follows the plane (0 at the left, 4 at the right) where known
    cols = np.nanmedian(np.where(inner, idx[:, 12:-12], np.nan), 0)
    assert np.corrcoef(np.arange(cols.size)[np.isfinite(cols)], cols[np.isfinite(cols)])[0, 1] > 0.9
    one = gallery.row_picture(st, {"focus": col})

    def twin(stack, max_side):  # another method: the same maps, as a model's column would come
        return gallery.Column(col.depth, col.aif, None, 0.01, ["a note"], None)

    monkeypatch.setitem(gallery.METHODS, "twin", ("another method", twin))
    two = gallery.row_picture(st, {"focus": col, "twin": twin(st, 640)})
    assert two.shape[0] == one.shape[0] and two.shape[1] > one.shape[1]
    page = gallery.page([(st, {"focus": col, "twin": twin(st, 640)}, "toy.png")], 640)
    assert "another method" in page and "a note" in page and "gallery/toy.png" in page


@pytest.mark.skipif(not (SHARED / "dfd_pair_breakfast_watanabe_nayar").is_dir(),
                    reason="../shared/data/dfd_pair_breakfast_watanabe_nayar absent (a clone without shared data)")
def test_the_script_on_a_shared_stack(gallery, tmp_path):
    assert gallery.main(["--out", str(tmp_path), "--stacks", "watanabe_nayar", "--max-side", "320"]) == 0
    assert (tmp_path / "gallery" / "watanabe_nayar.png").is_file()
    text = (tmp_path / "real_stacks.md").read_text()
    assert "0.529 and 0.869 m" in text and "two frames" in text


def test_camera_for_blur_gives_the_models_blur_growth(gallery):
    from aat_deploy.anycam.optics import CameraOptics

    focus = np.array([0.29, 0.4, 0.6, 1.0])
    f, n, pixel_um = gallery.camera_for_blur(8.0, focus)
    mid = 2.0 / (1 / focus.min() + 1 / focus.max())
    assert CameraOptics(f, n, pixel_um, 552, "test").defocus_px_per_d(mid, 552) == pytest.approx(8.0, rel=1e-9)
    # the pitch halves when the blur growth doubles
    assert gallery.camera_for_blur(16.0, focus)[2] == pytest.approx(pixel_um / 2, rel=1e-9)


def untrained_any_camera_model(path):
    """An untrained any-camera net exported as the shipped one is (needs torch): path."""
    torch = pytest.importorskip("torch")
    from training.nets.dfvaat import build
    from training.nets.export import export_focus_map_onnx, focus_map_metadata

    torch.manual_seed(0)
    net = build()
    export_focus_map_onnx(net, path, focus_map_metadata(net, effects=[], stack_range=(3, 16), config_hash="test",
                                                        k_range=(0.3, 64)), check_shapes=[(1, 3, 32, 64)])
    return path


def test_the_any_camera_column_runs_or_says_why(gallery, tmp_path):
    path = untrained_any_camera_model(tmp_path / "dfv_aat.onnx")
    st = toy_stack(gallery)
    assert gallery.dfv_aat_column(st, 640, path) == "not run: its optics are unknown"
    assert "not present" in gallery.dfv_aat_column(st, 640, tmp_path / "missing.onnx")
    st.defocus_px_per_d = 3.0
    col = gallery.dfv_aat_column(st, 640, path)
    assert isinstance(col, gallery.Column)
    assert col.depth.shape == col.aif.shape[1:] and col.aif.shape[0] == 3
    known = col.depth[np.isfinite(col.depth)]
    # an untrained net, but its depth is a blend of the frames' in-focus distances: inside the sweep
    assert known.size and known.min() >= st.focus_m.min() * 0.99 and known.max() <= st.focus_m.max() * 1.01
    cols = {"focus": gallery.focus_column(st, 640), "dfv_aat": "not run: two frames (the model takes 3 or more)"}
    assert gallery.row_picture(st, cols).shape[0] > 0
    assert "not run: two frames" in gallery.page([(st, cols, "toy.png")], 640)


def test_another_model_file_is_named_as_not_shipped(gallery, tmp_path):
    methods, note = gallery.model_methods(["focus", "dfv_aat"], gallery.DFV_AAT)
    assert note == "" and methods["dfv_aat"] == gallery.METHODS["dfv_aat"]
    cand = tmp_path / "dfv_aat_v9.onnx"
    methods, note = gallery.model_methods(["focus", "dfv_aat"], cand)
    assert list(methods) == ["focus", "dfv_aat"]
    assert methods["dfv_aat"][0] == "any-camera dfv_aat_v9 (not shipped)"
    assert "`dfv_aat_v9.onnx`" in note and "**not** the shipped" in note
    st = toy_stack(gallery)
    st.defocus_px_per_d = 3.0
    assert methods["dfv_aat"][1](st, 640) == "dfv_aat_v9.onnx not present (scripts/train_dfv_aat.sh, then export)"
    assert gallery.model_methods(["focus"], cand) == ({"focus": gallery.METHODS["focus"]}, "")


def test_depth_panels_of_a_stack_share_one_scale_and_the_page_its_columns(gallery):
    st = toy_stack(gallery, kind="depth")
    near = np.full((20, 30), 1.0)
    far = np.full((20, 30), 4.0)
    lo, hi = gallery.display_range(st, [near, far])
    assert lo == pytest.approx(1.0, rel=0.02) and hi == pytest.approx(4.0, rel=0.02)
    a = gallery.depth_panel(st, gallery.Column(near, None, None, 0.0), (lo, hi))
    b = gallery.depth_panel(st, gallery.Column(near, None, None, 0.0))  # its own scale: another colour
    assert not np.array_equal(a[5, 5], b[5, 5])
    col = gallery.Column(near, np.ones((3, 20, 30)), None, 0.5, [], 0.25)
    text = gallery.page([(st, {"focus": col}, "toy.png")], 640, {"focus": gallery.METHODS["focus"]}, "a note")
    header = next(line for line in text.splitlines() if line.startswith("| stack"))
    row = next(line for line in text.splitlines() if line.startswith("| toy"))
    assert header.count("|") == row.count("|") == 5 and "0.50 s, 25%" in row and "\na note\n" in text
    assert gallery.row_picture(st, {"focus": col}, height=100).shape[0] == 122


@pytest.mark.skipif(not (SHARED / "lightfield_lytro_real_epinet2067").is_dir(),
                    reason="../shared/data/lightfield_lytro_real_epinet2067 absent (a clone without shared data)")
def test_the_script_runs_a_candidate_model_beside_the_classical_method(gallery, tmp_path):
    path = untrained_any_camera_model(tmp_path / "cand.onnx")
    out = tmp_path / "g"
    assert gallery.main(["--out", str(out), "--stacks", "lytro_lightfield", "--methods", "focus,dfv_aat",
                         "--model", str(path), "--max-side", "160", "--panel-px", "100"]) == 0
    import cv2

    img = cv2.imread(str(out / "gallery" / "lytro_lightfield.png"))
    assert img.shape[0] == 122
    text = (out / "real_stacks.md").read_text()
    assert "any-camera cand (not shipped)" in text and "`cand.onnx`" in text
    row = next(line for line in text.splitlines() if line.startswith("| Lytro light field"))
    assert "not run" not in row and row.count(" s,") == 2  # both columns ran, with their times
    # the untrained file has no confidence calibration: no share of unknown pixels claimed for it
    assert row.rstrip(" |").endswith("s, no confidence")
