"""`aat-diagnose` step by step: where the sim-to-real gap lies, which unmodelled effect causes it, how far it
shrinks once that effect is simulated. This module holds step 2 and the entry point, `diagnose`.

1. Where (`gap.py`): each capture with ground truth against its digital twin; gap = |error| on the capture -
   |error| on the twin, broken down by field position, depth, defocus, stack position and texture.
2. Which (here): every registered effect the model's simulator lacks is added to the twin, each of its candidate
   settings tried; the setting whose images come closest to the capture's is kept (fit on the images, not on the
   gap). An effect scores by how much closer the twin comes, in the images (focus-measure curves, geometry) and in
   the model's error pattern. The best is added for good and the rest tried again (greedy), while the gain is
   significant (`is_named`). Every effect tried in a round is one `EffectEntry`.
3. How much (`verdict.py`): share_of_gap = how much of the gap the effect closes when added to the twin
   (predicted shrink), whether the named effects explain the gap, and the verdict; the realised shrink comes from
   retraining with it (`session.py`).

Torch-free: twins come from any renderer with `render(capture, aif, extra_effects, seed)`; an effect the
renderer cannot render without torch (`NeedsTorch`) is skipped and listed, not guessed.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from aat_deploy.diagnose import fitters
from aat_deploy.diagnose.bootstrap import capture_bootstrap, ratio_bootstrap
from aat_deploy.diagnose.compare import image_distances
from aat_deploy.diagnose.gap import DiagnoseConfig, GapAnalysis, Scored
from aat_deploy.diagnose.inputs import CaptureData
from aat_deploy.diagnose.verdict import (
    VERDICTS,
    annotate_shares,
    explains_gap,
    focus_measured,
    focus_summary,
    shrink_summary,
    unexplained_share,
    verdict,
)
from aat_deploy.infer.model import DfFModel
from aat_deploy.render import effects as fx


class _Absent:
    """A field an effect entry does not have: left out of its dict (and diagnosis.json), unlike None (null)."""

    def __repr__(self) -> str:
        return "ABSENT"


ABSENT = _Absent()


@dataclass
class EffectEntry:
    """One effect tried in one round of the search, as diagnosis.json's `effects_evaluated` and `ranked_effects`
    list it (docs/diagnosis.md). Three kinds: scored at full resolution (closeness and its parts with intervals,
    the share of the gap, per-capture distances), screened out at reduced resolution (`screened_out`, `note`: its
    images did not come closer), or with no setting the images support (`screened_out`, `note`, no intervals).
    Closeness values are fractions (how much closer the twin with it comes to the captures), shares fractions of
    the gap. Fields left ABSENT are not in `as_dict()`; the search and `verdict.py` add `alternatives`,
    `share_shown`, `share_note` and `explains_gap` to that dict."""

    effect: str
    params: dict | None
    round: int
    closeness: float | None
    closeness_ci: list | _Absent = ABSENT
    image_closeness: float | _Absent = ABSENT
    image_closeness_ci: list | _Absent = ABSENT
    brightness_closeness: float | _Absent = ABSENT
    brightness_closeness_ci: list | _Absent = ABSENT
    share_of_gap: float | None = None
    ci_low: float | None = None
    ci_high: float | None = None
    screened_out: bool | _Absent = ABSENT
    distances: list | _Absent = ABSENT
    fit: dict | _Absent = ABSENT  # the fitter's report (fitted search)
    note: str | _Absent = ABSENT

    def as_dict(self) -> dict:
        """The JSON-ready dict, keys in the fields' order, ABSENT fields left out."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not ABSENT}


def effect_label(e: fx.Effect) -> str:
    """'name(k=v, ...)'; the same text `--effects` accepts is `effect_spec`."""
    return e.name + ("(" + ", ".join(f"{k}={v}" for k, v in e.params.items()) + ")" if e.params else "")


class Diagnosis(GapAnalysis):
    """Steps 1 and 2: the gap (`GapAnalysis`) and the greedy search over effects."""

    def fit_state(self, cur: Scored) -> fitters.FitState:
        """What the fitters see in a round whose twin is `cur` (the binned renderer and sweeps kept across rounds)."""
        if self._binned is None:
            self._binned = self.twins.binned(self.factor)
        return fitters.FitState(self.twins, [r.data for r in self.runs], [r.aif_linear for r in self.runs],
                                list(cur.effects), fx.make, self.factor, self.cfg.fit_boot, self.cfg.seed,
                                self.sweep_cache, cur.fit_curves, tb=self._binned)

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

    def _image_distance(self, dist: list) -> float:
        """One number for a twin's per-capture `compare.Distances` (focus curves and geometry): which candidate
        setting of an effect comes closest."""
        c = self.cfg
        return float(sum(d.focus_curves / (1 + c.floor_focus_curves) + d.geometry_px * c.floor_focus_curves / c.floor_geometry_px
                         for d in dist))

    def _twin_image_distances(self, extra: list[fx.Effect]) -> list:
        """Per capture, the image part of `score_twin`'s distances (the model not run)."""
        return [image_distances(r.stack, r.curves, self.twins.render(r.data, r.aif_linear, extra, seed=self.cfg.seed + i))
                for i, r in enumerate(self.runs)]

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

    def _entry(self, name: str, rnd: int, cur: Scored, fit: Scored, gap0, image_only: bool,
               fit_report: dict | _Absent = ABSENT) -> dict:
        """A full-resolution evaluation of `fit` (the twin with the effect) against the round's twin `cur`, as an
        `EffectEntry`'s dict (with the fitter's report, in the fitted search)."""
        cfg = self.cfg
        score = capture_bootstrap(self._closeness(cur, fit, image_only), n_boot=cfg.n_boot, seed=cfg.seed)
        img = score if image_only else capture_bootstrap(self._closeness(cur, fit, True), n_boot=cfg.n_boot,
                                                          seed=cfg.seed)
        share = (None, None, None) if image_only else self._share(gap0, cur, fit)
        bri = capture_bootstrap(self._brightness_closeness(cur, fit), n_boot=cfg.n_boot, seed=cfg.seed)
        return EffectEntry(name, fit.effects[-1].params, rnd, score[0], [score[1], score[2]], img[0], [img[1], img[2]],
                           bri[0], [bri[1], bri[2]], share[0], share[1], share[2],
                           distances=[asdict(d) for d in fit.dist], fit=fit_report).as_dict()

    def _pick(self, best: list, cfg: DiagnoseConfig, focus_route: bool = True):
        """The round's named effect among (entry, twin) pairs, or None (`is_named`, then `named_by_brightness`).
        A focus-metadata error the focus fit measured (`named_by_focus`) is named before them, while the fit
        measured it in every earlier round too (`focus_route`, `_greedy`). The named entry
        lists in `alternatives` the other effects that would be named too and whose closeness interval reaches
        its: on these captures the images cannot tell them apart (a tilted sensor and a decentred element both
        tilt the focal surface)."""
        if not best:
            return None
        best.sort(key=lambda t: -t[0]["closeness"])
        measured = [t for t in best if focus_route and named_by_focus(t[0], cfg)]
        if measured:  # the fit's evidence, not closeness: first, so later rounds fit on the corrected focus
            top = measured[0]
        elif is_named(best[0][0], cfg.min_score):
            top = best[0]
        else:
            lit = [t for t in best if named_by_brightness(t[0], cfg.min_score)]
            if not lit:
                return None
            top = max(lit, key=lambda t: t[0]["brightness_closeness"])
        # the effects the images cannot tell apart from it; none for focus named on its fit's measurement
        top[0]["alternatives"] = [] if measured else [
            t[0]["effect"] for t in best if t is not top and is_named(t[0], cfg.min_score)
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
                evaluated.append(EffectEntry(name, None, rnd + 1, None, screened_out=True, fit=report,
                                             note="the fit found no setting the images support").as_dict())
                continue
            # a measured focus error is scored at full resolution whatever its binned images do (they barely move)
            route = getattr(self, "_focus_route", True)  # set per round by `_greedy`
            measured = route and focus_measured({"effect": name, "fit": report}, cfg.min_focus_support)
            screen = None if measured else self._screen(state, cur_b, name, proposals)
            if screen is not None:
                params, img, bri = screen
                if not (img.mean() > 0 or bri.mean() >= cfg.min_score):
                    sc = capture_bootstrap(img, n_boot=cfg.n_boot, seed=cfg.seed)
                    evaluated.append(EffectEntry(
                        name, fx.make(name, **params).params, rnd + 1, sc[0], [sc[1], sc[2]], sc[0], [sc[1], sc[2]],
                        float(bri.mean()), screened_out=True, fit=report,
                        note=f"not scored at full resolution: its images did not come closer at 1/{self.factor} "
                             f"resolution").as_dict())
                    continue
                proposals = [params]
            fit = self._best_of(name, proposals, cur, rnd)
            if fit is None:
                remaining.remove(name)
                continue
            entry = self._entry(name, rnd + 1, cur, fit, gap0, image_only, fit_report=report)
            best.append((entry, fit))
            evaluated.append(entry)
        return best

    def _best_of(self, name: str, settings: list[dict], cur: Scored, rnd: int) -> Scored | None:
        """The twin (current chain + effect `name` at each of `settings`, full resolution) whose images come
        closest to the capture's, scored; None, with the reason kept in `skipped`, when the effect needs torch.
        The settings are compared on their images alone, so the model runs on the closest one only (the twins'
        optics are cached: scoring it renders no new optics)."""
        try:
            effs = [fx.make(name, **params) for params in settings]
            best, best_d = effs[0], None
            for eff in effs:
                self.progress(f"round {rnd + 1}: {effect_label(eff)}")
                if len(effs) > 1:
                    d = self._image_distance(self._twin_image_distances(cur.effects + [eff]))
                    if best_d is None or d < best_d:  # the first of equals, as min() took it
                        best, best_d = eff, d
            return self.score_twin(cur.effects + [best])
        except fx.NeedsTorch as e:
            self.skipped.append({"effect": name, "reason": str(e)})
            self.progress(f"skipped {name}: {e}")
            return None

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
            # focus metadata is named on its measurement only while every earlier round's fit measured it too: a
            # later twin carries the effects named so far, and a stand-in among them bends the focus curves
            # (scene 2027's untouched copy: after a phone pipeline its third round read a 1.018 scale)
            self._focus_route = focus_route(evaluated, self.cfg)
            best = round_fn(chain[-1], rnd, remaining, gap0, evaluated, image_only)
            if not self._focus_route:  # nor does the verdict count this round's measurement (`focus_measured`)
                for e in evaluated:
                    if e["effect"] == "focus_metadata" and e.get("round") == rnd + 1:
                        e["focus_route"] = False
            top = self._pick(best, self.cfg, self._focus_route)
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


def focus_route(evaluated: list[dict], cfg: DiagnoseConfig) -> bool:
    """Whether focus metadata may still be named on its fit's measurement (`named_by_focus`): every earlier
    round's focus fit (the entries so far) measured an error (`verdict.focus_measured`). A fit that found the
    reported focus right on a plainer twin and an error only once other effects joined it reads those effects,
    not the camera's metadata."""
    return all(focus_measured(e, cfg.min_focus_support) for e in evaluated if e["effect"] == "focus_metadata")


def named_by_focus(entry: dict, cfg: DiagnoseConfig) -> bool:
    """Focus metadata named on its measured focus (issue 32): the focus fit measured the frames focused elsewhere
    than reported (`verdict.focus_measured`: an error family in at least `min_focus_support` of the bootstrap's
    replicates, some reported focus outside its corrected interval) and correcting the focus closes a significant
    part of the gap (`verdict.explains_gap`: share >= `min_share`, interval above 0, its images not moved away;
    with no significant gap, the measurement alone, as the image-only search lists what the captures show). A
    focus error changes the model's depth a lot and the images little (a frame 0.05 D off moves its focus curves
    about as much as the capture's noise), so closeness, the images' measure, missed it in 5 of the benchmark's
    33 error sets. Only focus metadata has
    this route; an untouched copy's fit chooses `none` and cannot take it."""
    if not focus_measured(entry, cfg.min_focus_support):
        return False
    if entry.get("share_of_gap") is None and entry.get("ci_low") is None:
        return True
    return explains_gap(entry, cfg.min_share, cfg.min_image_explained, cfg.min_focus_support)


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
        "focus": focus_summary(evaluated, ranked or seen, cfg.min_focus_support),
    }
    return out, diag, chain
