"""One `aat-diagnose` run: inputs, the diagnosis, the optional retraining, and the report folder (written to a
temporary folder and renamed, so an interrupted run leaves nothing half-written).

Torch-free: twins are rendered by `aat_deploy.diagnose.twin` with the exported PSF surrogate. When the training
package (torch) is installed, the effects numpy cannot render (`chromatic` without per-wavelength surrogates; the
lens's PSFs without a surrogate) are rendered by the training simulator, reached through the declared extension
`torch_twin_renderer` (`aat_deploy.extensions`); without it they are skipped and listed in the report. Retraining
runs `aat-train` (the `train` extra)."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
from pathlib import Path

import numpy as np

from aat_deploy import extensions
from aat_deploy.diagnose import report
from aat_deploy.diagnose.inputs import find_captures, load_capture_data
from aat_deploy.diagnose.lookup import find_lens, find_surrogate
from aat_deploy.diagnose.search import DiagnoseConfig, Diagnosis, diagnose
from aat_deploy.diagnose.twin import TwinError, TwinRenderer, model_effects
from aat_deploy.errors import AatError, CaptureError, ModelError
from aat_deploy.infer.model import DfFModel
from aat_deploy.io.atomic import atomic_folder
from aat_deploy.io.guard import check_no_overlap
from aat_deploy.lens.schema import Lens
from aat_deploy.progress import say
from aat_deploy.render import effects as fx
from aat_deploy.render.sources import OnnxSource


class DiagnoseError(AatError, RuntimeError):
    pass


def _say(quiet: bool):
    return lambda msg: say(quiet, msg)  # the runtime's progress lines (aat_deploy.progress)


def make_renderer(model: DfFModel, lens: Lens, surrogate: OnnxSource | None, torch_free: bool = False,
                  threads: int = 2):
    """The twin renderer: torch-free, with the training simulator behind it for torch-only effects when torch is
    installed (and `torch_free` is not asked for); threads: the torch-free renderer's frames in parallel."""
    if not torch_free:
        torch_backed = extensions.load("torch_twin_renderer", optional=True)  # None without torch: stay torch-free
        if torch_backed is not None:
            return torch_backed(model, lens, surrogate)
    if surrogate is None and any(e.uses_lens_psfs for e in model_effects(model)):
        raise TwinError(f"{model.path}: no PSF surrogate for lens {lens.name!r} at this sensor (pass --psf); "
                        "ray tracing the lens's PSFs needs the training package (torch)")
    return TwinRenderer(model, lens, surrogate, threads=threads)


def retrain_command(model_path: Path, lens_path: Path, psf_path: Path | None, effects: list[str], steps: int,
                    out: Path, sensor_mm, sensor_px) -> list[str]:
    """The `aat-train` call that fine-tunes the model with the named effects (aberrations = the AAT simulator,
    which the chain always uses)."""
    extra = [e for e in effects if not e.startswith("aberrations")]
    cmd = ["aat-train", "--lens", str(lens_path), "--sensor-mm", f"{sensor_mm[0]},{sensor_mm[1]}",
           "--resolution", f"{sensor_px[0]},{sensor_px[1]}", "--init", str(model_path), "--steps", str(steps),
           "--no-baseline", "--out", str(out)]
    if psf_path:
        cmd += ["--psf", str(psf_path)]
    if extra:
        cmd += ["--effects", ",".join(extra)]
    return cmd


def calibrated_focus(caps: list, calibration) -> tuple[list, dict]:
    """Captures with their reported focus corrected by a camera calibration's reported-focus error
    (`aat_deploy.calibrate`: on the frame centre; the model is fed these distances, the twins are rendered at
    them) and what was done."""
    from aat_deploy.calibrate.format import on_axis_diopters

    out = []
    for c in caps:
        d = on_axis_diopters(calibration, c.focus_m)
        out.append(dataclasses.replace(c, focus_m=(1.0 / np.maximum(d, 1e-3)).astype(c.focus_m.dtype)))
    fe = calibration.focus_error
    return out, {"family": fe.family, "bias_d": fe.bias_d, "scale": fe.scale, "map_d": list(fe.map_d),
                 "note": "reported focus corrected by the calibration's error before the diagnosis; its field term "
                         "is not used (the twin's lens has its own)"}


def run(root, model_path, out: Path, *, lens=None, psf=None, effects=None, retrain_steps: int = 0,
        threads: int = 2, seed: int = 0, force: bool = False, quiet: bool = False, cfg: DiagnoseConfig | None = None,
        torch_free: bool = False, calibration=None, max_megapixels: float | None = None,
        allow_outside_links: bool = False) -> dict:
    say = _say(quiet)
    if retrain_steps and shutil.which("aat-train") is None:
        raise DiagnoseError("--retrain-steps needs aat-train (pip install 'aat-dff[train]')")
    cfg = cfg or DiagnoseConfig(seed=seed, effects=[s.strip() for s in effects.split(",")] if effects else None)
    unknown = sorted(set(cfg.effects or []) - set(fx.names()))
    if unknown:  # before any model or capture is loaded
        raise DiagnoseError(f"--effects: unknown {', '.join(unknown)}; registered: {', '.join(fx.names())}")
    try:
        model = DfFModel(model_path, threads=threads)
        lens_obj, lens_file = find_lens(model, lens)
        src = find_surrogate(lens_obj, psf, threads)
        twins = make_renderer(model, lens_obj, src, torch_free)
        folders = find_captures(root, exclude=[Path(out)])
        check_no_overlap(out, folders)  # the report never goes into (or replaces) a capture folder
        if not folders:
            raise DiagnoseError(f"{root}: no capture folder with ground truth (see docs/contracts.md)")
        say(f"{len(folders)} capture(s); model simulator: {', '.join(fx.spec(e) for e in twins.base) or 'thin lens'}")
        caps = [load_capture_data(f, model, max_megapixels=max_megapixels, allow_outside_links=allow_outside_links)
                for f in folders]
        cal_info = None
        if calibration is not None:
            from aat_deploy.calibrate.format import load_calibration

            caps, cal_info = calibrated_focus(caps, load_calibration(calibration))
            cal_info["file"] = str(calibration)
            say(f"focus distances corrected by {calibration} ({cal_info['family']})")
    except (ModelError, TwinError, CaptureError, FileNotFoundError, ValueError) as e:
        raise DiagnoseError(str(e)) from None
    res, diag, chain = diagnose(model, twins, caps, cfg, progress=say)
    res["root"] = str(root)
    if cal_info is not None:
        res["calibration"] = cal_info
    res["model"] = {"file": str(model_path), "net": model.meta.get("aat.net"), "simulator": model.meta.get("aat.simulator"),
                    "effects": [fx.spec(e) for e in twins.base]}
    shrink = res["shrink"]
    out = Path(out)
    with atomic_folder(out, force, "aat-diagnose") as tmp:
        if shrink:
            named = [e.training_spec() for e in chain[-1].effects]
            cmd = retrain_command(Path(model_path), lens_file, src.path if src is not None else None,
                                  named, retrain_steps or 300, out / "retrain", model.meta["aat.sensor_mm"], model.sensor_px)
            shrink["retrain_command"] = " ".join(cmd)
            if retrain_steps:
                say("retraining: " + " ".join(cmd))
                cmd[cmd.index("--out") + 1] = str(tmp / "retrain")
                subprocess.run(cmd, check=True)
                new = sorted((tmp / "retrain").glob("dff_*_aat.onnx"))
                if not new:
                    raise DiagnoseError(f"{tmp / 'retrain'}: aat-train wrote no dff_*_aat.onnx")
                shrink.update(score_model(new[0], lens_obj, src, caps, cfg, threads, torch_free))
                shrink["retrained_model"] = str(out / "retrain" / new[0].name)
        report.write_focus_corrections(tmp, res)
        report.write_json(tmp / "diagnosis.json", res)
        report.figures(res, tmp)
        (tmp / "report.md").write_text(report.markdown(res))
        report.recording(tmp / "diagnosis.rrd", [
            {"name": r.data.name, "gt_m": r.data.gt_m, "pred_real_m": r.pred_m,
             "pred_twin_m": p0, "pred_twin_best_m": p1, "gap_m": g}
            for r, g, p0, p1 in zip(diag.runs, diag.gap_maps(chain[0]), chain[0].pred, chain[-1].pred)])
    return res


def score_model(path: Path, lens_obj, src, caps, cfg: DiagnoseConfig, threads: int, torch_free: bool = False) -> dict:
    """A retrained model's gap on the same captures, against its own simulator's twins."""
    model = DfFModel(path, threads=threads)
    d = Diagnosis(model, make_renderer(model, lens_obj, src, torch_free), caps, cfg)
    twin = d.score_twin([])
    gap = float(np.nanmean(np.concatenate([g.ravel() for g in d.gap_maps(twin)])))
    return {"gap_after_m": gap, "real_mae_after_m": float(np.nanmean(np.concatenate([r.err.ravel() for r in d.runs])))}
