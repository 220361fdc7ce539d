"""`aat-diagnose`, step 3: what the search's results mean. A share of the gap as people should read it
(`share_view`), whether a named effect explains the gap (`explains_gap`), the part left unexplained
(`unexplained_share`), the verdict (`VERDICTS`, `verdict`), and the summaries of the focus fit and of the predicted
shrink. Entries are the search's effect entries as dicts (`search.EffectEntry.as_dict`).
"""

from __future__ import annotations

import numpy as np

from aat_deploy.diagnose.bootstrap import ratio_bootstrap
from aat_deploy.diagnose.gap import DiagnoseConfig, GapAnalysis, Scored, _f


def share_view(entry: dict, min_image: float = 0.25, min_focus_support: float = 0.95
               ) -> tuple[float | None, str | None]:
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
    measured = focus_measured(entry, min_focus_support)  # a focus error's images barely move: see explains_gap
    if img is not None and img < (-min_image if measured else 0) and (bri is None or bri < min_image):
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


def focus_measured(entry: dict, min_support: float = 0.95) -> bool:
    """Whether `focus_metadata`'s fit measured a focus error in the captures (docs/diagnosis.md, "Verdict"): a family
    other than `none`, some error family chosen in at least `min_support` of the bootstrap replicates, and some
    frame's reported focus outside the 95 % interval of its corrected focus (its systematic error included,
    `focusfit.corrected_sd`, when the fit reports it). The fit reads every frame's focus
    from the images (each region's focus curve against the twin's focus sweep), which is what a focus error
    changes; the images' distances barely move with it (a frame 0.05 D off changes its focus curves little more
    than the capture's noise does) while the model's depth does. So for focus metadata this is the evidence that
    its twin resembles the captures. False for every other effect."""
    fit = entry.get("fit") or {}
    f = fit.get("focus_fit") or {}
    if entry.get("effect") != "focus_metadata" or f.get("family", "none") == "none":
        return False
    if entry.get("focus_route") is False:  # an earlier round's fit found no error (`search.focus_route`)
        return False
    if 1.0 - (f.get("support") or {}).get("none", 0.0) < min_support:
        return False
    # the interval with the per-frame estimates' systematic error (`total_ci_m`) where the fit gives it
    return any(not lo <= rep <= hi for c in fit.get("corrected_focus", [])
               for rep, (lo, hi) in zip(c["reported_m"], c.get("total_ci_m", c["ci_m"])))


def explains_gap(entry: dict, min_share: float, min_image: float = 0.25, min_focus_support: float = 0.95) -> bool:
    """Whether a named effect explains part of the gap: it closes a significant part of the gap (share >=
    min_share, interval above 0) AND its twin resembles the captures: its images came closer by at least
    `min_image` (fraction of the image distance), or its lighting did (vignetting, which the shape measures
    barely see), or, for focus metadata, its fit measured the frames focused elsewhere than reported
    (`focus_measured`). The second condition keeps a stand-in from being blamed: with a cause the registry lacks,
    a flexible effect can move the model's errors towards the captures' (weak noise raises the focus-curve floor
    a hidden focus bias also changes) while the images stay almost as far from the captures as before."""
    share, lo = entry.get("share_of_gap"), entry.get("ci_low")
    img, bri = entry.get("image_closeness"), entry.get("brightness_closeness")
    if share is None or lo is None or lo <= 0 or share < min_share:
        return False
    if focus_measured(entry, min_focus_support):
        # its evidence is the fit's; its images barely move either way (-0.03..0.06 on the benchmark's error sets,
        # noise), so only images that moved away by as much as an explaining effect's must come closer refute it
        return img is None or img > -min_image
    if img is not None and img < 0 and (bri is None or bri < min_image):
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
    if not any(explains_gap(e, cfg.min_share, cfg.min_image_explained, cfg.min_focus_support) for e in ranked):
        return "unexplained"
    return "partly_explained" if unexplained_share is not None and unexplained_share > cfg.max_unexplained \
        else "explained"


def unexplained_share(diag: GapAnalysis, base: Scored, chain: list[Scored], explaining: list[bool]) -> dict:
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
        e["share_shown"], e["share_note"] = share_view(e, cfg.min_image_explained, cfg.min_focus_support)
        e["explains_gap"] = (explains_gap(e, cfg.min_share, cfg.min_image_explained, cfg.min_focus_support)
                             if id(e) in named else None)



def focus_summary(evaluated: list[dict], ranked: list[dict], min_support: float = 0.95) -> dict | None:
    """What the images say about the focus metadata (docs/diagnosis.md, "Focus errors"): the error family the fit
    chose with its settings, intervals and support, and every capture's corrected focus distances, from the
    round in which `focus_metadata` was named (else its first fit); whether it was named and explains the gap, and
    whether the corrected distances are recommended (`correction_advice`: `corrected_recommended`,
    `corrected_note`)."""
    fits = [e for e in evaluated if e["effect"] == "focus_metadata" and e.get("fit", {}).get("focus_fit")]
    if not fits:
        return None
    named = next((e for e in ranked if e["effect"] == "focus_metadata"), None)
    e = named if named is not None and named.get("fit", {}).get("focus_fit") else fits[0]
    ok, note = correction_advice(e, named is not None, min_support)
    return {**e["fit"]["focus_fit"], "corrected_focus": e["fit"]["corrected_focus"], "round": e["round"],
            "named": named is not None, "explains_gap": bool(named and named.get("explains_gap")),
            "corrected_recommended": ok, "corrected_note": note}


def correction_advice(entry: dict, named: bool, min_support: float = 0.95) -> tuple[bool, str | None]:
    """Whether the diagnosis recommends the focus fit's corrected focus distances (the drop-in
    `corrected_focus/<capture>/capture.json`), and why not: only when the diagnosis itself names focus metadata
    (among the causes it ranks, or, with no significant gap, among the effects the images show) AND the fit's
    own evidence measured an error (`focus_measured`: an error family in at least `min_support` of the bootstrap
    replicates, some reported focus outside its corrected interval). The fit chooses a family on every set; a twin
    that lacks an effect the captures have (vignetting, the RAW development) bends its per-frame estimates like a
    gentle curve where the frames see little in focus (issue 32, scene 2038's untouched copy: family `monotone`,
    corrected up to 0.044 D off, while the diagnosis named noise and vignetting). Recommending those distances then
    would make a right capture.json worse. (True, None) when recommended; (False, None) when the family is `none`
    (nothing to correct)."""
    f = (entry.get("fit") or {}).get("focus_fit") or {}
    if f.get("family", "none") == "none":
        return False, None
    if not named:
        return False, (f"not recommended: the fit's best family is {f['family']}, but the diagnosis does not name "
                       "focus metadata (the twin's other misfits can bend the per-frame estimates like a focus "
                       "error); the reported focus distances stand, and no capture.json was written")
    if not focus_measured(entry, min_support):
        share = 1.0 - (f.get("support") or {}).get("none", 0.0)
        return False, (f"not recommended: the fit's evidence does not hold (it needs an error family in at least "
                       f"{min_support:.0%} of the bootstrap replicates, here {share:.0%}, and some reported focus "
                       "outside its corrected 95 % interval); the reported focus distances stand, and no "
                       "capture.json was written")
    return True, None


def shrink_summary(diag: GapAnalysis, base: Scored, ranked: list[dict], chain: list[Scored]) -> dict | None:
    """Gap before and predicted after (twin with the named effects)."""
    if not ranked:
        return None
    before = float(np.nanmean(np.concatenate([g.ravel() for g in diag.gap_maps(base)])))
    after = float(np.nanmean(np.concatenate([g.ravel() for g in diag.gap_maps(chain[-1])])))
    return {"effects": [e.training_spec() for e in chain[-1].effects], "gap_before_m": before, "gap_predicted_m": after,
            "real_mae_before_m": float(np.nanmean(np.concatenate([r.err.ravel() for r in diag.runs])))}

