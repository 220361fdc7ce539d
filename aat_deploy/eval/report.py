"""Evaluation tables: metrics.csv, metrics.json and metrics.md from the per-capture rows and the overall means.

A row is a dict with 'capture', 'model', 'status' ("ok" | "failed"), the depth metrics of
`aat_deploy.metrics.DEPTH_KEYS` (metres for MAE/MSE/RMSE, m for SqRel, unitless otherwise), 'n_valid',
optional 'psnr' (dB), 'ssim', 'align_scale', 'align_shift' (m), 'aif_gain' and 'error' (the failure message).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ..metrics import DEPTH_KEYS

CSV_COLUMNS = ("capture", "model", "status", "n_valid") + DEPTH_KEYS + (
    "psnr", "ssim", "align_scale", "align_shift", "aif_gain", "error")
MD_COLUMNS = (("mae", "MAE m"), ("rmse", "RMSE m"), ("abs_rel", "AbsRel"), ("sq_rel", "SqRel m"),
              ("rmse_log", "RMSE-log"), ("delta1", "δ1"), ("delta2", "δ2"), ("delta3", "δ3"),
              ("psnr", "AiF PSNR dB"), ("ssim", "AiF SSIM"))
OVERALL = "ALL"


def overall_means(rows: list[dict], labels: list[str]) -> tuple[dict[str, dict], set[str]]:
    """The mean metrics per model over the captures every model scored ("ok" rows), and those captures."""
    from ..metrics import MetricAccumulator

    ok = {lb: {r["capture"] for r in rows if r["model"] == lb and r["status"] == "ok"} for lb in labels}
    common = set.intersection(*ok.values()) if ok else set()
    overall = {}
    for lb in labels:
        acc = MetricAccumulator()
        acc.rows = [r for r in rows if r["model"] == lb and r["status"] == "ok" and r["capture"] in common]
        overall[lb] = acc.result()
    return overall, common


def _clean(v):
    """JSON-safe value: NaN/inf → None, numpy scalars → Python."""
    if isinstance(v, (np.floating, np.integer)):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    return v


def write_json(path: Path, report: dict) -> None:
    path.write_text(json.dumps(_clean(report), indent=2, allow_nan=False) + "\n")


def write_csv(path: Path, rows: list[dict], overall: dict[str, dict]) -> None:
    """One line per (capture, model), then one 'ALL' line per model (mean over the common captures)."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt_csv(r.get(k)) for k in CSV_COLUMNS})
        for label, m in overall.items():
            w.writerow({k: _fmt_csv(v) for k, v in {"capture": OVERALL, "model": label, "status": "mean",
                                                   "n_valid": m.get("n_images"), **m}.items() if k in CSV_COLUMNS})


def _fmt_csv(v):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return v


def _fmt(v, key: str) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if key in ("psnr",):
        return f"{v:.2f}"
    if key.startswith("delta") or key == "ssim":
        return f"{v:.3f}"
    return f"{v:.4f}"


def markdown(report: dict) -> str:
    """The Markdown summary: models, the overall table (one row per model), the per-capture table
    (one row per capture and model) and failures."""
    rows, overall = report["per_capture"], report["overall"]
    cols = [(k, name) for k, name in MD_COLUMNS
            if any(k in r for r in rows if r.get("status") == "ok") or any(k in m for m in overall.values())]
    align = report["options"].get("align")
    out = [f"# aat-eval: {report['root']}", ""]
    out.append("Depth in metres from the sensor plane; metrics per capture over valid ground-truth pixels "
               "(finite, > 0" + (", inside the focus range" if report["options"].get("focus_range_mask") else "")
               + "), then the mean over captures (so mean RMSE ≠ √mean MSE). "
               + ("Metric depth scored as predicted (no scale or shift fitted)." if not align else
                  f"Prediction aligned per capture ({align}: p' = s·p + t, fitted to the ground truth)."))
    out.append("")
    out.append("| model | file | simulator | net |")
    out.append("|---|---|---|---|")
    for m in report["models"]:
        out.append(f"| {m['label']} | `{m['path']}` | {m.get('aat.simulator', '–')} | {m.get('aat.net', '–')} |")
    out += ["", f"## Overall ({len(report['overall_captures'])} capture(s) scored by every model)", ""]
    out.append("| model | captures | " + " | ".join(n for _, n in cols) + " |")
    out.append("|---|---:|" + "---:|" * len(cols))
    for label, m in overall.items():
        out.append(f"| {label} | {m.get('n_images', 0)} | " + " | ".join(_fmt(m.get(k), k) for k, _ in cols) + " |")
    extra = [("align_scale", "scale s"), ("align_shift", "shift t m")] if align else []
    out += ["", "## Per capture", ""]
    out.append("| capture | model | pixels | " + " | ".join(n for _, n in cols + extra) + " |")
    out.append("|---|---|---:|" + "---:|" * len(cols + extra))
    for r in rows:
        if r.get("status") != "ok":
            continue
        out.append(f"| {r['capture']} | {r['model']} | {r.get('n_valid', 0)} | "
                   + " | ".join(_fmt(r.get(k), k) for k, _ in cols + extra) + " |")
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        out += ["", "## Failed", ""] + [f"- {r['capture']} ({r['model']}): {r.get('error', '')}" for r in failed]
    if report.get("skipped_without_gt"):
        out += ["", f"{len(report['skipped_without_gt'])} folder(s) with frames but no ground truth were skipped."]
    return "\n".join(out) + "\n"
