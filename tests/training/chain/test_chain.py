"""`aat-train --lens`: the whole chain on a tiny configuration for a lens that is not the RF50 (the EF50 double
Gauss on a 96 x 64 px sensor), killed during training and restarted; the runtime accepts the model for EF50
captures and warns on (or, strict, refuses) RF50 captures; unchanged stages are skipped, changed inputs rerun
what they feed (here under torchrun with 2 processes); fine-tuning from the exported ONNX with an extra effect."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import ROOT

from aat_deploy.errors import CaptureError
from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.pipeline import Options, run_capture
from training.cli.train import main
from training.nets.export import PARITY_TOL, read_metadata

EF50 = ROOT / "lenses" / "canon_ef50mm_f1.8.json"
STAGES = ["lens", "psf", "psf_colour", "train_aat", "train_thin", "export", "evaluate", "report"]


def _args(out: Path, *extra: str) -> list[str]:
    return ["--lens", str(EF50), "--sensor-mm", "36,24", "--resolution", "96,64", "--preset", "tiny",
            "--out", str(out), "--no-progress", *extra]


def _records(out: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in (out / "stages").glob("*.json") if ".running" not in p.name}


def _log_steps(run: Path) -> list[int]:
    rows = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    return [r["step"] for r in rows if "loss" in r or "total" in r]


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """One tiny run, killed after step 2 of the AAT training and restarted with the same command."""
    out = tmp_path_factory.mktemp("chain") / "ef50"
    from training.train import loop

    real_train = loop.train

    def killed(cfg, out_dir, **kw):
        if cfg.simulator == "aat":
            real_train(cfg, out_dir, stop_at_step=2, **kw)
            raise KeyboardInterrupt  # as if the process were killed after the step-2 checkpoint
        return real_train(cfg, out_dir, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(loop, "train", killed)
        with pytest.raises(KeyboardInterrupt):
            main(_args(out))
    first = _records(out)
    running = json.loads((out / "stages" / "train_aat.running.json").read_text())
    assert main(_args(out)) == 0
    return {"out": out, "first": first, "running": running, "second": _records(out)}


def test_killed_run_resumes_without_redoing_finished_stages(chain):
    first, second = chain["first"], chain["second"]
    assert set(first) == {"lens", "psf", "psf_colour"}  # finished before the kill (psf_colour: nothing to do)
    for s in ("lens", "psf", "psf_colour"):
        assert second[s]["finished"] == first[s]["finished"]  # not recomputed
    assert second["train_aat"]["action"] == "resumed"
    assert second["train_aat"]["input_hash"] == chain["running"]["input_hash"]
    assert _log_steps(chain["out"] / "train_aat") == [1, 2, 3, 4]  # continued from the step-2 checkpoint
    assert set(second) == set(STAGES)


def test_outputs_metadata_and_report(chain):
    out = chain["out"]
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["net"] == "dfvnet" and cfg["resolution"] == [96, 64] and cfg["preset"] == "tiny"
    rep = json.loads((out / "lens_report.json").read_text())
    assert rep["sensor_px"] == [96, 64] and rep["image_circle_method"] == "trace" and rep["warnings"] == []
    assert 50 < rep["efl_mm"] < 53 and rep["image_circle_mm"] > rep["sensor_diagonal_mm"]
    assert 0.2 < rep["nearest_focus_m"] < 0.5  # the EF50 cannot focus at 0.2 m: its focus table stops earlier
    from aat_deploy.lens.io import load_lens

    lens = load_lens(out / "lens.json")
    psf_md = read_metadata(out / "psf.onnx")
    assert psf_md["aat.lens_hash"] == lens.prescription_hash() and json.loads(psf_md["aat.sensor_px"]) == [96, 64]
    for sim, name in (("aat", "dff_dfvnet_aat.onnx"), ("thin_lens", "dff_dfvnet_thin.onnx")):
        md = read_metadata(out / name)
        assert md["aat.simulator"] == sim and md["aat.lens_hash"] == lens.prescription_hash()
        assert md["aat.lens_name"].startswith("Canon EF50mm") and json.loads(md["aat.sensor_px"]) == [96, 64]
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics["models"]) == {"dff_dfvnet_aat.onnx", "dff_dfvnet_thin.onnx"}
    for r in metrics["models"].values():
        assert np.isfinite(r["metrics"]["mae"]) and len(r["radial_mae_m"]) == 10
    report = (out / "report.md").read_text()
    assert "## Held-out evaluation" in report and "error_vs_radius.png" in report and "| train_aat |" in report
    assert (out / "error_vs_radius.png").stat().st_size > 1000


def test_runtime_accepts_ef50_captures_and_flags_rf50(chain, tmp_path):
    from aat_deploy.capture.virtual import write_capture
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render import effects as fx
    from training.data.scenes import SceneConfig, procedural_scene
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF

    out = chain["out"]
    lens = load_lens(out / "lens.json")
    rgb, depth = procedural_scene(SceneConfig(height=64, width=96, near_m=0.7, far_m=6.0), np.random.default_rng(3))
    sim = Simulator(lens, OnnxPSF(out / "psf.onnx", lens), fx.parse(["aberrations"]))
    focus = np.array([0.6, 0.9, 1.5, 3.0, 8.0])
    st = sim.render_stack(torch.from_numpy(rgb.transpose(2, 0, 1).copy()).float(), torch.from_numpy(depth).float(),
                          focus)
    cap = write_capture(tmp_path / "ef50_capture", st.frames.numpy(), focus, lens, depth,
                        rgb.transpose(2, 0, 1), {"lens": lens.name})
    model = DfFModel(out / "dff_dfvnet_aat.onnx")
    s = run_capture(cap, model, tmp_path / "o1", Options(quiet=True, record=False, strict=True))
    assert not any("lens" in w or "focal length" in w for w in s["warnings"])
    assert (tmp_path / "o1" / "depth_m.npy").exists()
    s = run_capture(ROOT / "captures" / "sample_rf50", model, tmp_path / "o2", Options(quiet=True, record=False))
    assert any("is not the model's lens" in w for w in s["warnings"])
    with pytest.raises(CaptureError, match="strict"):
        run_capture(ROOT / "captures" / "sample_rf50", model, tmp_path / "o3",
                    Options(quiet=True, record=False, strict=True))


def test_same_command_skips_everything_other_settings_need_force(chain, tmp_path, capsys):
    out = tmp_path / "copy"
    shutil.copytree(chain["out"], out)
    assert main(_args(out)) == 0
    assert "0 stages run, 8 up to date" in capsys.readouterr().out
    assert {k: v["finished"] for k, v in _records(out).items()} == {
        k: v["finished"] for k, v in chain["second"].items()}
    assert main(_args(out, "--steps", "3")) == 1
    assert "--force" in capsys.readouterr().err


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_changed_input_reruns_downstream_under_torchrun(chain, tmp_path):
    """--steps 3 --force on a finished folder, with 2 torchrun processes: lens and PSF stay, both trainings
    (distributed), export, evaluation and report rerun."""
    out = tmp_path / "ddp"
    shutil.copytree(chain["out"], out)
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE", "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node=2", f"--master_port={_free_port()}",
           "-m", "training.cli.train", *_args(out, "--steps", "3", "--force")]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600, check=False)
    # the launcher's own report ends stderr; the failing rank's cause (a C++ abort's "what()", a Python traceback) is
    # earlier, so both are shown (a rank once died of SIGABRT under a fully loaded machine, its cause cut off)
    cause = [ln for ln in res.stderr.splitlines() if any(k in ln for k in ("terminate", "what()", "Error", "error:"))]
    assert res.returncode == 0, "\n".join(cause[:20]) + "\n...\n" + res.stderr[-2000:]
    rec = _records(out)
    for s in ("lens", "psf", "psf_colour"):
        assert rec[s]["finished"] == chain["second"][s]["finished"]
    for s in STAGES[3:]:
        assert rec[s]["finished"] > chain["second"][s]["finished"], s
    assert read_metadata(out / "dff_dfvnet_aat.onnx")["aat.train_steps"] == "3"
    assert json.loads((out / "train_aat" / "config.json").read_text())["steps"] == 3
    assert _log_steps(out / "train_aat") == [1, 2, 3]


def test_fine_tune_from_onnx_with_extra_effect_and_given_psf(chain, tmp_path):
    out = tmp_path / "ft"
    src = chain["out"]
    assert main(_args(out, "--init", str(src / "dff_dfvnet_aat.onnx"), "--psf", str(src / "psf.onnx"),
                      "--effects", "noise:full_well_e=3000", "--steps", "2", "--no-baseline")) == 0
    rec = _records(out)
    assert set(rec) == {"lens", "psf", "psf_colour", "train_aat", "export", "evaluate", "report"}
    assert rec["psf_colour"]["outputs"] == {}  # no chromatic: nothing to fit
    log = [json.loads(line) for line in (out / "train_aat" / "log.jsonl").read_text().splitlines()]
    assert log[0]["init"]["kind"] == "onnx" and log[0]["init"]["rel_diff_vs_onnxruntime"] <= PARITY_TOL
    md = read_metadata(out / "dff_dfvnet_aat.onnx")
    assert json.loads(md["aat.effects"]) == ["noise:full_well_e=3000.0"] and md["aat.init"] == "dff_dfvnet_aat.onnx"
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["train"]["lr"] == pytest.approx(1e-4)  # fine-tuning: the preset's rate x 0.1
    assert (out / "psf.onnx").read_bytes() == (src / "psf.onnx").read_bytes()


@pytest.fixture(scope="module")
def colour(chain, tmp_path_factory):
    """Fine-tuning with --effects chromatic, with the ray tracer made to fail: colour must come from the
    per-wavelength surrogates that stage psf_colour fits."""
    from aat_deploy.render.effects import chromatic

    out = tmp_path_factory.mktemp("colour") / "ft"
    src = chain["out"]
    args = _args(out, "--init", str(src / "dff_dfvnet_aat.onnx"), "--psf", str(src / "psf.onnx"),
                 "--effects", "chromatic", "--steps", "1")  # both simulators: the thin-lens one too

    def no_tracing(*a, **k):
        raise AssertionError("chromatic traced its PSFs although per-wavelength surrogates exist")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(chromatic, "_three_wavelengths", no_tracing)
        assert main(args) == 0
        first = _records(out)
        assert main(args) == 0
    return {"out": out, "first": first, "second": _records(out)}


def test_chromatic_fits_per_wavelength_surrogates_and_trains_with_them(chain, colour):
    """Stage psf_colour: one surrogate per wavelength (sensor where the design wavelength focuses, kernels
    centred on its chief ray); training and evaluation render with them; a rerun refits nothing."""
    from aat_deploy.render.effects import chromatic

    out, rec = colour["out"], colour["first"]
    files = [chromatic.surrogate_name(w) for w in (610, 540, 465)]
    assert sorted(rec["psf_colour"]["outputs"]) == sorted(files)
    for f, w in zip(files, (610, 540, 465)):
        md = read_metadata(out / f)
        assert float(md["aat.wavelength_nm"]) == w and float(md["aat.center_wavelength_nm"]) == 589.0
        assert md["aat.lens_hash"] == read_metadata(chain["out"] / "psf.onnx")["aat.lens_hash"]
    for name in ("dff_dfvnet_aat.onnx", "dff_dfvnet_thin.onnx"):
        assert json.loads(read_metadata(out / name)["aat.effects"]) == ["chromatic"]
    assert colour["second"]["psf_colour"]["finished"] == rec["psf_colour"]["finished"]


def test_chromatic_twins_render_without_torch_next_to_their_surrogates(colour, tmp_path):
    """With psf_<w>nm.onnx next to the lens's surrogate the torch-free twin renderer renders `chromatic`
    (three different channels); psfs=trace still needs torch; a folder without them is a one-line error."""
    from aat_deploy.diagnose.twin import TwinRenderer
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render import effects as fx
    from aat_deploy.render.sources import OnnxSource

    out = colour["out"]
    lens = load_lens(out / "lens.json")
    twins = TwinRenderer(DfFModel(out / "dff_dfvnet_aat.onnx"), lens, OnnxSource(out / "psf.onnx", lens))
    assert twins.why_torch(fx.parse("chromatic")) is None
    assert "torch" in twins.why_torch(fx.parse("chromatic:psfs=trace"))
    rgb = np.ones((3, 64, 96), np.float32)
    rgb[:, :, 48:] = 0.1  # an edge: colour fringes where the channels' PSFs differ
    depth = np.full((64, 96), 3.0, np.float32)
    frames = twins.optical(fx.parse("chromatic"), rgb, depth, np.array([0.6]), twins.context())
    assert frames.shape == (1, 3, 64, 96) and np.isfinite(frames).all()
    assert np.abs(frames[0, 0] - frames[0, 2]).max() > 1e-3 * np.abs(frames).max()
    with pytest.raises(ValueError, match=r"chromatic.*no per-wavelength surrogate psf_610nm.onnx"):
        fx.parse([{"name": "chromatic", "psfs": str(tmp_path)}])  # before anything renders
    frames_dir = twins.optical(fx.parse([{"name": "chromatic", "psfs": str(out)}]), rgb, depth, np.array([0.6]),
                               twins.context())
    # the folder given explicitly: the same surrogates through the same code in one process, bit for bit
    np.testing.assert_array_equal(frames_dir, frames)


def test_bad_options_are_one_line_errors(chain, tmp_path, capsys):
    assert main(_args(tmp_path / "a", "--effects", "aberrations")) == 2
    assert "aberrations" in capsys.readouterr().err
    assert main(_args(tmp_path / "b", "--effects", "fog")) == 2
    assert "unknown effect" in capsys.readouterr().err
    assert main(_args(tmp_path / "b", "--effects", "noise:gain")) == 2
    assert "key=value" in capsys.readouterr().err
    assert main(_args(tmp_path / "b", "--effects", f"chromatic:psfs={tmp_path}")) == 2
    err = capsys.readouterr().err
    assert "no per-wavelength surrogate psf_610nm.onnx" in err and len(err.strip().splitlines()) == 1
    assert main(_args(tmp_path / "c", "--net", "aif", "--init", str(chain["out"] / "dff_dfvnet_aat.onnx"))) == 2
    assert "is a dfvnet small model" in capsys.readouterr().err
    rf50_psf = ROOT / "models" / "psf_rf50.onnx"
    assert main(_args(tmp_path / "d", "--psf", str(rf50_psf), "--no-baseline")) == 1
    assert "not this lens and sensor" in capsys.readouterr().err


def test_image_circle_warning(monkeypatch):
    import training.chain.lens_check as lc

    monkeypatch.setattr(lc, "nearest_focus_m", lambda lens: 0.25)
    big = lc.resolve_lens(EF50, (48.0, 36.0), (96, 72))
    rep = lc.lens_report(big, EF50, (0.5, 10.0))
    assert rep["image_circle_method"] == "trace"
    assert any("exceeds the image circle" in w for w in rep["warnings"])
    assert rep["image_circle_paraxial_mm"] > 0
    with pytest.raises(ValueError, match="focuses no closer"):
        lc.lens_report(big, EF50, (0.2, 10.0))
