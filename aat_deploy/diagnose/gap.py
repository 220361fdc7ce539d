"""`aat-diagnose`, step 1: where the sim-to-real gap lies.

Each capture with ground truth is run through the model; its digital twin (same depth, all-in-focus image and
reported focus distances, rendered by the model's own simulator) is run too. gap = |error| on the capture - |error|
on the twin, per pixel, broken down by field position, depth, defocus, stack position and texture with bootstrap
intervals over captures and pixel tiles (`GapAnalysis.where`). The search over effects (step 2) builds on this
(`search.py`); what the results mean, the verdict, is `verdict.py`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aat_deploy.diagnose import bins as B
from aat_deploy.diagnose import fitters
from aat_deploy.diagnose.bootstrap import binned_bootstrap
from aat_deploy.diagnose.compare import distances, focus_curves
from aat_deploy.diagnose.inputs import CaptureData
from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.normalise import normalise_stack
from aat_deploy.render import effects as fx


@dataclass
class DiagnoseConfig:
    n_boot: int = 400
    seed: int = 0
    min_rel_gap: float = 0.05  # a gap smaller than this fraction of the twin's MAE is not worth naming
    min_score: float = 0.05  # an effect must bring the twin this much closer (fraction, CI low) to be named
    min_bin_pixels: int = 200  # smaller bins are reported but never called significant
    max_effects: int = 3  # greedy rounds
    # floors of the three distances (capture vs twin): below these, differences are noise
    floor_focus_curves: float = 0.02
    floor_geometry_px: float = 0.2
    floor_error_m: float = 0.005
    floor_brightness: float = 0.01  # natural-log units (1 %)
    effects: list[str] | None = None  # restrict the search (None = every registered effect)
    image_search: bool = True  # without a significant gap, still search the effects the images show
    search: str = "fit"  # "fit": settings fitted at reduced resolution, survivors scored at full; "grid": every
    # candidate setting of every effect rendered at full resolution (the method before fitting; slow)
    search_px: int = 240  # the reduced-resolution search bins the sensor to about this many pixels across
    fit_boot: int = 100  # bootstrap replicates of the fits' intervals
    min_share: float = 0.1  # a named effect explains the gap when its share is >= this and its interval > 0
    min_image_explained: float = 0.25  # ... and its twin's images (or lighting) came at least this much closer,
    min_focus_support: float = 0.95  # or (focus metadata) this share of the fit's replicates found an error
    max_unexplained: float = 1 / 3  # more of the gap left than this (point estimate): "partly explained"


@dataclass
class Scored:
    """One twin variant evaluated on every capture."""

    effects: list[fx.Effect]
    pred: list[np.ndarray]  # per capture predicted depth on the twin (H, W), m
    err: list[np.ndarray]  # per capture |pred - gt| on the twin (H, W), NaN = unknown
    dist: list  # per capture compare.Distances
    fit_curves: list | None = None  # per capture (R, S): the twin's focus measures for the fits (fitters.fit_curves)


@dataclass
class CaptureRun:
    data: CaptureData
    stack: np.ndarray  # normalised capture stack
    curves: np.ndarray
    pred_m: np.ndarray
    err: np.ndarray
    aif_linear: np.ndarray
    binnings: list = field(default_factory=list)


def abs_error(pred_m: np.ndarray, gt_m: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(gt_m) & (gt_m > 0), np.abs(pred_m - gt_m), np.nan).astype(np.float32)


class GapAnalysis:
    """The captures run through the model, their twins, and where the gap between them lies (step 1)."""

    def __init__(self, model: DfFModel, twins, captures: list[CaptureData], cfg: DiagnoseConfig = DiagnoseConfig(),
                 progress=None):
        self.model, self.twins, self.cfg = model, twins, cfg
        self.progress = progress or (lambda msg: None)
        self.skipped: list[dict] = []  # effects the renderer could not render (torch-only), with the reason
        self.runs: list[CaptureRun] = []
        for cap in captures:
            stack = normalise_stack(cap.frames)
            out = model.infer(stack, cap.focus_m.astype(np.float32))
            aif = cap.aif_linear if cap.aif_linear is not None else out.aif
            self.runs.append(CaptureRun(cap, stack, focus_curves(stack), out.depth_m, abs_error(out.depth_m, cap.gt_m), aif))
        d_edges, t_edges = B.shared_edges([r.data.gt_m for r in self.runs], [r.aif_linear for r in self.runs])
        self.depth_edges_m, self.texture_edges = d_edges, t_edges
        for r in self.runs:
            r.binnings = B.make_binnings(r.data.gt_m, r.data.focus_m, r.aif_linear, d_edges, t_edges)
        # error-pattern bins: field radius x depth
        n_d = len(d_edges) - 1
        self.pattern = [np.where((b[0].index >= 0) & (b[2].index >= 0), b[0].index * n_d + b[2].index, -1)
                        for b in (r.binnings for r in self.runs)]
        self.n_pattern = (len(B.RADIUS_EDGES) - 1) * n_d
        w = self.runs[0].stack.shape[-1] if self.runs else 1
        self.factor = max(1, min(8, w // max(cfg.search_px, 1)))  # the search's binning
        self._binned = None  # (binned renderer) made on first use, shared by the rounds
        self.sweep_cache: dict = {}

    # --- twins -------------------------------------------------------------------------------------------
    def score_twin(self, extra: list[fx.Effect]) -> Scored:
        preds, errs, dists, curves = [], [], [], []
        for i, r in enumerate(self.runs):
            twin = self.twins.render(r.data, r.aif_linear, extra, seed=self.cfg.seed + i)
            pred = self.model.infer(twin, r.data.focus_m.astype(np.float32)).depth_m
            e = abs_error(pred, r.data.gt_m)
            preds.append(pred)
            errs.append(e)
            dists.append(distances(r.stack, r.curves, twin, r.err, e, self.pattern[i], self.n_pattern))
            if self.cfg.search == "fit":
                curves.append(fitters.fit_curves(twin, self.factor))
        return Scored(list(extra), preds, errs, dists, curves or None)

    # --- where -------------------------------------------------------------------------------------------
    def gap_maps(self, twin: Scored) -> list[np.ndarray]:
        return [r.err - e for r, e in zip(self.runs, twin.err)]

    def where(self, twin: Scored) -> dict:
        gaps = self.gap_maps(twin)
        cfg = self.cfg
        overall = binned_bootstrap(gaps, [np.where(np.isfinite(g), 0, -1) for g in gaps], 1, cfg.n_boot, cfg.seed)
        twin_mae = float(np.nanmean(np.concatenate([e.ravel() for e in twin.err])))
        real_mae = float(np.nanmean(np.concatenate([r.err.ravel() for r in self.runs])))
        thresh = cfg.min_rel_gap * twin_mae
        sig = bool((overall.ci_low[0] > 0 or overall.ci_high[0] < 0) and abs(overall.mean[0]) >= thresh)
        breakdown, where = {}, []
        for k, name in enumerate(b.name for b in self.runs[0].binnings):
            bn = self.runs[0].binnings[k]
            st = binned_bootstrap(gaps, [r.binnings[k].index for r in self.runs], len(bn.labels), cfg.n_boot, cfg.seed)
            rows = []
            for j, lab in enumerate(bn.labels):
                s = bool(st.pixels[j] >= cfg.min_bin_pixels and (st.ci_low[j] > 0 or st.ci_high[j] < 0) and abs(st.mean[j]) >= thresh)
                rows.append({"bin": lab, "gap_m": _f(st.mean[j]), "ci_low": _f(st.ci_low[j]), "ci_high": _f(st.ci_high[j]),
                             "pixels": int(st.pixels[j]), "significant": s})
                if s and sig:
                    where.append({"by": name, "bin": lab, "gap_m": _f(st.mean[j]), "ci_low": _f(st.ci_low[j]),
                                  "ci_high": _f(st.ci_high[j])})
            breakdown[name] = {"unit": bn.unit, "bins": rows}
        where.sort(key=lambda w: -abs(w["gap_m"]))
        return {"gap_m": _f(overall.mean[0]), "ci_low": _f(overall.ci_low[0]), "ci_high": _f(overall.ci_high[0]),
                "real_mae_m": real_mae, "twin_mae_m": twin_mae, "threshold_m": thresh, "significant": sig,
                "where": where, "breakdown": breakdown}


def _f(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None
