"""`aat-diagnose` step by step: where the sim-to-real gap lies, which unmodelled effect causes it, how far it
shrinks once that effect is simulated.

1. Each capture with ground truth is run through the model; its digital twin (same depth, all-in-focus image
   and reported focus distances, rendered by the model's own simulator) is run too. gap = |error| on the
   capture - |error| on the twin, per pixel, broken down by field position, depth, defocus, stack position and
   texture with bootstrap intervals over captures and pixel tiles.
2. Every registered effect the model's simulator lacks is added to the twin, each of its candidate settings
   tried; the setting whose images come closest to the capture's is kept (fit on the images, not on the gap).
   An effect scores by how much closer the twin comes, in the images (focus-measure curves, geometry) and in
   the model's error pattern. The best is added for good and the rest tried again (greedy), while the gain is
   significant (`is_named`).
3. share_of_gap = how much of the gap the effect closes when added to the twin (predicted shrink); the
   realised shrink comes from retraining with it (`session.py`).

Torch-free: twins come from any renderer with `render(capture, aif, extra_effects, seed)`; an effect the
renderer cannot render without torch (`NeedsTorch`) is skipped and listed, not guessed.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from aat_deploy.diagnose import bins as B
from aat_deploy.diagnose import fitters
from aat_deploy.diagnose.bootstrap import binned_bootstrap, capture_bootstrap, ratio_bootstrap
from aat_deploy.diagnose.compare import distances, focus_curves, image_distances
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
    min_image_explained: float = 0.25  # ... and its twin's images (or lighting) came at least this much closer
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


def effect_label(e: fx.Effect) -> str:
    """'name(k=v, ...)'; the same text `--effects` accepts is `effect_spec`."""
    return e.name + ("(" + ", ".join(f"{k}={v}" for k, v in e.params.items()) + ")" if e.params else "")


class Diagnosis:
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

    def fit_state(self, cur: Scored) -> fitters.FitState:
        """What the fitters see in a round whose twin is `cur` (the binned renderer and sweeps kept across rounds)."""
        if self._binned is None:
            self._binned = self.twins.binned(self.factor)
        return fitters.FitState(self.twins, [r.data for r in self.runs], [r.aif_linear for r in self.runs],
                                list(cur.effects), fx.make, self.factor, self.cfg.fit_boot, self.cfg.seed,
                                self.sweep_cache, cur.fit_curves, tb=self._binned)

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

    # --- which -------------------------------------------------------------------------------------------
    def _closeness(self, base: Scored, cand: Scored, image_only: bool = False) -> np.ndarray:
        """Per capture, how much closer `cand` comes to the capture than `base`, as fractions
        (d_base - d_cand) / (d_base + floor): images (focus curves, geometry; their mean counts twice) and the
        model's error pattern. An effect that moves the images away from the capture scores at most that
        image fraction, whatever it does to the errors: it cannot be the cause. image_only: the image part alone
        (when there is no depth gap, the error pattern is noise)."""
        c = self.cfg
        out = []
        for db, dc in zip(base.dist, cand.dist):
            img = np.mean([(db.focus_curves - dc.focus_curves) / (db.focus_curves + c.floor_focus_curves),
                           (db.geometry_px - dc.geometry_px) / (db.geometry_px + c.floor_geometry_px)])
            if image_only:
                out.append(img)
                continue
            err = (db.error_pattern_m - dc.error_pattern_m) / (db.error_pattern_m + c.floor_error_m)
            both = (2 * img + err) / 3
            out.append(both if img > 0 else min(img, both))
        return np.array(out)

    def _brightness_closeness(self, base: Scored, cand: Scored) -> np.ndarray:
        """Per capture, how much closer `cand`'s lighting across the field comes to the capture's than `base`'s."""
        f = self.cfg.floor_brightness
        return np.array([(db.brightness - dc.brightness) / (db.brightness + f) for db, dc in zip(base.dist, cand.dist)])

    def _image_distance(self, s: Scored) -> float:
        c = self.cfg
        return float(sum(d.focus_curves / (1 + c.floor_focus_curves) + d.geometry_px * c.floor_focus_curves / c.floor_geometry_px
                         for d in s.dist))

    def _share(self, gap0: list[np.ndarray], base: Scored, cand: Scored) -> tuple[float, float, float]:
        """Fraction of the original gap closed by going from `base` to `cand` twins, with its interval
        (captures and tiles resampled together in numerator and denominator)."""
        num = [ec - eb for ec, eb in zip(cand.err, base.err)]
        return ratio_bootstrap(num, gap0, self.cfg.n_boot, self.cfg.seed)

    def which(self, base: Scored, candidates: list[str], image_only: bool = False) -> tuple[list[dict], list[Scored], list[dict]]:
        """Greedy search. Returns the ranked effects, the chain of twins (base, base+E1, ...) and every
        effect's best fit in every round. image_only: rank by the images alone and give no share of the gap
        (for captures whose depth gap is not significant: what they show that the simulator lacks)."""
        if self.cfg.search == "grid":
            return self._which_grid(base, candidates, image_only)
        return self._which_fit(base, candidates, image_only)

    def _entry(self, name: str, rnd: int, cur: Scored, fit: Scored, gap0, image_only: bool) -> dict:
        """A full-resolution evaluation of `fit` (the twin with the effect) against the round's twin `cur`."""
        cfg = self.cfg
        score = capture_bootstrap(self._closeness(cur, fit, image_only), n_boot=cfg.n_boot, seed=cfg.seed)
        img = score if image_only else capture_bootstrap(self._closeness(cur, fit, True), n_boot=cfg.n_boot,
                                                          seed=cfg.seed)
        share = (None, None, None) if image_only else self._share(gap0, cur, fit)
        bri = capture_bootstrap(self._brightness_closeness(cur, fit), n_boot=cfg.n_boot, seed=cfg.seed)
        return {"effect": name, "params": fit.effects[-1].params, "round": rnd,
                "closeness": score[0], "closeness_ci": [score[1], score[2]],
                "image_closeness": img[0], "image_closeness_ci": [img[1], img[2]],
                "brightness_closeness": bri[0], "brightness_closeness_ci": [bri[1], bri[2]],
                "share_of_gap": share[0], "ci_low": share[1], "ci_high": share[2],
                "distances": [asdict(d) for d in fit.dist]}

    def _pick(self, best: list, cfg: DiagnoseConfig):
        """The round's named effect among (entry, twin) pairs, or None (`is_named`, then `named_by_brightness`).
        The named entry lists in `alternatives` the other effects that would be named too and whose closeness
        interval reaches its: on these captures the images cannot tell them apart (a tilted sensor and a
        decentred element both tilt the focal surface)."""
        if not best:
            return None
        best.sort(key=lambda t: -t[0]["closeness"])
        if is_named(best[0][0], cfg.min_score):
            top = best[0]
        else:
            lit = [t for t in best if named_by_brightness(t[0], cfg.min_score)]
            if not lit:
                return None
            top = max(lit, key=lambda t: t[0]["brightness_closeness"])
        top[0]["alternatives"] = [t[0]["effect"] for t in best if t is not top and is_named(t[0], cfg.min_score)
                                  and t[0]["closeness_ci"][1] >= top[0]["closeness_ci"][0]]
        return top

    def _screen(self, state: fitters.FitState, cur_b: list, name: str, proposals: list[dict]):
        """Each proposed setting's twin at reduced resolution against the round's: (best params, image closeness
        per capture, lighting closeness per capture), best = closest focus curves and geometry; None when the
        effect cannot be judged there (binning removes it, or it cannot be rendered binned)."""
        c = self.cfg
        best = None
        for params in proposals:
            eff = fx.make(name, **params)
            if eff.binned(self.factor) is None and self.factor > 1:
                return None
            try:
                d = state.image_distances_b([eff])
            except (fx.NeedsTorch, ValueError):
                return None
            img = np.array([np.mean([(b.focus_curves - x.focus_curves) / (b.focus_curves + c.floor_focus_curves),
                                     (b.geometry_px - x.geometry_px) / (b.geometry_px + c.floor_geometry_px)])
                            for b, x in zip(cur_b, d)])
            bri = np.array([(b.brightness - x.brightness) / (b.brightness + c.floor_brightness) for b, x in zip(cur_b, d)])
            if best is None or img.mean() > best[1].mean():
                best = (params, img, bri)
        return best

    def _which_fit(self, base: Scored, candidates: list[str], image_only: bool):
        """Greedy search with fitted settings: per round, every effect's settings are fitted on the images at
        reduced resolution (`fitters`; effects without a fitter: their candidates, the closest kept), screened
        there, and only effects whose images come closer (or whose lighting does) are rendered and scored at
        full resolution; the naming rule is the grid search's."""
        return self._greedy(base, candidates, image_only, self._round_fit)

    def _round_fit(self, cur: Scored, rnd: int, remaining: list[str], gap0, evaluated: list,
                   image_only: bool) -> list:
        """One round of the fitted search: (entry, scored twin) of every effect scored at full resolution."""
        cfg = self.cfg
        state = self.fit_state(cur)
        cur_b = [image_distances(r, c, b) for r, c, b in zip(state.real_b, state.real_curves_b, state.base_b)]
        best = []
        for name in list(remaining):
            why = fx.make(name).torch_reason(self.twins.context())
            if why and not getattr(self.twins, "uses_torch", False):
                self.skipped.append({"effect": name, "reason": f"effect {name!r} needs the training package "
                                                                f"(torch): {why}"})
                self.progress(f"skipped {name}: {why}")
                remaining.remove(name)
                continue
            self.progress(f"round {rnd + 1}: fitting {name}")
            report: dict = {}
            if name in fitters.FITTERS:
                try:
                    fitted = fitters.FITTERS[name](state)
                except fx.NeedsTorch as e:
                    self.skipped.append({"effect": name, "reason": str(e)})
                    remaining.remove(name)
                    continue
                report = fitted.report
                proposals = [fitted.params] if fitted.params is not None else []
            else:
                proposals = list(fx.make(name).candidates)
            if not proposals:  # the fit found nothing: no twin to score
                evaluated.append({"effect": name, "params": None, "round": rnd + 1, "closeness": None,
                                  "share_of_gap": None, "ci_low": None, "ci_high": None, "screened_out": True,
                                  "fit": report, "note": "the fit found no setting the images support"})
                continue
            screen = self._screen(state, cur_b, name, proposals)
            if screen is not None:
                params, img, bri = screen
                if not (img.mean() > 0 or bri.mean() >= cfg.min_score):
                    sc = capture_bootstrap(img, n_boot=cfg.n_boot, seed=cfg.seed)
                    evaluated.append({"effect": name, "params": fx.make(name, **params).params, "round": rnd + 1,
                                      "closeness": sc[0], "closeness_ci": [sc[1], sc[2]],
                                      "image_closeness": sc[0], "image_closeness_ci": [sc[1], sc[2]],
                                      "brightness_closeness": float(bri.mean()), "share_of_gap": None,
                                      "ci_low": None, "ci_high": None, "screened_out": True, "fit": report,
                                      "note": f"not scored at full resolution: its images did not come closer at "
                                              f"1/{self.factor} resolution"})
                    continue
                proposals = [params]
            fit = self._best_of(name, proposals, cur, rnd)
            if fit is None:
                remaining.remove(name)
                continue
            entry = self._entry(name, rnd + 1, cur, fit, gap0, image_only)
            entry["fit"] = report
            best.append((entry, fit))
            evaluated.append(entry)
        return best

    def _best_of(self, name: str, settings: list[dict], cur: Scored, rnd: int) -> Scored | None:
        """The twin (current chain + effect `name` at each of `settings`, full resolution) whose images come
        closest to the capture's; None, with the reason kept in `skipped`, when the effect needs torch."""
        fits = []
        try:
            for params in settings:
                eff = fx.make(name, **params)
                self.progress(f"round {rnd + 1}: {effect_label(eff)}")
                fits.append(self.score_twin(cur.effects + [eff]))
        except fx.NeedsTorch as e:
            self.skipped.append({"effect": name, "reason": str(e)})
            self.progress(f"skipped {name}: {e}")
            return None
        return min(fits, key=self._image_distance)

    def _which_grid(self, base: Scored, candidates: list[str], image_only: bool = False):
        """The greedy search over every effect's candidate settings, each rendered at full resolution."""
        return self._greedy(base, candidates, image_only, self._round_grid)

    def _round_grid(self, cur: Scored, rnd: int, remaining: list[str], gap0, evaluated: list,
                    image_only: bool) -> list:
        best = []
        for name in list(remaining):
            fit = self._best_of(name, fx.make(name).candidates, cur, rnd)
            if fit is None:
                remaining.remove(name)
                continue
            entry = self._entry(name, rnd + 1, cur, fit, gap0, image_only)
            best.append((entry, fit))
            evaluated.append(entry)
        return best

    def _greedy(self, base: Scored, candidates: list[str], image_only: bool, round_fn):
        """Rounds of `round_fn` (which scores the remaining effects on the current chain and drops those it must
        skip); each round's best significant effect (`_pick`) joins the chain, until none does or max_effects."""
        gap0 = self.gap_maps(base)
        chain, ranked, remaining, evaluated = [base], [], list(candidates), []
        for rnd in range(self.cfg.max_effects):
            best = round_fn(chain[-1], rnd, remaining, gap0, evaluated, image_only)
            top = self._pick(best, self.cfg)
            if top is None:
                break
            ranked.append(top[0])
            chain.append(top[1])
            remaining.remove(top[0]["effect"])
        return ranked, chain, evaluated

def is_named(entry: dict, min_score: float) -> bool:
    """Whether the round's best effect is named: its twin comes closer to the captures, significantly (interval
    low >= min_score) in images and errors together, or else significantly in the images alone with a mean gain
    >= min_score overall. The second clause is for noisy captures: there the model's error pattern varies from
    one noise draw to the next, so a real second effect (tilt under strong noise) can lose ground in one
    capture's error pattern while every capture's images show it."""
    if entry["closeness_ci"][0] >= min_score:
        return True
    img = entry.get("image_closeness_ci")
    return img is not None and img[0] >= min_score and entry["closeness"] >= min_score


def named_by_brightness(entry: dict, min_score: float) -> bool:
    """The fallback when the round's best effect by closeness is not named: an effect whose twin comes
    significantly closer to the captures in the images once their lighting across the field counts too (interval
    lows: (2 x images + lighting) / 3 >= min_score, the lighting significantly closer) and that closes a
    significant part of the gap (share interval above 0). Vignetting needs it: focus curves and shifts barely see
    a change of brightness, and under noise its focus curves can even move away a little, yet it changes the
    model's depth at the dark edges. An effect that moves the images far away (breathing that the captures lack
    shifts their edges, which changes the regions' brightness too) still fails."""
    bri, img, low = entry.get("brightness_closeness_ci"), entry.get("image_closeness_ci"), entry.get("ci_low")
    if bri is None or img is None or low is None:
        return False
    return bri[0] >= min_score and (2 * img[0] + bri[0]) / 3 >= min_score and low > 0


def share_view(entry: dict, min_image: float = 0.25) -> tuple[float | None, str | None]:
    """The share of the gap as people should read it: (value to show, note) from an entry's `share_of_gap`,
    its interval and its image closeness. A share is a ratio of sums: it means "this much of the gap closes"
    only when the effect's twin resembles the captures and the ratio lies in 0..1. Otherwise the value shown
    is clipped to 0..1 or withheld, and the note says why (the raw number stays in `share_of_gap`)."""
    share = entry.get("share_of_gap")
    if entry.get("screened_out"):
        return None, entry.get("note")
    if share is None:
        return None, "no significant gap: no share" if entry.get("closeness") is not None else None
    img, bri = entry.get("image_closeness"), entry.get("brightness_closeness")
    if img is not None and img < 0 and (bri is None or bri < min_image):  # nor did its lighting come closer
        return None, (f"not shown: its images moved away from the captures (closeness {img:.2f}), so its twin "
                      f"does not resemble them and its share ({share:.2f}) says nothing about the cause")
    if share > 1:
        return 1.0, f"clipped to 1: the twin with it does better than the captures (raw share {share:.2f})"
    if share < 0:
        return 0.0, f"clipped to 0: adding it widens the gap (raw share {share:.2f})"
    lo = entry.get("ci_low")
    if lo is not None and lo <= 0:
        return share, "not significant: the interval includes 0"
    return share, None


def explains_gap(entry: dict, min_share: float, min_image: float = 0.25) -> bool:
    """Whether a named effect explains part of the gap: it closes a significant part of the gap (share >=
    min_share, interval above 0) AND its twin resembles the captures: its images came closer by at least
    `min_image` (fraction of the image distance), or its lighting did (vignetting, which the shape measures
    barely see). The second condition keeps a stand-in from being blamed: with a cause the registry lacks, a
    flexible effect can move the model's errors towards the captures' (weak noise raises the focus-curve floor
    a hidden focus bias also changes) while the images stay almost as far from the captures as before."""
    share, lo = entry.get("share_of_gap"), entry.get("ci_low")
    img, bri = entry.get("image_closeness"), entry.get("brightness_closeness")
    if share is None or lo is None or lo <= 0 or share < min_share or (img is not None and img < 0 and
                                                                          (bri is None or bri < min_image)):
        return False
    return img is None or img >= min_image or (bri is not None and bri >= min_image)


VERDICTS = {
    "no_gap": "The gap is not significant: nothing to explain.",
    "unexplained": ("The gap is real, but no registered effect explains it: none closes a significant part of it "
                    "with its images moving closer to the captures. The cause is something the simulator does "
                    "not model (yet)."),
    "partly_explained": "The named effects explain part of the gap; a significant part remains unexplained.",
    "explained": "The named effects explain the gap.",
}


def verdict(gap_significant: bool, ranked: list[dict], unexplained_share: float | None, cfg: DiagnoseConfig) -> str:
    """One of VERDICTS' keys: no_gap, unexplained (a significant gap and no named effect explains part of it),
    partly_explained (some do, but more than cfg.max_unexplained of the gap is left), explained."""
    if not gap_significant:
        return "no_gap"
    if not any(explains_gap(e, cfg.min_share, cfg.min_image_explained) for e in ranked):
        return "unexplained"
    return "partly_explained" if unexplained_share is not None and unexplained_share > cfg.max_unexplained \
        else "explained"


def unexplained_share(diag: Diagnosis, base: Scored, chain: list[Scored], explaining: list[bool]) -> dict:
    """The part of the gap that the effects which explain it (`explaining`, one flag per named effect, in the
    chain's order) leave: 1 - the sum of their shares, i.e. sum(gap - what each of them closes in its round) /
    sum(gap), with its two-level interval; 1 exactly when none does. Named effects that do not explain the gap
    (present in the images, but closing no significant part of it) are not credited. The value shown is
    clipped to 0..1 with a note when it falls outside (the twins overshooting the captures)."""
    gap0 = diag.gap_maps(base)
    if not any(explaining):
        est = lo = hi = 1.0
    else:
        left = [g.copy() for g in gap0]
        for k, ok in enumerate(explaining, 1):
            if ok:
                for i, (a, b) in enumerate(zip(chain[k].err, chain[k - 1].err)):
                    left[i] -= a - b
        est, lo, hi = ratio_bootstrap(left, gap0, diag.cfg.n_boot, diag.cfg.seed)
    shown, note = est, None
    if est < 0:
        shown, note = 0.0, f"clipped to 0: the twin with the named effects does better than the captures (raw {est:.2f})"
    elif est > 1:
        shown, note = 1.0, f"clipped to 1: the named effects together widen the gap (raw {est:.2f})"
    return {"share": _f(est), "ci_low": _f(lo), "ci_high": _f(hi), "shown": _f(shown), "note": note}


def annotate_shares(entries: list[dict], ranked: list[dict], cfg: DiagnoseConfig) -> None:
    """Add `share_shown` and `share_note` to every entry, and `explains_gap` (None for effects not named), in
    place."""
    named = {id(e) for e in ranked}
    for e in entries:
        e["share_shown"], e["share_note"] = share_view(e, cfg.min_image_explained)
        e["explains_gap"] = explains_gap(e, cfg.min_share, cfg.min_image_explained) if id(e) in named else None


def _f(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def focus_summary(evaluated: list[dict], ranked: list[dict]) -> dict | None:
    """What the images say about the focus metadata (docs/diagnosis.md, "Focus errors"): the error family the fit
    chose with its settings, intervals and support, and every capture's corrected focus distances, from the
    round in which `focus_metadata` was named (else its first fit); whether it was named and explains the gap."""
    fits = [e for e in evaluated if e["effect"] == "focus_metadata" and e.get("fit", {}).get("focus_fit")]
    if not fits:
        return None
    named = next((e for e in ranked if e["effect"] == "focus_metadata"), None)
    e = named if named is not None and named.get("fit", {}).get("focus_fit") else fits[0]
    return {**e["fit"]["focus_fit"], "corrected_focus": e["fit"]["corrected_focus"], "round": e["round"],
            "named": named is not None, "explains_gap": bool(named and named.get("explains_gap"))}


def shrink_summary(diag: Diagnosis, base: Scored, ranked: list[dict], chain: list[Scored]) -> dict | None:
    """Gap before and predicted after (twin with the named effects)."""
    if not ranked:
        return None
    before = float(np.nanmean(np.concatenate([g.ravel() for g in diag.gap_maps(base)])))
    after = float(np.nanmean(np.concatenate([g.ravel() for g in diag.gap_maps(chain[-1])])))
    return {"effects": [e.training_spec() for e in chain[-1].effects], "gap_before_m": before, "gap_predicted_m": after,
            "real_mae_before_m": float(np.nanmean(np.concatenate([r.err.ravel() for r in diag.runs])))}


def diagnose(model: DfFModel, twins, captures: list[CaptureData], cfg: DiagnoseConfig, progress=None) -> tuple[dict, Diagnosis, list[Scored]]:
    """The three answers as a JSON-ready dict (see docs/diagnosis.md), the Diagnosis and the twin chain."""
    diag = Diagnosis(model, twins, captures, cfg, progress)
    base = diag.score_twin([])
    where = diag.where(base)
    base_names = {e.name for e in twins.base}
    candidates = [n for n in (cfg.effects or fx.names()) if n not in base_names]
    ranked, chain, evaluated, seen = ([], [base], [], [])
    if where["significant"]:
        ranked, chain, evaluated = diag.which(base, candidates)
    elif cfg.image_search:
        # Nothing to blame for the depth error; still say what the captures show that the simulator lacks.
        seen, _, evaluated = diag.which(base, candidates, image_only=True)
    annotate_shares(evaluated, ranked, cfg)  # ranked entries are among the evaluated ones
    unexplained = (unexplained_share(diag, base, chain, [bool(e["explains_gap"]) for e in ranked])
                   if where["significant"] else None)
    code = verdict(where["significant"], ranked, unexplained["share"] if unexplained else None, cfg)
    out = {
        "gap_significant": where["significant"],
        "verdict": code,
        "verdict_text": VERDICTS[code],
        "causes": [e["effect"] for e in ranked if e["explains_gap"]],
        "unexplained_share": unexplained,
        "where": where["where"],
        "ranked_effects": ranked,
        "image_effects": [{k: e[k] for k in ("effect", "params", "closeness", "closeness_ci")} for e in seen],
        "gap": {k: v for k, v in where.items() if k != "where"},
        "effects_evaluated": evaluated,
        "effects_skipped": diag.skipped,
        "shrink": shrink_summary(diag, base, ranked, chain),
        "captures": [{"name": r.data.name, "path": str(r.data.path), "focus_m": r.data.focus_m.tolist(),
                      "mae_m": float(np.nanmean(r.err)), "twin_mae_m": float(np.nanmean(e)),
                      "warnings": r.data.warnings} for r, e in zip(diag.runs, base.err)],
        "config": asdict(cfg),
        "twin_renders": twins.renders,
        "search_factor": diag.factor,
        "focus": focus_summary(evaluated, ranked or seen),
    }
    return out, diag, chain
