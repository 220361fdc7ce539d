"""`aat-calibrate` end to end through files (run as `python -m aat_deploy.cli.calibrate`'s main): the chart, the
virtual camera shooting it into DNG sweep folders, the fit, and the one-line errors with nothing written."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest
from conftest import ROOT

from aat_deploy.calibrate import in_focus_diopters, load_calibration
from aat_deploy.cli import calibrate as cli
from aat_deploy.lens.io import load_lens, save_lens

W, H = 320, 214
SWEEPS = ((0.6, "12,3"), (1.0, "-10,0"))


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """A chart, a small RF50 (thin-lens PSFs at 320 x 214 px) and two shot sweeps of a copy whose reported focus
    is 1.1 x the true distance."""
    d = tmp_path_factory.mktemp("calib")
    lens = load_lens(ROOT / "lenses" / "canon_rf50mm_f1.8.json")
    lens = dataclasses.replace(lens, sensor=lens.sensor.with_resolution(W, H))
    save_lens(lens, d / "small_rf50.json")
    assert cli.main(["chart", "--out", str(d / "chart.png"), "--size-mm", "700,467", "--marker-mm", "45",
                     "--dpi", "30", "-q"]) == 0
    for i, (dist, tilt) in enumerate(SWEEPS):
        assert cli.main(["shoot", "--chart", str(d / "chart.png"), "--lens", str(d / "small_rf50.json"),
                         "--distance-m", str(dist), f"--tilt-deg={tilt}", "--effects",
                         "focus_metadata:bias_d=0:scale=1.1,noise", "--out", str(d / f"sweep{i}"), "-q"]) == 0
    return d


def test_chart_writes_image_and_layout_and_keeps_existing_files(rig, capsys):
    assert (rig / "chart.png").is_file() and json.loads((rig / "chart.json").read_text())["format"] == "aat-chart-v1"
    before = (rig / "chart.png").read_bytes()
    assert cli.main(["chart", "--out", str(rig / "chart.png"), "--dpi", "30", "-q"]) == 2
    assert "exists" in capsys.readouterr().err and (rig / "chart.png").read_bytes() == before
    assert cli.main(["chart", "--out", str(rig / "c2.png"), "--size-mm", "10,10", "--dpi", "30"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "px per module" in err[0] and not (rig / "c2.png").exists()


def test_shoot_writes_a_capture_with_the_copys_reported_focus(rig):
    info = json.loads((rig / "sweep0" / "virtual_camera.json").read_text())
    assert len(list((rig / "sweep0").glob("*.dng"))) == len(info["focus_true_m"]) >= 10
    np.testing.assert_allclose(info["focus_reported_m"], 1.1 * np.array(info["focus_true_m"]), rtol=1e-9)


def test_fit_from_dng_sweeps(rig, capsys):
    out = rig / "out" / "cam.json"
    rc = cli.main(["fit", str(rig / "sweep0"), str(rig / "sweep1"), "--chart", str(rig / "chart.json"),
                   "--distance-m", "0.6,1.0", "--out", str(out), "--boot", "20", "-q"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    summary = json.loads(cap.out.strip().splitlines()[-1])
    assert summary["focus_error"]["family"] == "scale" and abs(summary["focus_error"]["scale"] - 1.1) < 0.01
    assert out.is_file() and out.with_suffix(".png").is_file()
    cal = load_calibration(out)
    assert cal.camera.model == "virtual camera" and cal.size_px == (W, H)
    # the centre of a frame reported at 1.1 m is truly at 1.0 m
    assert float(in_focus_diopters(cal, [1.1], H, W)[0, H // 2, W // 2]) == pytest.approx(1.0, abs=0.01)
    assert cli.main(["show", str(out), "-q"]) == 0
    assert json.loads(capsys.readouterr().out)["focus_error"]["family"] == "scale"
    # an existing calibration is kept without --force
    before = out.read_bytes()
    assert cli.main(["fit", str(rig / "sweep0"), "--chart", str(rig / "chart.json"), "--out", str(out), "-q"]) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == before


def _copy_sweep(src, dst):
    shutil.copytree(src, dst)
    return dst


def test_bad_sweeps_are_one_line_errors_with_nothing_written(rig, tmp_path, capsys):
    """Markers not found (another chart's layout), frames from another camera inside a sweep, and sweeps of
    different cameras: one line each, exit 1, no calibration written."""
    out = tmp_path / "cam.json"
    other = json.loads((rig / "chart.json").read_text())
    for m in other["markers"]:
        m["id"] += 100
    (tmp_path / "other.json").write_text(json.dumps(other))
    rc = cli.main(["fit", str(rig / "sweep0"), "--chart", str(tmp_path / "other.json"), "--distance-m", "0.6",
                   "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and any("chart markers not found" in e for e in err) and not out.exists()
    assert err[-1].endswith("nothing written")
    # a frame of another lens (its DNG says so) inside sweep0
    lens = load_lens(rig / "small_rf50.json")
    other_lens = dataclasses.replace(lens, name="Another lens")
    save_lens(other_lens, tmp_path / "other_lens.json")
    assert cli.main(["shoot", "--chart", str(rig / "chart.png"), "--lens", str(tmp_path / "other_lens.json"),
                     "--distance-m", "1.0", "--out", str(tmp_path / "other_sweep"), "--step-d", "0.1", "-q"]) == 0
    mixed = _copy_sweep(rig / "sweep0", tmp_path / "mixed")
    shutil.copy(sorted((tmp_path / "other_sweep").glob("*.dng"))[0], mixed / "zz_other.dng")
    rc = cli.main(["fit", str(mixed), "--chart", str(rig / "chart.json"), "--distance-m", "0.6", "--out", str(out),
                   "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and any("from another camera" in e and "zz_other.dng" in e for e in err) and not out.exists()
    rc = cli.main(["fit", str(rig / "sweep1"), str(tmp_path / "other_sweep"), "--chart", str(rig / "chart.json"),
                   "--distance-m", "1.0,1.0", "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "from another camera" in err[0] and not out.exists()
    # a wrong number of distances is a usage error
    assert cli.main(["fit", str(rig / "sweep1"), "--chart", str(rig / "chart.json"), "--distance-m", "1,2",
                     "--out", str(out), "-q"]) == 2
    assert not out.exists()


def test_calibrate_cli_is_torch_free(rig, tmp_path):
    from deploy_fixtures import run_without_torch

    out = tmp_path / "cam.json"
    r = run_without_torch(f"""
        import sys
        from aat_deploy.cli import calibrate
        rc = calibrate.main(["fit", {str(rig / "sweep0")!r}, {str(rig / "sweep1")!r}, "--chart",
                             {str(rig / "chart.json")!r}, "--distance-m", "0.6,1.0", "--out", {str(out)!r},
                             "--boot", "5", "-q"])
        assert rc == 0, rc
        print(any(m == "torch" or m.startswith("torch.") for m in sys.modules))
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == "False" and out.is_file()


def test_infer_and_api_use_the_calibration(rig, tmp_path, capsys):
    """Depth of a chart sweep of the copy (reported focus 1.1 x the true distance) against its ground truth:
    with --calibration the error is a fraction of the nominal mapping's (which is ~10 % off in scale)."""
    from aat_deploy.api import depth_from_focus, read_stack
    from aat_deploy.cli import infer

    cam = rig / "out" / "cam.json"
    if not cam.is_file():
        assert cli.main(["fit", str(rig / "sweep0"), str(rig / "sweep1"), "--chart", str(rig / "chart.json"),
                         "--distance-m", "0.6,1.0", "--out", str(cam), "--boot", "10", "-q"]) == 0
    gt = np.load(rig / "sweep1" / "gt_depth_m.npy")
    maes = {}
    for name, extra in (("thin", []), ("cal", ["--calibration", str(cam)])):
        out = tmp_path / name
        assert infer.main([str(rig / "sweep1"), "--method", "focus", "--out", str(out), "--no-recording", "-q",
                           *extra]) == 0, capsys.readouterr().err
        d = np.load(out / "depth_m.npy")
        maes[name] = float(np.nanmean(np.abs(d - gt)))
        summary = json.loads((out / "summary.json").read_text())
    assert summary["model"]["mapping"] == "calibration" and summary["model"]["calibration"] == str(cam)
    assert maes["cal"] < 0.3 * maes["thin"], maes
    assert maes["thin"] > 0.05  # the copy's scaled reported focus: ~10 % of 1 m
    stack, focus = read_stack(rig / "sweep1")
    res = depth_from_focus(stack, focus, method="focus", calibration=cam)
    assert float(np.nanmean(np.abs(res.depth_m - gt))) == pytest.approx(maes["cal"], rel=0.05)
    with pytest.raises(ValueError, match="lens-specific model"):
        depth_from_focus(stack[:8], focus[:8], model="rf50_dfvnet_aat", calibration=cam)
    # not with a lens-specific model; a broken file is one line
    with pytest.raises(SystemExit):
        infer.main([str(rig / "sweep1"), "--model", "rf50_dfvnet_aat", "--calibration", str(cam)])
    capsys.readouterr()
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert infer.main([str(rig / "sweep1"), "--method", "focus", "--calibration", str(bad), "--out",
                       str(tmp_path / "x"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a camera calibration" in err[0]


def test_capture_inspect_says_whether_the_camera_matches(rig, tmp_path, capsys):
    from aat_deploy.cli import capture

    cam = rig / "out" / "cam.json"
    if not cam.is_file():
        assert cli.main(["fit", str(rig / "sweep0"), str(rig / "sweep1"), "--chart", str(rig / "chart.json"),
                         "--distance-m", "0.6,1.0", "--out", str(cam), "--boot", "10", "-q"]) == 0
    capsys.readouterr()
    assert capture.main(["inspect", str(rig / "sweep1"), "--calibration", str(cam), "-q"]) == 0
    assert "matches the calibration's camera" in capsys.readouterr().out
    d = json.loads(cam.read_text())
    d["camera"]["lens"], d["camera"]["f_number"] = "Another lens", 4.0
    other = tmp_path / "other.json"
    other.write_text(json.dumps(d))
    assert capture.main(["inspect", str(rig / "sweep1"), "--calibration", str(other), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert any("lens" in m for m in rows[0]["calibration_mismatch"])
    assert any("f-number" in m for m in rows[0]["calibration_mismatch"])
    assert capture.main(["inspect", str(rig / "sweep1"), "--calibration", str(tmp_path / "none.json")]) == 2
    assert "missing" in capsys.readouterr().err


def _texture(rng, h: int, w: int) -> np.ndarray:
    """(H, W) in [0.1, 0.9]: noise at several scales (texture at every blur)."""
    import cv2

    t = sum(cv2.resize(rng.random((h // k + 1, w // k + 1)), (w, h), interpolation=cv2.INTER_CUBIC)
            for k in (1, 3, 9))
    return (0.1 + 0.8 * (t - t.min()) / (t.max() - t.min())).astype(np.float32)


@pytest.fixture(scope="module")
def scene(rig):
    """Not a chart: a textured staircase at 0.65 / 0.8 / 0.95 m (inside the calibrated 0.6-1.0 m) shot by the same
    copy (reported focus 1.1 x the true one), 8 frames even in diopters over 0.55-1.2 m (true)."""
    from aat_deploy.capture.virtual import shoot, write_capture
    from aat_deploy.render import effects as fx

    lens = load_lens(rig / "small_rf50.json")
    rng = np.random.default_rng(3)
    depth = np.full((H, W), 0.65, np.float32)
    depth[:, W // 3:] = 0.8
    depth[:, 2 * W // 3:] = 0.95
    rgb = np.stack([_texture(rng, H, W)] * 3) * 0.6
    true_m = 1.0 / np.linspace(1 / 1.2, 1 / 0.55, 8)
    frames, reported = shoot(lens, rgb, depth, true_m, [fx.spec(e) for e in fx.parse(
        "focus_metadata:bias_d=0:scale=1.1,noise")], seed=5)
    out = rig / "scene"
    write_capture(out, frames, reported, lens, depth, rgb, {"what": "a staircase through the copy"})
    return out, depth


def test_calibration_corrects_depth_of_a_scene_the_right_way(rig, scene, tmp_path, capsys):
    """A scene the fit never saw: without the calibration the depth follows the reported focus (1.1 x the true
    distance); with it (CLI and API alike) that scale is taken out, on every step of the staircase."""
    from aat_deploy.api import depth_from_focus, read_stack
    from aat_deploy.cli import infer

    cap, gt = scene
    cam = rig / "out" / "cam.json"
    if not cam.is_file():
        assert cli.main(["fit", str(rig / "sweep0"), str(rig / "sweep1"), "--chart", str(rig / "chart.json"),
                         "--distance-m", "0.6,1.0", "--out", str(cam), "--boot", "10", "-q"]) == 0
    ratio = {}
    for name, extra in (("thin", []), ("cal", ["--calibration", str(cam)])):
        out = tmp_path / name
        assert infer.main([str(cap), "--method", "focus", "--out", str(out), "--no-recording", "-q", *extra]) == 0, \
            capsys.readouterr().err
        d = np.load(out / "depth_m.npy")
        # per step of the staircase, the median depth over its truth (inner columns: away from the edges)
        ratio[name] = [float(np.nanmedian(d[20:-20, a + 15:b - 15] / gt[20:-20, a + 15:b - 15]))
                       for a, b in ((0, W // 3), (W // 3, 2 * W // 3), (2 * W // 3, W))]
        summary = json.loads((out / "summary.json").read_text())
        assert summary["model"]["mapping"] == ("calibration" if extra else "thin_lens")
    # on every step the calibration takes the reported focus's scale out (the 8-frame method's own few-% bias is
    # in both) and so comes at least 0.07 closer to the truth
    for t, c in zip(ratio["thin"], ratio["cal"]):
        assert t / c == pytest.approx(1.1, abs=0.015), ratio
        assert abs(c - 1.0) < abs(t - 1.0) - 0.07 and abs(c - 1.0) < 0.05, ratio
    stack, focus = read_stack(cap)
    np.testing.assert_allclose(np.sort(focus), np.sort(1.1 / np.linspace(1 / 1.2, 1 / 0.55, 8)), rtol=1e-3)
    api = depth_from_focus(stack, focus, method="focus", calibration=cam).depth_m
    np.testing.assert_allclose(np.nanmedian(api / gt), np.nanmedian(np.load(tmp_path / "cal" / "depth_m.npy") / gt),
                               rtol=0.01)
    # one mapping at a time: a calibration replaces the --lens map, it is not added to it
    capsys.readouterr()
    assert infer.main([str(cap), "--method", "focus", "--calibration", str(cam), "--lens", "rf50",
                       "--out", str(tmp_path / "both"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--calibration" in err[0] and not (tmp_path / "both").exists()


def test_aat_lens_focus_map_from_captures_is_the_same_fit(rig, tmp_path, capsys):
    """`aat-lens focus-map --from-captures` (the best-focus map command's front door for captures) runs
    `aat-calibrate fit` itself: the same calibration file, its maps beside it, its one-line errors under aat-lens's
    name, and an existing file kept without --force; prescription-only options are refused."""
    from training.cli.lens import main as lens_main

    common = ["--chart", str(rig / "chart.json"), "--distance-m", "0.6,1.0", "--boot", "5", "-q"]
    sweeps = [str(rig / "sweep0"), str(rig / "sweep1")]
    ref, out = tmp_path / "ref.json", tmp_path / "lens" / "cam.json"
    assert cli.main(["fit", *sweeps, "--out", str(ref), *common]) == 0
    capsys.readouterr()
    assert lens_main(["focus-map", "--from-captures", *sweeps, "--out", str(out), *common]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["calibration"] == str(out) and out.with_suffix(".png").is_file()
    a, b = (load_calibration(p).to_dict() for p in (ref, out))
    for d in (a, b):
        d["fit"].pop("created")
    assert a == b
    before = out.read_bytes()
    assert lens_main(["focus-map", "--from-captures", *sweeps, "--out", str(out), *common]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"aat-lens: error: {out}: exists") and out.read_bytes() == before
    assert lens_main(["focus-map", "--from-captures", *sweeps, "--out", str(out), "--force", *common]) == 0
    capsys.readouterr()
    for extra in (["--png", str(tmp_path / "m.png")], ["--stamp", "x.onnx"], ["--no-calibrate"]):
        assert lens_main(["focus-map", "--from-captures", *sweeps, "--out", str(tmp_path / "n.json"), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("aat-lens: error: --") and not (tmp_path / "n.json").exists()
    assert lens_main(["focus-map", "--from-captures", *sweeps]) == 2  # --out is required
    assert "needs --out" in capsys.readouterr().err
    # the missing chart: the fit's own message, under aat-lens's name
    assert lens_main(["focus-map", "--from-captures", *sweeps, "--out", str(tmp_path / "n.json"), "-q"]) == 2
    assert capsys.readouterr().err.strip() == "aat-lens: error: --chart chart.json is required (or --from-scenes)"
    # LENS and --from-captures together, neither, or a fit option with LENS: usage errors
    for argv in (["focus-map", "rf50", "--from-captures", *sweeps], ["focus-map"],
                 ["focus-map", "rf50", "--chart", str(rig / "chart.json")]):
        with pytest.raises(SystemExit) as e:
            lens_main(argv)
        assert e.value.code == 2
    capsys.readouterr()


def test_a_chart_distance_marked_fitted_is_found_by_the_fit(rig, tmp_path, capsys):
    """`--distance-m 0.6,~1.03`: the second chart (truly at 1.0 m) given 30 mm off as only a start; the fit finds
    its distance (the summary's `fitted_distances`, the file's per-sweep `distance_given_m`) and the map as with
    both measured. Every distance marked ~ is a usage error with nothing written."""
    out = tmp_path / "cam.json"
    rc = cli.main(["fit", str(rig / "sweep0"), str(rig / "sweep1"), "--chart", str(rig / "chart.json"),
                   "--distance-m", "0.6,~1.03", "--out", str(out), "--boot", "20", "-q"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    summary = json.loads(cap.out.strip().splitlines()[-1])
    (fd,) = summary["fitted_distances"]
    assert fd["given_m"] == pytest.approx(1.03) and abs(fd["chart_distance_m"] - 1.0) < 0.01, fd
    cal = load_calibration(out)
    per = cal.residuals["per_sweep"]
    assert per[0]["distance_from"] == "measured distance" and "distance_given_m" not in per[0]
    assert per[1]["distance_from"].startswith("fitted") and per[1]["chart_distance_m"] == fd["chart_distance_m"]
    assert cal.fit["distance_fitted"] == [1]
    assert float(in_focus_diopters(cal, [1.1], H, W)[0, H // 2, W // 2]) == pytest.approx(1.0, abs=0.01)
    # a bare ~: no tape at all, the start is the chart's marker pose (focal length from its perspective); the fit
    # finds the same distance as from the tape's start, and the file says where the start came from
    out2 = tmp_path / "cam2.json"
    rc = cli.main(["fit", str(rig / "sweep0"), str(rig / "sweep1"), "--chart", str(rig / "chart.json"),
                   "--distance-m", "0.6,~", "--out", str(out2), "--boot", "20", "-q"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    (fd2,) = json.loads(cap.out.strip().splitlines()[-1])["fitted_distances"]
    assert fd2["start_from"] == "marker pose" and fd["start_from"] == "--distance-m"
    assert fd2["given_m"] != pytest.approx(1.03) and abs(fd2["given_m"] - 1.0) < 0.05, fd2  # the pose's start
    assert abs(fd2["chart_distance_m"] - fd["chart_distance_m"]) < 0.0005 and abs(fd2["chart_distance_m"] - 1.0) < 0.01
    cal2 = load_calibration(out2)
    per2 = cal2.residuals["per_sweep"]
    assert per2[1]["distance_start_from"] == "marker pose" and "distance_start_from" not in per[1]
    assert per2[1]["distance_from"].startswith("fitted") and per2[1]["distance_given_m"] == fd2["given_m"]
    assert cal2.fit["distance_m"] == [0.6, None] and cal2.fit["distance_fitted"] == [1]
    assert float(in_focus_diopters(cal2, [1.1], H, W)[0, H // 2, W // 2]) == pytest.approx(1.0, abs=0.01)
    for every in ("~0.6,~1.0", "~,~", "~0.6,~"):
        with pytest.raises(SystemExit) as e:
            cli.main(["fit", str(rig / "sweep0"), str(rig / "sweep1"), "--chart", str(rig / "chart.json"),
                      "--distance-m", every, "--out", str(tmp_path / "none.json"), "-q"])
        assert e.value.code == 2 and "measure at least one" in capsys.readouterr().err.strip().splitlines()[-1]
        assert not (tmp_path / "none.json").exists()


def test_a_bare_fitted_distance_without_a_marker_pose_is_one_line_with_nothing_written(rig, tmp_path, capsys):
    """`--distance-m 0.6,~` where the second chart is square to the camera: with no EXIF focal length in pixels
    (no --sensor-mm) its perspective cannot give the focal length, so the markers give no pose to start from: one
    line naming the sweep folder, exit 1, nothing written."""
    square = tmp_path / "square"
    assert cli.main(["shoot", "--chart", str(rig / "chart.png"), "--lens", str(rig / "small_rf50.json"),
                     "--distance-m", "1.0", "--step-d", "0.1", "--effects", "focus_metadata:bias_d=0:scale=1.1",
                     "--out", str(square), "-q"]) == 0
    capsys.readouterr()
    out = tmp_path / "cam.json"
    rc = cli.main(["fit", str(rig / "sweep0"), str(square), "--chart", str(rig / "chart.json"),
                   "--distance-m", "0.6,~", "--out", str(out), "--boot", "20", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and not out.exists() and not out.with_suffix(".png").exists()
    (line,) = [e for e in err if e.startswith("aat-calibrate: error:")]
    assert f"{square}: a distance marked ~ alone starts from the chart's marker pose, and there is none" in line
    assert "too square" in line and "~D" in line and err[-1].endswith("nothing written")


def test_the_edge_degree_is_chosen_on_the_tiles_at_the_fitted_distance(rig, tmp_path, capsys, monkeypatch):
    """Where the edge powers' degree in focus is chosen (four sweeps or more, `model.refit_edge`), it is chosen
    again after the chart distances marked ~ are fitted: on the tiles' objects at the fitted distance, not at the
    start. Spied on two sweeps by marking every fit as one where the choice was asked (the rig has too few sweeps
    to ask it)."""
    from dataclasses import replace as dc_replace

    from aat_deploy.calibrate import fit as fit_mod

    seen = []
    real_fit_model = fit_mod.fit_model

    def asked(*a, **k):  # every fit looks like one whose edge degree was chosen
        return dc_replace(real_fit_model(*a, **k), edge_cv={"cells": 0})

    def spy(obs, f):
        seen.append(np.asarray(obs.object_d[obs.sweep == 1]).copy())
        return f

    monkeypatch.setattr(fit_mod, "fit_model", asked)
    monkeypatch.setattr(fit_mod, "refit_edge", spy)
    out = tmp_path / "cam.json"
    rc = cli.main(["fit", str(rig / "sweep0"), str(rig / "sweep1"), "--chart", str(rig / "chart.json"),
                   "--distance-m", "0.6,~1.03", "--out", str(out), "--boot", "5", "-q"])
    assert rc == 0, capsys.readouterr().err
    assert seen, "the edge degree was never chosen again after the distance fit"
    # the median tile's object distance (m): about 1 % short of the chart's axial distance on this tilted chart
    d_last = 1.0 / float(np.median(seen[-1]))
    fitted = load_calibration(out).residuals["per_sweep"][1]["chart_distance_m"]  # 0.999 (truly 1.0; start 1.03)
    assert abs(d_last - fitted) < 0.015 and 1.03 - d_last > 0.03, (d_last, fitted)
