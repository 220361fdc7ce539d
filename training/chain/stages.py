"""The stages of the lens-to-model chain, in order, each with the files it reads and writes in the run folder DIR.

| stage      | reads                               | writes                                                        |
|------------|-------------------------------------|---------------------------------------------------------------|
| lens       | the lens file, sensor, focus range  | lens.json (lens + your sensor), lens_report.json              |
| psf        | lens.json (or --psf)                | psf.onnx (RotPSF surrogate, aat.* metadata); work: psf_work/  |
| psf_colour | lens.json (only with chromatic)     | psf_<w>nm.onnx per wavelength; work: psf_colour_work/         |
| train_aat  | lens.json, psf.onnx                 | train_aat/model.pt (+ last.pt, log.jsonl, rendered stacks)    |
| train_thin | lens.json (psf.onnx with vignetting)| train_thin/model.pt                                           |
| export     | lens.json, the model.pt files       | dff_<net>_aat.onnx, dff_<net>_thin.onnx                       |
| evaluate   | lens.json, psf.onnx, the .onnx nets | metrics.json, error_vs_radius.png, error_over_field.png       |
| report     | all of the above                    | report.md                                                     |

Each stage's settings (a dict, part of DIR/config.json) and the hashes of the files it reads make its input hash
(training/chain/hashing.py). Both trainings use the same data seeds, scenes, crops and focus schedules; only
the simulator differs ("aat": the lens's PSFs through psf.onnx; "thin_lens": Gaussian blur of the same EFL,
F-number and pixels); the requested effects apply to both. Evaluation scenes (seed 777777) are whole-sensor
renders with the AAT simulator plus the requested effects: the camera as well as we can simulate it.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from aat_deploy.io.atomic import atomic_file

TRAIN_SEED, VAL_SEED, EVAL_SEED = 0, 100000, 777777


@dataclass
class Context:
    """A run: its folder, resolved config (training.chain.config), process rank / world size, progress bars, and
    where torch runs (device, amp: not settings of the run, so a folder may continue on other hardware)."""

    run_dir: Path
    cfg: dict
    rank: int = 0
    world: int = 1
    progress: bool = True
    log: Callable[[str], None] = print
    device: str = "auto"
    amp: str | None = None

    def path(self, rel: str) -> Path:
        return self.run_dir / rel

    @property
    def net(self) -> str:
        return self.cfg["net"]

    @property
    def simulators(self) -> list[str]:
        return ["aat", "thin_lens"] if self.cfg["baseline"] else ["aat"]


@dataclass
class Stage:
    """name; reads(ctx): run-folder files whose hashes enter the input hash; settings(ctx): the stage's config;
    run(ctx): does the work, returns the output files (relative paths); work: files/folders of partial work,
    deleted when the inputs change; distributed: every torchrun process runs it (else rank 0 only)."""

    name: str
    reads: Callable[[Context], list[str]]
    settings: Callable[[Context], dict]
    run: Callable[[Context], list[str]]
    work: Callable[[Context], list[str]] = field(default=lambda ctx: [])
    distributed: bool = False


def onnx_name(ctx: Context, simulator: str) -> str:
    return f"dff_{ctx.net}_{'aat' if simulator == 'aat' else 'thin'}.onnx"


def train_dir(simulator: str) -> str:
    return "train_aat" if simulator == "aat" else "train_thin"


def _uses_psf(simulator: str, effects: list[str]) -> bool:
    # Mirrors training.data.stacks.FocalStackDataset: the lens's PSF source is built for the AAT simulator, for
    # the vignetting effect (relative illumination from the lens) and for chromatic (its per-wavelength
    # surrogates are found next to psf.onnx).
    from training.chain.config import effect_name

    return simulator == "aat" or bool({"vignetting", "chromatic"} & {effect_name(e) for e in effects})


# -- 1. lens -------------------------------------------------------------------------------------------------------
def _lens_settings(ctx: Context) -> dict:
    from training.chain.lens_check import MIN_BLUR_PX, MIN_RELATIVE_ILLUMINATION

    c = ctx.cfg
    return {"lens_sha256": c["lens"]["sha256"], "sensor_mm": c["sensor_mm"], "resolution": c["resolution"],
            "focus_range_m": c["focus_range_m"], "min_relative_illumination": MIN_RELATIVE_ILLUMINATION,
            "min_blur_px": MIN_BLUR_PX}


def _lens_run(ctx: Context) -> list[str]:
    from aat_deploy.lens.io import save_lens
    from training.chain.hashing import write_json_atomic
    from training.chain.lens_check import format_report, lens_report, resolve_lens

    c = ctx.cfg
    lens = resolve_lens(c["lens"]["path"], c["sensor_mm"], c["resolution"])
    save_lens(lens, ctx.path("lens.json"), force=True)
    ctx.path("lens.json").chmod(0o644)
    rep = lens_report(lens, c["lens"]["path"], tuple(c["focus_range_m"]))
    write_json_atomic(ctx.path("lens_report.json"), rep)
    ctx.log(format_report(rep))
    return ["lens.json", "lens_report.json"]


# -- 2. psf --------------------------------------------------------------------------------------------------------
def _psf_settings(ctx: Context) -> dict:
    c = ctx.cfg
    return {"file": c["psf_file"]} if c["psf_file"] else {"fit": c["psf"]}


def _psf_run(ctx: Context) -> list[str]:
    from aat_deploy.lens.io import load_lens

    lens = load_lens(ctx.path("lens.json"))
    out = ctx.path("psf.onnx")
    given = ctx.cfg["psf_file"]
    if given:
        from aat_deploy.psf.surrogate import PSFSurrogate

        sur = PSFSurrogate(given["path"])
        if sur.lens_hash != lens.prescription_hash():
            raise ValueError(f"--psf {given['path']}: fitted for {sur.meta.get('aat.lens_name')!r} with sensor "
                             f"{sur.meta.get('aat.sensor_mm')} mm at {sur.meta.get('aat.sensor_px')} px (prescription "
                             f"{sur.lens_hash}), not this lens and sensor ({lens.prescription_hash()})")
        with atomic_file(out) as tmp:
            shutil.copyfile(given["path"], tmp)
        ctx.log(f"psf: using {given['path']}")
        return ["psf.onnx"]
    fit_surrogate(ctx, lens, out)
    return ["psf.onnx"]


def fit_surrogate(ctx: Context, lens, out: Path, wavelength_nm: float | None = None,
                  center_wavelength_nm: float | None = None, work_dir: str = "psf_work") -> None:
    """Trace the axis and validation PSF datasets (cached in `work_dir`), fit RotPSF on its wall-clock budget
    (resumable from `work_dir`/psf_fit/), export to `out` with metadata. wavelength_nm: None = the config's;
    center_wavelength_nm: centre the kernels on that wavelength's chief ray (per-wavelength surrogates)."""
    import torch

    from training.chain.hashing import write_json_atomic
    from training.psf.dataset import build_psf_dataset, to_tensors
    from training.psf.experiment import PSFExperiment
    from training.psf.export import export_psf_onnx

    p = dict(ctx.cfg["psf"])
    nearest = json.loads(ctx.path("lens_report.json").read_text())["nearest_focus_m"]
    p["near_m"] = max(p["near_m"], nearest)  # the margin below the focus range stops at the lens's nearest focus
    wavelength = float(wavelength_nm or p["wavelength_nm"])
    work = ctx.path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    name = "psf_chain" if center_wavelength_nm is None else f"psf_chain_{wavelength:g}nm"
    exp = PSFExperiment(lens=str(ctx.path("lens.json")), near_m=p["near_m"], far_m=p["far_m"],
                        kernel_size=p["kernel_size"], margin_px=p["margin_px"], wavelength_nm=wavelength,
                        center_wavelength_nm=center_wavelength_nm,
                        train_axis={"n": p["axis_n"], "n_rays": p["axis_rays"], "seed": 1 + 10 * p["seed"]},
                        val={"n": p["val_n"], "n_rays": p["val_rays"], "seed": 3 + 10 * p["seed"]},
                        fits={"rot": {"minutes": p["fit_minutes"], "lr": 1e-3, "loss": "l1",
                                      "eval_every_s": max(5.0, 6.0 * p["fit_minutes"]),
                                      "checkpoint_every_s": 30.0}},
                        source=str(work / f"{name}.json"))
    write_json_atomic(work / f"{name}.json", {k: v for k, v in exp.__dict__.items() if k != "source"})
    data = {}
    for name, layout, part in (("axis", "axis", exp.train_axis), ("val", "field", exp.val)):
        d = build_psf_dataset(lens, exp.data_config(layout, part), work, compiled=p["compiled"],
                              progress=ctx.progress, device=ctx.device)
        data[name] = to_tensors(d)
    ctx.log(f"psf: {p['axis_n']} axis PSFs traced at {wavelength:g} nm; fitting RotPSF for "
            f"{p['fit_minutes'] * 60:.0f} s")
    model, fit_cfg = exp.run_fit("rot", lens, data, cache_dir=work, progress=ctx.progress, device=ctx.device)
    st = torch.load(exp.checkpoint("rot", work, lens), map_location="cpu", weights_only=False)
    last = (fit_cfg.history or [{}])[-1]
    centre = {} if center_wavelength_nm is None else {"center_wavelength_nm": center_wavelength_nm}
    export_psf_onnx(model, lens, out, force=True, extra_metadata={
        "fit": "rot", "wavelength_nm": wavelength, **centre, "training_minutes": f"{st['elapsed'] / 60:.2f}",
        "validation_l1": f"{last.get('l1', float('nan')):.4e}",
        "command": f"aat-train --lens (training/chain, stage {'psf' if center_wavelength_nm is None else 'psf_colour'})"})
    ctx.log(f"psf: validation l1 {last.get('l1', float('nan')):.3e} per cell; wrote {out.name}")


# -- 2b. psf_colour -----------------------------------------------------------------------------------------------
def _chromatic(ctx: Context):
    """The run's `chromatic` effect, or None."""
    from aat_deploy.render import effects as fx

    return next((e for e in fx.parse(ctx.cfg["effects"]) if e.name == "chromatic"), None)


def _colour_files(ctx: Context) -> list[str]:
    """The per-wavelength surrogates stage psf_colour writes (none without chromatic, or when the effect is told
    where its surrogates are or to trace)."""
    from aat_deploy.render.effects.chromatic import surrogate_name

    e = _chromatic(ctx)
    if e is None or e.params["psfs"] != "auto":
        return []
    return [surrogate_name(w) for w in e.wavelengths()]


def _colour_settings(ctx: Context) -> dict:
    files = _colour_files(ctx)
    return {"files": files, "fit": ctx.cfg["psf"]} if files else {}


def _colour_run(ctx: Context) -> list[str]:
    """One RotPSF per wavelength of `chromatic`, traced with the sensor where the design wavelength focuses and
    centred on its chief ray: chromatic then renders as fast as the lens's PSFs (else ~30 s a training stack)."""
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.chromatic import REFERENCE_WAVELENGTH_NM

    files = _colour_files(ctx)
    if not files:
        return []
    lens = load_lens(ctx.path("lens.json"))
    for w, f in zip(_chromatic(ctx).wavelengths(), files):
        fit_surrogate(ctx, lens, ctx.path(f), wavelength_nm=w, center_wavelength_nm=REFERENCE_WAVELENGTH_NM,
                      work_dir="psf_colour_work")
    return files


# -- 3./4. training ------------------------------------------------------------------------------------------------
def train_config(ctx: Context, simulator: str):
    """The TrainConfig of one simulator's run (identical but for `simulator` and the PSF file it needs)."""
    from training.train.config import LossConfig, TrainConfig

    c, t = ctx.cfg, ctx.cfg["train"]
    near, far = c["focus_range_m"]
    sw, sh = _sensor_px(ctx)
    h, w = min(t["crop_hw"][0], sh), min(t["crop_hw"][1], sw)
    psf = str(ctx.path("psf.onnx")) if _uses_psf(simulator, c["effects"]) else None
    cache = str(ctx.path(train_dir(simulator)) / "stacks")
    common = {"height": h, "width": w, "stack_size": c["stack"], "focus_near_m": near, "focus_far_m": far,
              "scene_near_m": near, "scene_far_m": far, "psf": psf, "cell_px": t["cell_px"], "cache_dir": cache}
    from training.nets.registry import NETS

    levels = NETS[c["net"]].level_weights
    return TrainConfig(
        name=f"{train_dir(simulator)}_{c['net']}", net=c["net"], size=c["size"], simulator=simulator,
        lens=str(ctx.path("lens.json")), effects=list(c["effects"]),
        data={**common, "n_items": t["n_items"], "seed": TRAIN_SEED + c["seed"]},
        val_data={**common, "n_items": t["val_items"], "seed": VAL_SEED + c["seed"]},
        focus_range_m=(near, far), stack_range=(2, max(16, c["stack"])), steps=t["steps"],
        batch_size=t["batch_size"], lr=t["lr"], lr_min=t["lr"] / 100, warmup_steps=t["warmup_steps"],
        loss=LossConfig(level_weights=levels), seed=c["seed"], checkpoint_every=t["checkpoint_every"],
        log_every=t["log_every"], val_items=t["val_items"],
        init=c["init"]["path"] if c["init"] else None,
    ).validate()


def _sensor_px(ctx: Context) -> tuple[int, int]:
    rep = json.loads(ctx.path("lens_report.json").read_text())
    return int(rep["sensor_px"][0]), int(rep["sensor_px"][1])


def _train_reads(simulator: str) -> Callable[[Context], list[str]]:
    return lambda ctx: ["lens.json"] + (["psf.onnx"] if _uses_psf(simulator, ctx.cfg["effects"]) else []) + \
        _colour_files(ctx)


def _train_settings(simulator: str) -> Callable[[Context], dict]:
    def settings(ctx: Context) -> dict:
        c = ctx.cfg
        return {"simulator": simulator, "net": c["net"], "size": c["size"], "stack": c["stack"],
                "effects": c["effects"], "focus_range_m": c["focus_range_m"], "seed": c["seed"],
                "train": c["train"], "init_sha256": c["init"]["sha256"] if c["init"] else None}
    return settings


def _train_run(simulator: str) -> Callable[[Context], list[str]]:
    def run(ctx: Context) -> list[str]:
        from training.train.loop import train

        cfg = train_config(ctx, simulator)
        out = ctx.path(train_dir(simulator))
        res = train(cfg, out, resume=True, progress=ctx.progress, device=ctx.device, amp=ctx.amp)
        if not res.finished:
            raise RuntimeError(f"{out}: training stopped at step {res.step}/{cfg.steps}")
        spd = f", {res.seconds_per_step:.3f} s/step" if res.seconds_per_step else ""
        ctx.log(f"{train_dir(simulator)}: {cfg.steps} steps{spd}; validation {json.dumps(res.val_metrics)[:160]}")
        return [f"{train_dir(simulator)}/model.pt"]
    return run


# -- 5. export -----------------------------------------------------------------------------------------------------
def _export_run(ctx: Context) -> list[str]:
    from training.train.export import export_checkpoint

    outs = []
    for sim in ctx.simulators:
        name = onnx_name(ctx, sim)
        md, err = export_checkpoint(ctx.path(train_dir(sim)) / "model.pt", ctx.path(name), force=True, extra={
            "command": "aat-train --lens (training/chain, stage export)",
            "init": Path(ctx.cfg["init"]["path"]).name if ctx.cfg["init"] else "",
            "preset": ctx.cfg["preset"]})
        ctx.log(f"export: {name} ({md['aat.lens_name']}, {md['aat.simulator']}), ORT vs torch {err:.1e} relative")
        outs.append(name)
    return outs


# -- 6. evaluate ---------------------------------------------------------------------------------------------------
def _eval_settings(ctx: Context) -> dict:
    c = ctx.cfg
    return {"eval": c["eval"], "effects": c["effects"], "stack": c["stack"], "focus_range_m": c["focus_range_m"],
            "seed": EVAL_SEED + c["seed"]}


def _eval_run(ctx: Context) -> list[str]:
    from training.chain.hashing import write_json_atomic
    from training.data.stacks import FocalStackDataset, StackDataConfig
    from training.train.heldout import (
        evaluate_model,
        plot_error_over_field,
        plot_error_vs_radius,
        procedural_items,
        result_dict,
        table,
    )

    c = ctx.cfg
    near, far = c["focus_range_m"]
    sw, sh = _sensor_px(ctx)
    ds = FocalStackDataset(StackDataConfig(
        simulator="aat", lens=str(ctx.path("lens.json")), psf=str(ctx.path("psf.onnx")),
        effects=tuple(c["effects"]), height=sh, width=sw, stack_size=c["stack"], focus_near_m=near,
        focus_far_m=far, scene_near_m=near, scene_far_m=far, n_items=c["eval"]["n_scenes"],
        seed=EVAL_SEED + c["seed"], margin_px=0, cell_px=c["eval"]["cell_px"]))
    items = procedural_items(ds, c["eval"]["n_scenes"], progress=ctx.progress)
    results = [evaluate_model(ctx.path(onnx_name(ctx, s)), items) for s in ctx.simulators]
    title = f"{len(items)} held-out scenes, {'+'.join(['aberrations'] + c['effects'])}"
    plot_error_vs_radius(results, ctx.path("error_vs_radius.png"), title)
    plot_error_over_field(results, ctx.path("error_over_field.png"))
    write_json_atomic(ctx.path("metrics.json"), {
        "test_set": {"scenes": len(items), "seed": EVAL_SEED + c["seed"], "size_px": [sw, sh],
                     "simulator": "aat", "effects": c["effects"], "stack": c["stack"], "focus_range_m": [near, far]},
        "models": {onnx_name(ctx, s): result_dict(r) for s, r in zip(ctx.simulators, results)}})
    ctx.log(table(results))
    return ["metrics.json", "error_vs_radius.png", "error_over_field.png"]


# -- 7. report -----------------------------------------------------------------------------------------------------
def _report_reads(ctx: Context) -> list[str]:
    return ["lens_report.json", "metrics.json", "error_vs_radius.png", "error_over_field.png", "psf.onnx"] + [
        onnx_name(ctx, s) for s in ctx.simulators]


def _report_run(ctx: Context) -> list[str]:
    from training.chain.report import write_report

    write_report(ctx, [onnx_name(ctx, s) for s in ctx.simulators],
                 [s.name for s in stages(ctx) if s.name != "report"])
    return ["report.md"]


def stages(ctx: Context) -> list[Stage]:
    """The chain for this run (train_thin only with the baseline)."""
    out = [
        Stage("lens", lambda c: [], _lens_settings, _lens_run),
        Stage("psf", lambda c: ["lens.json", "lens_report.json"], _psf_settings, _psf_run, work=lambda c: ["psf_work", "psf.onnx"]),
        Stage("psf_colour", lambda c: ["lens.json", "lens_report.json"], _colour_settings, _colour_run,
              work=lambda c: ["psf_colour_work", *_colour_files(c)]),
    ]
    for sim in ctx.simulators:
        d = train_dir(sim)
        out.append(Stage(d, _train_reads(sim), _train_settings(sim), _train_run(sim),
                         work=lambda c, d=d: [d], distributed=True))
    out += [
        Stage("export", lambda c: ["lens.json"] + [f"{train_dir(s)}/model.pt" for s in c.simulators],
              lambda c: {"net": c.net, "simulators": c.simulators, "preset": c.cfg["preset"],
                         "init": Path(c.cfg["init"]["path"]).name if c.cfg["init"] else ""},
              _export_run),
        Stage("evaluate", lambda c: ["lens.json", "psf.onnx", *_colour_files(c)] + [onnx_name(c, s) for s in c.simulators],
              _eval_settings, _eval_run),
        Stage("report", _report_reads, lambda c: {"config": c.cfg}, _report_run),
    ]
    return out
