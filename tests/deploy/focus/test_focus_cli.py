"""`aat-infer --method focus`: outputs as the model path writes them, --focus-m, tied focus distances, --max-side,
--psf / --lens, one-line errors; the --focus-m reader under hypothesis."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import ROOT
from deploy_fixtures import write_dng_capture, write_png_capture
from hypothesis import given, settings
from hypothesis import strategies as st

from aat_deploy.capture.focuslist import MAX_FOCUS_M, parse_focus_list
from aat_deploy.cli.infer import main
from aat_deploy.errors import CaptureError
from aat_deploy.infer.pipeline import OUTPUT_FILES

FOCUS = [0.6, 0.75, 0.95, 1.3, 1.9, 3.0, 5.0]


def _err_lines(capsys) -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("aat-infer:")]


def test_focus_method_writes_the_model_paths_outputs(tmp_path, capsys):
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    out = tmp_path / "out"
    assert main([str(cap), "--method", "focus", "--out", str(out), "-q"]) == 0
    for name in OUTPUT_FILES + ("confidence.npy", "confidence.png"):
        assert (out / name).is_file(), name
    s = json.loads((out / "summary.json").read_text())
    assert s["model"]["method"] == "focus" and s["model"]["mapping"] == "thin_lens"
    assert s["method_info"]["frames"] == len(FOCUS) and s["ground_truth"]["pixels"] > 0
    d = np.load(out / "depth_m.npy")
    gt = np.load(cap / "gt_depth_m.npy")
    for plane in (0.8, 3.0):  # the fixture's two planes (weak blur: 2.5 px per diopter), inner pixels
        m = gt == plane
        m[:, 28:36] = False
        assert np.isfinite(d[m]).mean() > 0.5  # most of a textured plane is known (confident or filled)
        assert abs(1 / np.nanmedian(d[m]) - 1 / plane) < 0.1, (plane, np.nanmedian(d[m]))  # diopters


def test_focus_m_for_frames_without_metadata_and_its_errors(tmp_path, capsys):
    cap = write_png_capture(tmp_path / "png", FOCUS, sidecar=False)
    assert main([str(cap), "--method", "focus", "--out", str(tmp_path / "o1"), "-q"]) == 1
    err = _err_lines(capsys)
    assert len(err) == 2 and "no focus distance" in err[0] and "--focus-m" in err[0]
    fm = ",".join(str(f) for f in FOCUS)
    assert main([str(cap), "--method", "focus", "--focus-m", fm, "--out", str(tmp_path / "o2"), "-q"]) == 0
    s = json.loads((tmp_path / "o2" / "summary.json").read_text())
    assert {f["focus_source"] for f in s["frames"]} == {"--focus-m"}
    assert main([str(cap), "--method", "focus", "--focus-m", "0.6,0.8", "--out", str(tmp_path / "o3"), "-q"]) == 1
    err = _err_lines(capsys)
    assert "gives 2 focus distances for 7 frames" in err[0] and str(cap) in err[0]
    assert main([str(cap), "--method", "focus", "--focus-m", "0.6,x", "--out", str(tmp_path / "o4")]) == 2
    err = _err_lines(capsys)
    assert len(err) == 1 and "entry 2" in err[0]


def test_equal_reported_focus_is_a_warning_for_the_focus_method(tmp_path, tmp_path_factory, capsys):
    focus = [0.6, 0.75, 0.95, 0.95, 1.9, 3.0, 5.0]  # two frames alike, as coarse XMP metadata reports
    cap = write_png_capture(tmp_path / "cap", FOCUS)
    sidecar = json.loads((cap / "capture.json").read_text())
    for fr, f in zip(sidecar["frames"], focus):
        fr["focus_m"] = f
    (cap / "capture.json").write_text(json.dumps(sidecar))
    assert main([str(cap), "--method", "focus", "--out", str(tmp_path / "o"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "equal reported focus" in err
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    placed = {p["frame"]: p["placed_m"] for p in s["method_info"]["placements"]}
    assert len(placed) == 2 and len(set(round(v, 4) for v in s["method_info"]["focus_m_used"])) == 7
    # the model path still refuses them (a net cannot place frames)
    from deploy_fixtures import tiny_model_path

    model = tiny_model_path(tmp_path_factory)
    assert main([str(cap), "--model", str(model), "--out", str(tmp_path / "m"), "-q"]) == 1
    assert "duplicate focus distance" in capsys.readouterr().err


def test_max_side_reduces_the_working_size(tmp_path):
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    out = tmp_path / "o"
    assert main([str(cap), "--method", "focus", "--max-side", "32", "--out", str(out), "-q"]) == 0
    assert np.load(out / "depth_m.npy").shape == (24, 32)
    assert json.loads((out / "summary.json").read_text())["output_size_px"] == [32, 24]


def test_prefilter_px_reaches_the_method_and_its_record(tmp_path):
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    runs = {}
    for sigma in ("0", "2.5"):
        out = tmp_path / f"o{sigma}"
        assert main([str(cap), "--method", "focus", "--prefilter-px", sigma, "--out", str(out), "-q"]) == 0
        s = json.loads((out / "summary.json").read_text())
        assert s["method_info"]["config"]["prefilter_px"] == float(sigma)
        runs[sigma] = np.load(out / "confidence.npy")
    assert not np.array_equal(runs["0"], runs["2.5"])  # it changed what the measure saw


def test_focus_method_with_the_lens_psf(tmp_path):
    """--psf: the map stamped in the shipped surrogate (aberration-aware), the lens's focal length in the recording."""
    cap = write_dng_capture(tmp_path / "cap", FOCUS, lens="Canon RF50mm F1.8 STM (US 2021/0263286 A1, Example 1)")
    out = tmp_path / "o"
    assert main([str(cap), "--method", "focus", "--psf", str(ROOT / "models/psf_rf50.onnx"), "--out", str(out),
                 "-q"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["model"]["mapping"] == "aberration_aware" and s["method_info"]["best_focus_map"]["calibrated"]
    assert s["model"]["lens_name"].startswith("Canon RF50")
    assert any("frames are 64x48 px, the lens's sensor is 36x24 mm" in w for w in s["warnings"])  # 4:3 vs 3:2


def test_cli_misuse_is_one_line(tmp_path, capsys):
    cap = write_dng_capture(tmp_path / "cap", FOCUS)
    for argv, msg in (([str(cap)], "--model is required"),
                      ([str(cap), "--method", "focus", "--model", "m.onnx"], "uses no --model"),
                      # whether --lens fits depends on the model (the any-camera model takes it): asked of it
                      ([str(cap), "--model", "rf50_dfvnet_aat", "--lens", "canon_rf50mm_f1.8"], "is a lens-specific model"),
                      ([str(cap), "--method", "focus", "--max-side", "4"], "--max-side"),
                      ([str(cap), "--model", "m.onnx", "--prefilter-px", "1"], "belongs to --method focus"),
                      ([str(cap), "--method", "focus", "--prefilter-px", "-1"], "--prefilter-px")):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2 and msg in capsys.readouterr().err
    bad = tmp_path / "nolens.json"
    bad.write_text("{}")
    assert main([str(cap), "--method", "focus", "--lens", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = _err_lines(capsys)
    assert len(err) == 1 and "nolens.json" in err[0]
    assert main([str(cap), "--method", "focus", "--psf", str(ROOT / "models/reproduce/dff_dfvnet_aat.onnx")]) == 2
    err = _err_lines(capsys)
    assert len(err) == 1 and "not an aat PSF surrogate" in err[0]


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=60))
def test_focus_list_reader_never_fails_otherwise(text):
    try:
        out = parse_focus_list(text)
    except CaptureError as e:
        assert "\n" not in str(e) and str(e).startswith("--focus-m")
        return
    assert out and all(math.isfinite(v) and 0 < v <= MAX_FOCUS_M for v in out)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(min_value=1e-3, max_value=MAX_FOCUS_M, allow_nan=False), min_size=1, max_size=20),
       st.sampled_from([",", ", ", " ,"]))
def test_focus_list_round_trip(values, sep):
    assert parse_focus_list(sep.join(repr(v) for v in values)) == values
