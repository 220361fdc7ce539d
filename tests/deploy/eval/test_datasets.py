"""Readers of the public benchmarks (`aat-eval --dataset`), each on a tiny fixture the test writes in that dataset's
published format (docs/datasets.md; never copied data), and the scoring conventions against hand-computed cases."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aat_deploy.cli.eval import main
from aat_deploy.eval.dataset_run import score_stack
from aat_deploy.eval.datasets import DatasetError, ddff12, fod500, need, open_dataset, zedd
from aat_deploy.io.color import linear_to_srgb

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from deploy_fixtures import render_stack, synthetic_scene  # noqa: E402

SHARED_BALLS = Path(__file__).resolve().parents[3] / "../shared/data/focal_stack_mobiledepth_balls"


def _extra(name: str):
    """An optional reader package (the datasets extra, in dev too): only its dataset's tests skip without it."""
    try:
        return __import__(name)
    except ImportError:
        return None


h5py, OpenEXR = _extra("h5py"), _extra("OpenEXR")
needs_h5py = pytest.mark.skipif(h5py is None, reason="the datasets extra (h5py) is not installed")
needs_exr = pytest.mark.skipif(OpenEXR is None, reason="the datasets extra (OpenEXR) is not installed")


def srgb8(linear: np.ndarray) -> np.ndarray:
    return np.rint(linear_to_srgb(linear) * 255).astype(np.uint8)


def scene(h: int = 48, w: int = 64, seed: int = 0, near: float = 0.8, far: float = 3.0):
    tex, depth = synthetic_scene(h, w, seed)
    depth = np.where(depth < 1, near, far).astype(np.float32)
    return tex, depth


def write_jpg(path: Path, linear: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".jpg", srgb8(linear)[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 98])
    assert ok
    path.write_bytes(buf.tobytes())


# -- DDFF-12 -----------------------------------------------------------------------------------------------------

def write_ddff(path: Path, n: int = 2, split: str = "val", with_disp: bool = True) -> np.ndarray:
    """An h5 as DDFF-12 / DFV publish it: stack_<split> (N, 10, H, W, 3) uint8, disp_<split> (N, H, W) float."""
    focus = ddff12.BF / ddff12.FOCUS_DISPARITY
    stacks, disps = [], []
    for i in range(n):
        tex, depth = scene(seed=i, near=0.9, far=2.5)
        stacks.append(np.stack([srgb8(f) for f in render_stack(tex, depth, list(focus), 6.0)]))
        disp = (ddff12.BF / depth).astype(np.float32)
        disp[:4] = 0.0  # unknown rows, as the RGB-D sensor leaves
        disps.append(disp)
    with h5py.File(path, "w") as f:
        f[f"stack_{split}"] = np.stack(stacks)
        if with_disp:
            f[f"disp_{split}"] = np.stack(disps)
    return np.stack(disps)


@needs_h5py
def test_ddff12_reader_reads_the_published_layout(tmp_path):
    disp = write_ddff(tmp_path / "my_ddff_trainVal.h5")
    ds = open_dataset("ddff12", tmp_path / "my_ddff_trainVal.h5")
    items = list(ds.items())
    assert len(ds) == 2 and [it.name for it in items] == ["val_0000", "val_0001"]
    it = items[0]
    np.testing.assert_allclose(it.focus_m, ddff12.BF / np.linspace(ddff12.BF / 0.5, ddff12.BF / 7, 10))
    assert it.focus_m[0] == pytest.approx(0.5) and it.focus_m[-1] == pytest.approx(7.0)
    assert len(it.frames) == 10 and it.frames[0].shape == (48, 64, 3) and it.frames[0].dtype == np.float32
    assert np.isnan(it.gt[:4]).all() and np.allclose(it.gt[4:], disp[0][4:])
    five = open_dataset("ddff12", tmp_path / "my_ddff_trainVal.h5", frames=[0, 2, 4, 6, 9])
    assert np.allclose(next(five.items()).focus_m, it.focus_m[[0, 2, 4, 6, 9]])


@needs_h5py
def test_ddff12_scored_in_disparity_by_aat_eval(tmp_path, capsys):
    write_ddff(tmp_path / "ddff.h5")
    out = tmp_path / "out"
    assert main(["--dataset", "ddff12", str(tmp_path / "ddff.h5"), "--method", "focus", "--out", str(out), "-q"]) == 0
    rep = json.loads((out / "metrics.json").read_text())
    assert rep["units"] == "disparity" and rep["dataset"]["split"] == "val"
    m = rep["overall"]["focus"]
    assert m["n_images"] == 2 and m["delta1"] > 0.8, m  # two textured planes: the classical method finds them
    assert 0 < m["rmse"] < 0.05  # disparity units (0.02 ... 0.28), not metres
    md = (out / "metrics.md").read_text()
    assert "disparity" in md and "| focus | 2 |" in md
    assert (out / "maps" / "focus" / "val_0000.png").is_file()
    assert "stack(s) (disparity)" in capsys.readouterr().out


def _calibration(tmp_path, scale: float, size_px=(64, 48)) -> Path:
    """A calibration with no field term whose reported focus distance is `scale` x the true one."""
    from aat_deploy.calibrate import CameraCalibration, CameraIdentity, FieldPoly, FocusError, save_calibration
    from aat_deploy.calibrate.format import poly_terms

    terms = poly_terms(2, constant=False)
    cal = CameraCalibration(CameraIdentity("aat", "test", "lens", 6.0, 2.0), size_px,
                            FocusError("scale", scale=scale) if scale != 1 else FocusError(),
                            FieldPoly(terms, np.zeros((len(terms), 1)), (0.1, 2.5)), None, (6.4, 4.8),
                            {"rms_d": 0.0}, {}, {"method": "test"})
    return save_calibration(cal, tmp_path / f"cam_{scale:g}.json")


@needs_h5py
def test_focus_method_on_a_dataset_takes_a_calibration(tmp_path, capsys):
    """--calibration maps the stacks' focus: an identity calibration scores as the nominal focus does, one saying the
    reported distances are 1.25 x the true ones makes every depth 1/1.25 (disparity 1.25 x: abs_rel about 0.25)."""
    write_ddff(tmp_path / "ddff.h5")
    scores = {}
    for name, extra in (("nominal", []), ("identity", ["--calibration", str(_calibration(tmp_path, 1.0))]),
                        ("scaled", ["--calibration", str(_calibration(tmp_path, 1.25))])):
        out = tmp_path / name
        assert main(["--dataset", "ddff12", str(tmp_path / "ddff.h5"), "--method", "focus", "--out", str(out), "-q",
                     *extra]) == 0, capsys.readouterr().err
        rep = json.loads((out / "metrics.json").read_text())
        scores[name] = rep["overall"]["focus"]
        assert rep["models"][0]["mapping"] == ("calibration" if extra else "thin_lens")
    assert scores["identity"]["abs_rel"] == pytest.approx(scores["nominal"]["abs_rel"], abs=0.01), scores
    assert scores["nominal"]["abs_rel"] < 0.08 and scores["scaled"]["abs_rel"] == pytest.approx(0.25, abs=0.06), scores
    capsys.readouterr()
    # refused in one line: without --method focus, on capture folders, a broken file
    with pytest.raises(SystemExit):
        main(["--dataset", "ddff12", str(tmp_path / "ddff.h5"), "--model", "rf50_dfvnet_aat", "--calibration",
              str(tmp_path / "cam_1.json"), "--out", str(tmp_path / "x")])
    assert "--calibration belongs to --method focus" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(tmp_path), "--model", "rf50_dfvnet_aat", "--calibration", str(tmp_path / "cam_1.json"),
              "--out", str(tmp_path / "y")])
    assert "--calibration belongs to --dataset" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text("{}")
    assert main(["--dataset", "ddff12", str(tmp_path / "ddff.h5"), "--method", "focus", "--calibration",
                 str(tmp_path / "bad.json"), "--out", str(tmp_path / "z"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a camera calibration" in err[0] and not (tmp_path / "z").exists()


@needs_h5py
def test_ddff12_errors_are_one_line(tmp_path):
    write_ddff(tmp_path / "a.h5", split="train")
    with pytest.raises(DatasetError, match=r"a\.h5: no dataset 'stack_val' \(stacks in this file: stack_train\)"):
        open_dataset("ddff12", tmp_path / "a.h5")
    (tmp_path / "b.h5").write_bytes(b"not hdf5 at all")
    with pytest.raises(DatasetError, match=r"b\.h5: not a readable HDF5 file"):
        open_dataset("ddff12", tmp_path / "b.h5")
    with pytest.raises(DatasetError, match="frames"):
        open_dataset("ddff12", tmp_path / "a.h5", split="train", frames=[3, 1])
    for e in ("x",):
        with pytest.raises(DatasetError, match="split"):
            open_dataset("ddff12", tmp_path / "a.h5", split=e)


@needs_h5py
def test_ddff12_float_stacks_and_the_test_split_without_ground_truth(tmp_path, capsys):
    """DFV's file stores the 8-bit codes as floats 0-255: read as the same frames. stack_test has no disp_test (the
    benchmark's server holds it): shown, not scored."""
    write_ddff(tmp_path / "u8.h5", n=1)
    with h5py.File(tmp_path / "u8.h5") as f, h5py.File(tmp_path / "f32.h5", "w") as g:
        g["stack_val"] = f["stack_val"][()].astype(np.float32)
        g["disp_val"] = f["disp_val"][()]
        g["stack_test"] = f["stack_val"][()]
    a = next(open_dataset("ddff12", tmp_path / "u8.h5").items())
    b = next(open_dataset("ddff12", tmp_path / "f32.h5").items())
    assert all(np.array_equal(fa, fb) for fa, fb in zip(a.frames, b.frames))
    test = open_dataset("ddff12", tmp_path / "f32.h5", split="test")
    it = next(test.items())
    assert it.name == "test_0000" and it.gt is None and len(it.frames) == 10
    out = tmp_path / "out"
    assert main(["--dataset", "ddff12", str(tmp_path / "f32.h5"), "--split", "test", "--method", "focus", "--out",
                 str(out), "-q"]) == 0
    rep = json.loads((out / "metrics.json").read_text())
    assert rep["shown_without_ground_truth"] == ["test_0000"] and rep["overall"]["focus"]["n_images"] == 0


def test_a_missing_reader_package_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "h5py", None)  # import h5py raises ImportError
    with pytest.raises(DatasetError) as e:
        need("h5py", "reading DDFF-12's .h5 files")
    assert 'aat-dff[datasets]' in str(e.value) and "\n" not in str(e.value)


def test_scoring_conventions_against_hand_computed_cases():
    """A perfect depth scores 0 in disparity; twice the depth halves the disparity: AbsRel exactly 0.5, delta1 0
    (ratio 2 > 1.25); FoD500's clip at 1.5 m makes a far miss count only up to the clip."""
    gt_disp = np.full((4, 6), 0.1, np.float32)
    gt_disp[0, 0] = np.nan  # unknown
    depth = (ddff12.BF / gt_disp).astype(np.float32)
    depth[0, 0] = 1.0
    ds = ddff12.DDFF12.__new__(ddff12.DDFF12)  # only its conventions are used
    crop = (0, 0, 6, 4)
    row, _, _ = score_stack(depth, gt_disp, None, (6, 4), crop, ds, "gt")
    assert row["n_valid"] == 23 and row["mse"] == pytest.approx(0.0, abs=1e-12)
    row, _, _ = score_stack(2 * depth, gt_disp, None, (6, 4), crop, ds, "gt")
    assert row["abs_rel"] == pytest.approx(0.5) and row["delta1"] == 0.0 and row["mae"] == pytest.approx(0.05)
    half = depth.copy()
    half[:2] = np.nan  # a method's unknown pixels: scored where it answers, the share reported
    row, _, _ = score_stack(half, gt_disp, None, (6, 4), crop, ds, "gt")
    assert row["n_valid"] == 12 and row["coverage"] == pytest.approx(12 / 23) and row["mse"] == pytest.approx(0.0)
    fod = fod500.FoD500.__new__(fod500.FoD500)
    gt = np.full((4, 6), 1.0, np.float32)
    row, _, _ = score_stack(np.full((4, 6), 5.0, np.float32), gt, None, (6, 4), crop, fod, "gt")
    assert row["mae"] == pytest.approx(0.5)  # 5 m clipped to 1.5 m


# -- FoD500 ------------------------------------------------------------------------------------------------------

def write_exr(path: Path, depth: np.ndarray) -> None:
    d = depth.astype(np.float16)
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"R": d, "G": d, "B": d}) as f:
        f.write(str(path))


def write_fod(folder: Path, scenes=(10, 400, 401)) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for sid in scenes:
        tex, depth = scene(seed=sid, near=0.2, far=0.9)
        for k, f in enumerate(render_stack(tex, depth, list(fod500.FOCUS_M), 1.5)):
            assert cv2.imwrite(str(folder / f"{sid:06d}{k:02d}All.tif"), srgb8(f)[..., ::-1])
        write_exr(folder / f"{sid:06d}Dpt.exr", depth)


@needs_exr
def test_fod500_reader_and_eval(tmp_path):
    write_fod(tmp_path / "fod")
    ds = open_dataset("fod500", tmp_path / "fod")
    assert len(ds) == 2  # scenes 400, 401: the test split; scene 10 is training
    it = next(ds.items())
    assert it.name == "000400" and list(it.focus_m) == [0.1, 0.15, 0.3, 0.7, 1.5]
    assert it.info["files"][0] == "00040000All.tif" and it.gt.dtype == np.float32
    assert set(np.unique(it.gt)) == {np.float32(np.float16(0.2)), np.float32(np.float16(0.9))}
    assert len(open_dataset("fod500", tmp_path / "fod", split="train")) == 1
    out = tmp_path / "out"
    assert main(["--dataset", "fod500", str(tmp_path / "fod"), "--method", "focus", "--out", str(out), "-q"]) == 0
    rep = json.loads((out / "metrics.json").read_text())
    assert rep["units"] == "depth_m" and rep["dataset"]["clip"] == [0.0, 1.5]
    assert rep["overall"]["focus"]["n_images"] == 2 and np.isfinite(rep["overall"]["focus"]["abs_rel"])


@needs_exr
def test_fod500_errors(tmp_path):
    write_fod(tmp_path / "fod", scenes=(400,))
    (tmp_path / "fod" / "00040004All.tif").unlink()
    with pytest.raises(DatasetError, match=r"scene 000400 has 4 \*All\.tif images, FoD500 has 5"):
        open_dataset("fod500", tmp_path / "fod")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="no FoD500 images"):
        open_dataset("fod500", tmp_path / "empty")
    (tmp_path / "bad.exr").write_bytes(b"\x76\x2f\x31\x01 broken")
    with pytest.raises(DatasetError, match=r"bad\.exr: not a readable OpenEXR file"):
        fod500.read_exr_depth(tmp_path / "bad.exr")


# -- ZEDD --------------------------------------------------------------------------------------------------------

RUNS = [0.82, 1.0, 1.25, 1.6, 2.1, 2.9, 4.0, 5.6, 8.1]


def write_zedd(root: Path, aperture: float = 2.8) -> None:
    root.mkdir(parents=True)
    codes = [f"{0x6D3E - 300 * i:04X}" for i in range(9)]
    (root / "metadata.txt").write_text("# run\tmotor\tfocus (m)\n" + "".join(
        f"run_{i + 1}\t{c}\t{f}\n" for i, (c, f) in enumerate(zip(codes, RUNS))))
    for split, gt in (("val", True), ("test", False)):
        tex, depth = scene(h=64, w=96, seed=7, near=1.1, far=3.5)
        folder = root / split / f"{split}_0001"
        for i, f in enumerate(render_stack(tex, depth, RUNS, 4.0)):
            write_jpg(folder / "focus_stack" / f"img_run_{i + 1}_motor_{codes[i]}_aperture_F{aperture:.1f}.jpg", f)
        (folder / "gt").mkdir()
        np.savetxt(folder / "gt" / "K.txt", np.eye(3))
        if gt:
            np.save(folder / "gt" / "depth.npy", depth)


def test_zedd_reader_and_eval(tmp_path):
    write_zedd(tmp_path / "ZEDD")
    ds = open_dataset("zedd", tmp_path / "ZEDD")
    it = next(ds.items())
    assert ds.describe()["runs"] == [1, 3, 5, 7, 9] and list(it.focus_m) == RUNS[::2]
    assert it.info["files"][0].startswith("img_run_1_motor_6D3E_aperture_F2.8")
    assert it.gt.shape == (64, 96)
    out = tmp_path / "out"
    assert main(["--dataset", "zedd", str(tmp_path / "ZEDD"), "--method", "focus", "--out", str(out), "-q"]) == 0
    assert json.loads((out / "metrics.json").read_text())["overall"]["focus"]["n_images"] == 1
    out2 = tmp_path / "out_test"  # the test split's ground truth is hidden: shown, not scored
    assert main(["--dataset", "zedd", str(tmp_path / "ZEDD"), "--split", "test", "--method", "focus",
                 "--out", str(out2), "-q"]) == 0
    rep = json.loads((out2 / "metrics.json").read_text())
    assert rep["shown_without_ground_truth"] == ["test_0001"] and rep["overall"]["focus"]["n_images"] == 0
    assert (out2 / "maps" / "focus" / "test_0001.png").is_file()


def test_zedd_errors(tmp_path, capsys):
    write_zedd(tmp_path / "ZEDD")
    with pytest.raises(DatasetError, match="aperture F3"):
        open_dataset("zedd", tmp_path / "ZEDD", aperture=3.0)
    out = tmp_path / "out"  # a missing frame fails that scene on one line; the exit status says so
    assert main(["--dataset", "zedd", str(tmp_path / "ZEDD"), "--aperture", "1.4", "--method", "focus",
                 "--out", str(out), "-q"]) == 1
    err = capsys.readouterr().err
    assert "img_run_1_motor_6D3E_aperture_F1.4.jpg: missing" in err
    (tmp_path / "ZEDD" / "metadata.txt").write_text("run_1\t6D3E\t0.82\nrun_2 oops\n")
    with pytest.raises(DatasetError, match=r"metadata\.txt:2: not 'run_<n> <motor hex> <focus m>'"):
        open_dataset("zedd", tmp_path / "ZEDD")


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=200))
def test_zedd_metadata_reader_never_fails_otherwise(tmp_path_factory, text):
    p = tmp_path_factory.mktemp("meta") / "metadata.txt"
    p.write_bytes(text.encode("utf-8", "replace"))
    try:
        runs = zedd.read_metadata(p)
    except DatasetError as e:
        assert "\n" not in str(e) and str(p) in str(e)
    else:
        assert runs and all(0 < f <= 1000 for _, f in runs.values())


# -- Mobile Depth ------------------------------------------------------------------------------------------------

def write_mobile(folder: Path, layout: str) -> list[float]:
    tex, depth = scene(seed=3, near=0.6, far=2.0)
    focus = [0.5, 0.7, 1.0, 1.5, 3.0]
    values = [10.0, 15.0, 23.0, 58.0, 7.2e6][::-1]  # the dataset's units; larger = farther, stored far first
    frames = render_stack(tex, depth, focus[::-1], 3.0)
    for i, f in enumerate(frames):
        write_jpg(folder / (f"a{i}.jpg" if layout == "dfv" else f"{i:02d}.jpg"), f)
    name = "focus_dpth.txt" if layout == "dfv" else "focus_distance.txt"
    (folder / name).write_text("\n".join(f"{v:g}" for v in values) + "\n")
    return values


@pytest.mark.parametrize("layout", ["dfv", "wild"])
def test_mobile_depth_is_shown_not_scored(tmp_path, layout):
    values = write_mobile(tmp_path / "md" / "balls", layout)
    ds = open_dataset("mobile_depth", tmp_path / "md")
    it = next(ds.items())
    assert it.gt is None and it.info["focus_values"] == sorted(values)
    assert it.info["files"][0] == ("a4.jpg" if layout == "dfv" else "04.jpg")  # nearest first
    assert np.all(np.diff(it.focus_m) > 0)
    out = tmp_path / "out"
    assert main(["--dataset", "mobile_depth", str(tmp_path / "md"), "--method", "focus", "--out", str(out),
                 "-q"]) == 0
    rep = json.loads((out / "metrics.json").read_text())
    assert rep["shown_without_ground_truth"] == ["balls"] and (out / "maps" / "focus" / "balls.png").is_file()
    assert "not scored" in (out / "metrics.md").read_text()


def test_mobile_depth_errors(tmp_path):
    write_mobile(tmp_path / "s", "dfv")
    (tmp_path / "s" / "focus_dpth.txt").write_text("1\n2\n")
    with pytest.raises(DatasetError, match=r"focus_dpth\.txt: 2 focus values for 5 frames"):
        list(open_dataset("mobile_depth", tmp_path / "s").items())
    (tmp_path / "none").mkdir()
    with pytest.raises(DatasetError, match="no Mobile Depth scene"):
        open_dataset("mobile_depth", tmp_path / "none")


def test_mobile_depth_metals_runs_the_other_way(tmp_path):
    """In "metals" the dataset's focus values grow towards the camera (DFV's evaluation negates them): ordered near
    to far all the same."""
    values = write_mobile(tmp_path / "md" / "metals", "dfv")
    (tmp_path / "md" / "metals" / "focus_dpth.txt").write_text("\n".join(f"{-v:g}" for v in values) + "\n")
    it = next(open_dataset("mobile_depth", tmp_path / "md").items())
    assert it.info["files"][0] == "a4.jpg" and it.info["focus_values"] == [-v for v in sorted(values)]


def test_dataset_frames_obey_the_pixel_limit(tmp_path, capsys):
    """aat-eval --dataset reads image files with the frame reader's pixel limit (--max-megapixels): a stack beyond
    it fails on one line naming the file (exit status 1)."""
    write_zedd(tmp_path / "ZEDD")
    out = tmp_path / "out"
    assert main(["--dataset", "zedd", str(tmp_path / "ZEDD"), "--method", "focus", "--out", str(out), "-q",
                 "--max-megapixels", "0.001"]) == 1
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert any("img_run_1_motor_6D3E_aperture_F2.8.jpg" in ln and "megapixels" in ln for ln in err), err
    assert main(["--dataset", "zedd", str(tmp_path / "ZEDD"), "--method", "focus", "--out", str(tmp_path / "o2"),
                 "-q", "--max-megapixels", "1"]) == 0


@pytest.mark.skipif(not SHARED_BALLS.is_dir(), reason="../shared/data/focal_stack_mobiledepth_balls is absent")
def test_mobile_depth_reads_the_real_balls_stack():
    ds = open_dataset("mobile_depth", SHARED_BALLS)
    it = next(ds.items())
    assert len(it.frames) == 10 and it.info["files"][0] == "09.jpg" and it.info["files"][-1] == "00.jpg"
    assert it.frames[0]().shape == (720, 1280, 3)


def test_cli_misuse_is_one_line(tmp_path, capsys):
    write_mobile(tmp_path / "md", "dfv")
    with pytest.raises(SystemExit):
        main(["--dataset", "mobile_depth", str(tmp_path / "md"), "--out", str(tmp_path / "o")])  # no method
    assert "--method focus" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(tmp_path / "md"), "--method", "focus", "--out", str(tmp_path / "o")])  # --method needs --dataset
    assert main(["--dataset", "fod500", str(tmp_path / "md"), "--method", "focus", "--out", str(tmp_path / "o"),
                 "-q"]) == 2
    assert "no FoD500 images" in capsys.readouterr().err
