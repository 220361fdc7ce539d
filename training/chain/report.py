"""Stage 7 of the chain: DIR/report.md — the resolved config, the lens check, the held-out metrics (AAT vs the
thin-lens baseline), the figures, the stage times and the commands that use the result."""

from __future__ import annotations

import json
from pathlib import Path

from aat_deploy.io.atomic import write_text_atomic
from training.chain.hashing import StageMarkers

METRIC_COLS = (("MAE (m)", "mae"), ("RMSE (m)", "rmse"), ("AbsRel", "abs_rel"), ("δ1", "delta1"),
               ("MAE centre", "mae_centre"), ("MAE outer", "mae_outer"))


def _fmt(v) -> str:
    return "–" if v is None else f"{v:.4f}" if isinstance(v, float) else str(v)


def lens_section(rep: dict) -> list[str]:
    fov = rep["fov_deg"]
    rows = [
        ("lens", rep["name"]), ("file", f"`{rep['source']}`"), ("prescription hash (with sensor)",
                                                                 f"`{rep['prescription_hash']}`"),
        ("EFL", f"{rep['efl_mm']:.2f} mm"), ("F-number", f"F/{rep['f_number']:.2f}"),
        ("sensor", (f"{rep['sensor_mm'][0]:g} × {rep['sensor_mm'][1]:g} mm, {rep['sensor_px'][0]} × "
                   f"{rep['sensor_px'][1]} px ({rep['pixel_um']:.2f} µm pixels)")),
        ("field of view", f"{fov['horizontal']:.1f}° × {fov['vertical']:.1f}° (diagonal {fov['diagonal']:.1f}°)"),
        ("image circle", (f"{rep['image_circle_mm']:.1f} mm ({rep['image_circle_method']}); sensor diagonal "
                         f"{rep['sensor_diagonal_mm']:.1f} mm")),
        ("nearest focus", f"{rep['nearest_focus_m']:.3f} m from the sensor"),
        ("defocus blur over the focus range", (f"{rep['defocus_blur_px']:.1f} px (thin lens, near end with focus "
                                              "at the far end)")),
    ]
    out = ["| | |", "|---|---|"] + [f"| {a} | {b} |" for a, b in rows]
    out += [""] + [f"**Warning:** {w}" for w in rep["warnings"]] if rep["warnings"] else []
    return out


def metrics_section(metrics: dict) -> list[str]:
    ts = metrics["test_set"]
    out = [f"{ts['scenes']} held-out procedural scenes (seed {ts['seed']}), whole sensor {ts['size_px'][0]} × "
           f"{ts['size_px'][1]} px, {ts['stack']} frames over {ts['focus_range_m'][0]:g}–{ts['focus_range_m'][1]:g} m, "
           f"rendered with the lens's PSFs" + (f" and {', '.join(ts['effects'])}" if ts["effects"] else "")
           + ". Depth errors in metres from the sensor; centre / outer: field radius (from the centre over "
           "the half-diagonal) < 0.33 / > 0.66.", "",
           "| model | file | " + " | ".join(c for c, _ in METRIC_COLS) + " |",
           "|---|---|" + "---|" * len(METRIC_COLS)]
    for name, r in metrics["models"].items():
        m = r["metrics"]
        out.append(f"| {r['label']} | `{name}` | " + " | ".join(_fmt(m.get(k)) for _, k in METRIC_COLS) + " |")
    return out


def stage_times(run_dir: Path, names: list[str]) -> list[str]:
    mk = StageMarkers(run_dir)
    out = ["| stage | wall time (s) |", "|---|---|"]
    total = 0.0
    for n in names:
        rec = mk.record(n)
        if rec is not None:
            out.append(f"| {n} | {rec['seconds']:.1f} |")
            total += rec["seconds"]
    out.append(f"| total | {total:.1f} |")
    return out


def write_report(ctx, models: list[str], names: list[str]) -> Path:
    """Write ctx.run_dir/report.md (atomic). models: the exported ONNX files (the AAT one first); names: the
    stages whose wall times it lists."""
    d = ctx.run_dir
    rep = json.loads((d / "lens_report.json").read_text())
    metrics = json.loads((d / "metrics.json").read_text())
    lines = [f"# {ctx.net} for {rep['name']}", "",
             (f"Made by `aat-train --lens` (preset {ctx.cfg['preset']}). Everything below is in this folder; "
             "`config.json` holds the resolved configuration."), "",
             "## Lens and sensor", ""] + lens_section(rep) + [
             "", "## Held-out evaluation", ""] + metrics_section(metrics) + [
             "", "![error vs field radius](error_vs_radius.png)", "",
             "![mean error over the sensor](error_over_field.png)", "",
             "## Use it", "", "```bash",
             f"aat-infer CAPTURE_DIR --model {d / models[0]} --out OUT_DIR",
             f"aat-render RGB DEPTH --lens {d / 'lens.json'} --psf {d / 'psf.onnx'} --focus-m 0.6,1,2,6 --out CAPTURE_DIR",
             "```", "", "## Stage times", ""] + stage_times(d, names) + [
             "", "## Resolved configuration", "", "```json", json.dumps(ctx.cfg, indent=1), "```", ""]
    out = d / "report.md"
    write_text_atomic(out, "\n".join(lines))
    return out
