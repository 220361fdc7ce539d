"""`aat-eval --dataset NAME PATH`: run DfF models and/or the classical method on a public benchmark read by
`aat_deploy.eval.datasets` and score them against its ground truth as the field does (its unit, valid pixels, clip;
per stack, then the mean over stacks).

Each stack goes through the runtime's array path (`aat_deploy.infer.process.depth_from_frames`, as `aat-infer` and the
Python API): fitted to the model's sensor (or the focus method's working size), normalised, inferred. The ground
truth is brought to that working grid by nearest sampling (docs/contracts.md, "Ground truth"), the prediction
converted to the dataset's unit. Output folder (written whole or not at all; replaced only with force):
  metrics.csv, metrics.json, metrics.md   per stack and model, and the mean per model over the stacks every model
                                          scored (MSE, RMSE, AbsRel, delta1 ... in the dataset's unit)
  maps/<model>/<stack>.png                prediction | ground truth | |error| (one colour scale per stack), or the
                                          prediction alone where there is no ground truth (shown, not scored)
A stack that fails is reported on one line and the others go on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import CaptureError
from ..gt.read import to_sensor
from ..infer.process import depth_from_frames
from ..io.atomic import atomic_folder, writing
from ..io.colorize import colorize
from ..metrics import depth_metrics
from . import plots, report
from .batch import Progress
from .datasets import Dataset

TABLE = (("mae", "MAE"), ("mse", "MSE"), ("rmse", "RMSE"), ("abs_rel", "AbsRel"), ("sq_rel", "SqRel"),
         ("delta1", "δ1"), ("delta2", "δ2"), ("delta3", "δ3"))


@dataclass
class DatasetEvalOptions:
    limit: int | None = None  # only the first N stacks
    force: bool = False
    quiet: bool = False
    pictures: bool = True
    messages: list[str] = field(default_factory=list)


def score_stack(pred_m: np.ndarray, gt: np.ndarray, mask: np.ndarray | None, frame_wh: tuple[int, int],
                crop_xywh, ds: Dataset, where: str) -> tuple[dict, np.ndarray, np.ndarray]:
    """(metrics in the dataset's unit plus `coverage`, the share of valid ground-truth pixels the prediction
    answers (not NaN); prediction and ground truth in that unit on the working grid, NaN = not scored) of one
    working-size depth map (h, w) in metres against the dataset's ground truth."""
    h, w = pred_m.shape
    g = to_sensor(gt, frame_wh, tuple(crop_xywh), (w, h), where).astype(np.float64)
    valid = np.isfinite(g) & (g > 0)
    if mask is not None:
        valid &= to_sensor(mask.astype(np.uint8), frame_wh, tuple(crop_xywh), (w, h), where).astype(bool)
    conv = ds.conventions
    p = np.asarray(conv.to_unit(np.asarray(pred_m, np.float64)), np.float64)
    if conv.clip is not None:
        p, g = np.clip(p, *conv.clip), np.clip(g, *conv.clip)
    n_gt = int(valid.sum())
    valid &= np.isfinite(p)  # a method may leave pixels unknown (NaN): scored where it answers, coverage reported
    row = depth_metrics(p, np.where(valid, g, 0.0), mask=valid)
    row["coverage"] = float(valid.sum() / n_gt) if n_gt else 0.0
    return row, p, np.where(valid, g, np.nan)


def evaluate_dataset(ds: Dataset, methods: list[tuple[str, object]], out_dir: str | Path, opts: DatasetEvalOptions
                     ) -> dict:
    """Score `methods` [(label, DfFModel or FocusMethod)] on every stack of `ds`; returns the report (metrics.json).
    The output folder must have been checked by the caller (aat_deploy.io.guard.check_output_dir)."""
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    n = len(ds) if opts.limit is None else min(len(ds), opts.limit)
    rows: list[dict] = []
    with writing(out_dir), atomic_folder(out_dir, opts.force, "aat-eval") as tmp:
        for label, _ in methods:
            (tmp / "maps" / label).mkdir(parents=True)
        bar = Progress(n * len(methods), opts.quiet)

        def fail(name: str, label: str, msg: str) -> None:
            bar.fail(rows, opts.messages, name, label, msg)

        try:
            items = ds.items()
            for k in range(n):
                try:
                    item = next(items)
                except StopIteration:
                    break
                except CaptureError as e:  # a damaged stack: the reader cannot go on past it
                    for label, _ in methods:
                        fail(f"#{k}", label, str(e))
                    break
                for label, model in methods:
                    try:
                        rows.append(_run_one(ds, item, label, model, tmp, opts))
                    except CaptureError as e:
                        fail(item.name, label, str(e))
                    except MemoryError:
                        fail(item.name, label, "out of memory")
                    except Exception as e:  # noqa: BLE001 (one stack's surprise must not stop the batch)
                        fail(item.name, label, f"unexpected {type(e).__name__}: "
                                               f"{str(e).splitlines()[0] if str(e) else ''}")
                    bar.step(f"{item.name} ({label})")
        finally:
            bar.close()
        result = _tables(tmp, ds, methods, rows)
        result["seconds"] = round(time.perf_counter() - t0, 2)
        report.write_json(tmp / "metrics.json", result)
    return result


def _run_one(ds: Dataset, item, label: str, model, tmp: Path, opts: DatasetEvalOptions) -> dict:
    t0 = time.perf_counter()
    res = depth_from_frames(item.frames, np.asarray(item.focus_m, np.float32), model, name=item.name, quiet=True)
    pred = res.working.depth_m
    row = {"capture": item.name, "model": label, "working_size_px": list(res.working_size),
           "warnings": res.warnings, "seconds": round(time.perf_counter() - t0, 3)}
    if item.gt is None:
        if opts.pictures:
            shown = ds.conventions.to_unit(np.asarray(pred, np.float64))
            lo, hi = np.nanpercentile(shown, [1, 99]) if np.isfinite(shown).any() else (0.0, 1.0)
            plots.write_rgb_png(tmp / "maps" / label / f"{item.name}.png", colorize(shown, lo, max(hi, lo + 1e-9)))
        return {**row, "status": "shown"}
    frame_hw = res.frame_hw
    metrics, p, g = score_stack(pred, item.gt, item.mask, (frame_hw[1], frame_hw[0]), res.geometry["crop_xywh"],
                                ds, f"{item.name} ground truth")
    if opts.pictures and np.isfinite(g).any():
        lo, hi = np.nanpercentile(g, [1, 99])
        hi = max(hi, lo + 1e-9)
        err = np.abs(p - g)
        emax = max(float(np.nanpercentile(err, 99)) if np.isfinite(err).any() else 1.0, 1e-9)
        panel = np.hstack([colorize(p, lo, hi), colorize(g, lo, hi), colorize(err, 0.0, emax)])
        plots.write_rgb_png(tmp / "maps" / label / f"{item.name}.png", panel)
    return {**row, "status": "ok" if metrics["n_valid"] else "failed", **metrics,
            **({} if metrics["n_valid"] else {"error": "no valid ground-truth pixel"})}


def _tables(tmp: Path, ds: Dataset, methods, rows: list[dict]) -> dict:
    labels = [lb for lb, _ in methods]
    overall, common = report.overall_means(rows, labels)
    result = {"dataset": ds.describe(), "units": ds.conventions.unit, "conventions": ds.conventions.text,
              "models": [{"label": lb, **m.summary()} for lb, m in methods], "per_capture": rows,
              "overall": overall, "overall_captures": sorted(common),
              "shown_without_ground_truth": sorted({r["capture"] for r in rows if r["status"] == "shown"}),
              "failed": [f"{r['capture']} ({r['model']}): {r['error']}" for r in rows if r["status"] == "failed"]}
    report.write_csv(tmp / "metrics.csv", rows, overall)
    (tmp / "metrics.md").write_text(markdown(result))
    return result


def markdown(result: dict) -> str:
    """The tables of a dataset evaluation: the conventions, the mean per model, then per stack."""
    d = result["dataset"]
    unit = {"disparity": "disparity units", "depth_m": "m"}.get(result["units"], result["units"])
    out = [f"# aat-eval on {d['dataset']}: {d.get('path', '')}", "", result["conventions"], ""]
    out += ["| model | what |", "|---|---|"]
    for m in result["models"]:
        what = m.get("method") or m.get("aat.net") or "model"
        out.append(f"| {m['label']} | {what} {m.get('path', '') or ''} |".replace("  |", " |"))
    cols = [(k, f"{name} ({unit})" if k in ("mae", "rmse") else (f"{name} ({unit}²)" if k in ("mse", "sq_rel")
                                                                  else name)) for k, name in TABLE]
    out += ["", f"## Mean over the {len(result['overall_captures'])} stack(s) every model scored", ""]
    out.append("| model | stacks | " + " | ".join(n for _, n in cols) + " |")
    out.append("|---|---:|" + "---:|" * len(cols))
    for label, m in result["overall"].items():
        out.append(f"| {label} | {m.get('n_images', 0)} | " + " | ".join(report._fmt(m.get(k), k) for k, _ in cols)
                   + " |")
    cov = [r["coverage"] for r in result["per_capture"] if r.get("status") == "ok" and "coverage" in r]
    if cov and min(cov) < 1:
        out += ["", f"Predictions left some pixels unknown (NaN): scored where they answer; coverage of the valid "
                f"ground truth per stack {min(cov):.3f} .. {max(cov):.3f} (metrics.json has each)."]
    scored = [r for r in result["per_capture"] if r.get("status") == "ok"]
    if scored:
        out += ["", "## Per stack", "", "| stack | model | pixels | " + " | ".join(n for _, n in cols) + " |",
                "|---|---|---:|" + "---:|" * len(cols)]
        for r in scored:
            out.append(f"| {r['capture']} | {r['model']} | {r.get('n_valid', 0)} | "
                       + " | ".join(report._fmt(r.get(k), k) for k, _ in cols) + " |")
    if result["shown_without_ground_truth"]:
        out += ["", f"{len(result['shown_without_ground_truth'])} stack(s) without ground truth: shown in maps/, "
                "not scored."]
    if result["failed"]:
        out += ["", "## Failed", ""] + [f"- {f}" for f in result["failed"]]
    return "\n".join(out) + "\n"


__all__ = ["DatasetEvalOptions", "evaluate_dataset", "markdown", "score_stack"]
