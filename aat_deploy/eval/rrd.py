"""The evaluation's rerun recording (`eval.rrd`): per capture (timeline `capture`, sequence = capture index),
for each model `models/<label>/gt` and `models/<label>/depth` (DepthImage, metres, one shared depth range)
and `models/<label>/abs_error` (colour-mapped |pred − GT|, JPEG-compressed RGB, its scale in
`models/<label>/abs_error_max_m`), plus `metrics/<label>/mae_m` and `metrics/<label>/abs_rel` Scalars and the capture's name as a TextLog on
`capture`. The default blueprint puts GT, prediction and error side by side, a row per model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..io.colorize import colorize


def _entity(label: str) -> str:
    return "".join(c if c.isalnum() or c in "_-" else "_" for c in label)


class EvalRecording:
    """Streams an evaluation to an .rrd file; close() flushes it."""

    def __init__(self, path: Path, labels: list[str]):
        self.labels = labels
        self.rec = rr.RecordingStream(application_id="aat-eval", recording_id="aat-eval")
        rows = [rrb.Horizontal(*[rrb.Spatial2DView(origin=f"models/{_entity(lb)}/{part}", name=f"{lb} {part}")
                                 for part in ("gt", "depth", "abs_error")]) for lb in labels]
        blueprint = rrb.Blueprint(rrb.Vertical(*rows, rrb.Horizontal(rrb.TimeSeriesView(origin="metrics"),
                                                                     rrb.TextLogView(origin="capture"))))
        self.rec.save(str(path), default_blueprint=blueprint)

    def log_capture(self, index: int, name: str, gt: dict[str, np.ndarray], preds: dict[str, np.ndarray],
                    errors: dict[str, np.ndarray], metrics: dict[str, dict], depth_range: tuple[float, float],
                    err_max: float) -> None:
        """gt/preds/errors: label → (H, W) metres (NaN = invalid; errors signed); metrics: label → row."""
        rec = self.rec
        rec.set_time("capture", sequence=index)
        rec.log("capture", rr.TextLog(name))
        for label, pred in preds.items():
            e = f"models/{_entity(label)}"
            g = np.where(np.isfinite(gt[label]), gt[label], 0).astype(np.float32)
            rec.log(f"{e}/gt", rr.DepthImage(g, meter=1.0, depth_range=depth_range))
            rec.log(f"{e}/depth", rr.DepthImage(pred.astype(np.float32), meter=1.0, depth_range=depth_range))
            err_rgb = colorize(np.abs(errors[label]), 0.0, err_max)
            rec.log(f"{e}/abs_error", rr.Image(err_rgb).compress(jpeg_quality=90))
            rec.log(f"{e}/abs_error_max_m", rr.Scalars(float(err_max)))
            row = metrics.get(label, {})
            for k in ("mae", "abs_rel"):
                if np.isfinite(row.get(k, np.nan)):
                    rec.log(f"metrics/{_entity(label)}/{k}{'_m' if k == 'mae' else ''}", rr.Scalars(float(row[k])))
        rec.reset_time()

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
