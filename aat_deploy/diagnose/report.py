"""The diagnosis report: `diagnosis.json` (for machines), `report.md` + PNG figures (for people) and
`diagnosis.rrd` (captures, twins and gap maps side by side in the rerun viewer)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

ANSWER_KEYS = ("gap_significant", "where", "ranked_effects")


def write_json(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(obj, indent=2, allow_nan=False, default=_default))


def _default(v):
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    raise TypeError(f"not JSON-serialisable: {type(v).__name__}")


def _fmt(x, nd=3) -> str:
    return "—" if x is None else f"{x:.{nd}f}"


def markdown(d: dict) -> str:
    w = d["gap"]
    lines = [f"# Sim-to-real diagnosis: {d['model']['file']}", "",
             f"Model: {d['model']['net']} trained with the `{d['model']['simulator']}` simulator"
             f"{' + ' + ', '.join(d['model']['effects']) if d['model']['effects'] else ''}; "
             f"{len(d['captures'])} capture(s) with ground truth under `{d['root']}`.", "",
             "## 1. Where", "",
             f"Mean absolute depth error on the captures {w['real_mae_m']:.3f} m, on their digital twins "
             f"{w['twin_mae_m']:.3f} m: gap {w['gap_m']:+.3f} m (95 % interval {w['ci_low']:+.3f} … {w['ci_high']:+.3f}). "
             + ("**The gap is significant.**" if d["gap_significant"] else
                f"**The gap is not significant** (interval includes 0 or |gap| < {w['threshold_m']:.3f} m, "
                "5 % of the twin's error): nothing to blame."), ""]
    if d["where"]:
        lines += ["Significant bins (largest first):", "", "| by | bin | gap (m) | 95 % interval |", "|---|---|---|---|"]
        lines += [f"| {x['by']} | {x['bin']} | {x['gap_m']:+.3f} | {_fmt(x['ci_low'])} … {_fmt(x['ci_high'])} |"
                  for x in d["where"][:20]]
        lines.append("")
    lines += ["![gap by field radius and map](gap_where.png)", "", "![gap by depth, defocus, frame, texture](gap_by.png)", "",
              "## 2. Which effect", ""]
    code = d.get("verdict")
    if code:
        lines += [f"**Verdict: {code.replace('_', ' ')}.** {d['verdict_text']}", ""]
    u = d.get("unexplained_share")
    if u:
        lines += [f"Unexplained part of the gap: {_share_txt(u['shown'], u['ci_low'], u['ci_high'])}"
                  + (f" ({u['note']})" if u.get("note") else "") + ".", ""]
    notes: list[str] = []
    if d["ranked_effects"]:
        lines += ["| rank | effect | fitted settings | closer to the capture (95 %) | images alone (95 %) | "
                  "lighting (95 %) | share of gap (95 %) | explains the gap |", "|---|---|---|---|---|---|---|---|"]
        for i, e in enumerate(d["ranked_effects"], 1):
            img, bri = e.get("image_closeness_ci"), e.get("brightness_closeness_ci")
            img_txt = f"{e['image_closeness']:.2f} ({img[0]:.2f} … {img[1]:.2f})" if img else "—"
            bri_txt = f"{e['brightness_closeness']:.2f} ({bri[0]:.2f} … {bri[1]:.2f})" if bri else "—"
            lines.append(f"| {i} | **{e['effect']}** | {_params(e['params'])} | {e['closeness']:.2f} "
                         f"({e['closeness_ci'][0]:.2f} … {e['closeness_ci'][1]:.2f}) | {img_txt} | {bri_txt} | "
                         f"{_share_cell(e, notes)} | {'yes' if e.get('explains_gap') else 'no'} |")
        names = [f"**{e['effect']}**" for e in d["ranked_effects"]]
        lines += ["", f"Named: {names[0]}." if len(names) == 1 else
                  f"Named, in the order found: {', then '.join(names)}."]
        for e in d["ranked_effects"]:
            if e.get("alternatives"):
                lines.append(f"In round {e['round']}, {', '.join(e['alternatives'])} brought the images about as close "
                             f"as {e['effect']}: these captures cannot tell them apart.")
        if d.get("causes") is not None:
            lines.append("Effects that explain part of the gap: "
                         + (", ".join(f"**{c}**" for c in d["causes"]) or "none") + "; the others are in the "
                         "captures' images but close no significant part of the gap.")
    elif d["gap_significant"]:
        lines.append("No registered effect brings the twin significantly closer to the captures: the cause is "
                     "something the simulator does not model yet.")
    elif d.get("image_effects"):
        lines.append("Nothing to blame: the gap is not significant. The captures do show effects the simulator "
                     "lacks, which do not (yet) cost this model depth accuracy:")
        lines += ["", "| effect | fitted settings | images closer to the capture (95 %) |", "|---|---|---|"]
        lines += [f"| {e['effect']} | {_params(e['params'])} | {e['closeness']:.2f} ({e['closeness_ci'][0]:.2f} … "
                  f"{e['closeness_ci'][1]:.2f}) |" for e in d["image_effects"]]
    else:
        lines.append("Nothing to blame: the gap is not significant, and no registered effect brings the twins' "
                     "images significantly closer to the captures.")
    lines += ["", "All effects tried (first round), best setting each:", "",
              "| effect | settings | closer (95 %) | share of gap (95 %) |", "|---|---|---|---|"]
    for e in d["effects_evaluated"]:
        if e["round"] == 1:
            clo = "—" if e.get("closeness") is None else \
                f"{e['closeness']:.2f} ({e['closeness_ci'][0]:.2f} … {e['closeness_ci'][1]:.2f})"
            where = " (1/N resolution)".replace("N", str(d.get("search_factor", "?"))) if e.get("screened_out") and \
                e.get("closeness") is not None else ""
            lines.append(f"| {e['effect']} | {_params(e['params']) if e['params'] is not None else 'none fitted'} | "
                         f"{clo}{where} | {_share_cell(e, notes)} |")
    for e in d.get("effects_skipped", []):
        lines.append(f"| {e['effect']} | not tried: {e['reason']} | | |")
    if notes:
        lines += [""] + [f"[{i}] {n}" for i, n in enumerate(notes, 1)]
    lines += ["", "![effects](effects.png)", ""] + focus_section(d) + ["## 3. How far it shrinks", ""]
    s = d.get("shrink")
    if s:
        lines += ["| | gap (m) | MAE on captures (m) |", "|---|---|---|",
                  f"| before (model's own simulator) | {s['gap_before_m']:+.3f} | {s['real_mae_before_m']:.3f} |",
                  f"| predicted (twin with {', '.join(s['effects'])}) | {s['gap_predicted_m']:+.3f} | — |"]
        if s.get("gap_after_m") is not None:
            lines.append(f"| realised (retrained with them: `{s['retrain_command']}`) | {s['gap_after_m']:+.3f} | "
                         f"{s['real_mae_after_m']:.3f} |")
        else:
            lines.append(f"| realised | run `{s['retrain_command']}` then `aat-diagnose` with the new model (or pass --retrain-steps) | |")
    else:
        lines.append("Nothing to retrain for.")
    lines += ["", "Method: docs/diagnosis.md. Recording: `aat-view diagnosis.rrd`.", ""]
    return "\n".join(lines)


def focus_section(d: dict) -> list[str]:
    """The report's focus-metadata section: the error family the images support, its settings with intervals,
    the families weighed, and the corrected focus distances (with the drop-in capture.json files)."""
    f = d.get("focus")
    if not f:
        return []
    lines = ["## Focus metadata", ""]
    status = ("named, and it explains the gap" if f["explains_gap"] else "named" if f["named"] else
              "not named (the fit did not measure an error that closes a significant part of the gap, nor did "
              "the twin with it come significantly closer to the captures)")
    if f["family"] == "none":
        lines.append("The images support no focus-metadata error: the reported focus distances fit best as they are.")
    else:
        ci = "; ".join(f"{k} {v[0]:.4g} … {v[1]:.4g}" for k, v in f.get("params_ci", {}).items())
        lines.append(f"The images support a **{f['family']}** error of the reported focus "
                     f"({_params({k: v for k, v in f['params'].items() if k in ('bias_d', 'scale', 'map_d')})}"
                     f"{'; 95 % interval ' + ci if ci else ''}); `focus_metadata` was {status}.")
    lines += ["", "| family | parameters | score (−2 log evidence) | chosen in bootstrap replicates |", "|---|---|---|---|"]
    for fam in f["families"]:
        lines.append(f"| {fam['family']} | {fam['k']} | {fam['score']:.1f} | {f['support'].get(fam['family'], 0):.0%} |")
    if f["family"] != "none":
        if f.get("corrected_recommended"):
            lines += ["", "Corrected focus distances (m, 95 % interval, the per-frame estimates' systematic error "
                      "included); drop-in `capture.json` files are in `corrected_focus/<capture>/` (copy one into "
                      "its capture folder to use it with `aat-infer`):", ""]
        else:
            lines += ["", f"The fit's corrected focus distances, **{f.get('corrected_note') or 'not recommended'}** "
                      "(m, 95 % interval, the per-frame estimates' systematic error included):", ""]
        lines += ["| capture | reported (m) | corrected (m) |", "|---|---|---|"]
        undetermined = 0
        for c in f["corrected_focus"]:
            rep = ", ".join(f"{x:.3f}" for x in c["reported_m"])
            und = c.get("undetermined") or [False] * len(c["corrected_m"])
            undetermined += sum(und)
            cor = ", ".join(f"{x:.3f} ({lo:.3f} … {hi:.3f}){' **undetermined**' if u else ''}"
                            for x, (lo, hi), u in zip(c["corrected_m"], c.get("total_ci_m", c["ci_m"]), und))
            lines.append(f"| {c['capture']} | {rep} | {cor} |")
        if undetermined:
            lines += ["", f"{undetermined} frame(s) **undetermined**: the images do not fix their focus to "
                      "0.02 D (one standard error, systematic part included); the frame shows little in focus, so "
                      "its estimate reads a misfit of the twin's level as focus. Their value is the family's "
                      "point, not a corrected distance: trust only its interval (docs/diagnosis.md, \"Focus "
                      "errors\")."]
    return lines + [""]


def write_focus_corrections(out: Path, d: dict) -> list[Path]:
    """corrected_focus/<capture>/capture.json (the capture folder's sidecar format, docs/contracts.md) for every
    capture, only when the diagnosis recommends the corrected focus (`focus.corrected_recommended`,
    `verdict.correction_advice`: focus metadata named and its fit's evidence measured an error); the user's folders
    are never touched. Not written, rather than written marked: a sidecar is a drop-in, and `aat-infer` reads its
    distances, not its note."""
    f = d.get("focus")
    if not f or f["family"] == "none" or not f.get("corrected_recommended"):
        return []
    written = []
    for c in f["corrected_focus"]:
        if not c["files"]:
            continue
        path = out / "corrected_focus" / c["capture"] / "capture.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"frames": [{"file": n, "focus_m": round(float(m), 5)}
                                               for n, m in zip(c["files"], c["corrected_m"])],
                                    "note": f"focus corrected by aat-diagnose ({f['family']} error of the reported "
                                            "focus fitted on the images; docs/diagnosis.md)"}, indent=1))
        written.append(path)
    return written


def _share_txt(v, lo, hi) -> str:
    return "—" if v is None else f"{v:.2f} ({_fmt(lo, 2)} … {_fmt(hi, 2)})"


def _share_cell(e: dict, notes: list[str]) -> str:
    """A share as shown (clipped or withheld, `verdict.share_view`) with a numbered note when it was changed."""
    shown = e.get("share_shown", e.get("share_of_gap"))
    note = e.get("share_note")
    if e.get("share_of_gap") is None:
        if note and e.get("screened_out"):
            if note not in notes:
                notes.append(note)
            return f"— [{notes.index(note) + 1}]"
        return "—"
    txt = "withheld" if shown is None else (f"{shown:.2f} ({_fmt(e['ci_low'], 2)} … {_fmt(e['ci_high'], 2)})"
                                            if shown == e["share_of_gap"] else f"{shown:.2f}")
    if note:
        if note not in notes:
            notes.append(note)
        txt += f" [{notes.index(note) + 1}]"
    return txt


def _params(p: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in p.items()) or "defaults"


def figures(d: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    br = d["gap"]["breakdown"]

    def bars(ax, name, rot=0):
        rows = br[name]["bins"]
        x = np.arange(len(rows))
        m = np.array([r["gap_m"] if r["gap_m"] is not None else np.nan for r in rows])
        lo = np.array([r["ci_low"] if r["ci_low"] is not None else np.nan for r in rows])
        hi = np.array([r["ci_high"] if r["ci_high"] is not None else np.nan for r in rows])
        col = ["tab:red" if r["significant"] else "tab:gray" for r in rows]
        ax.bar(x, m, color=col)
        ax.errorbar(x, m, yerr=[m - lo, hi - m], fmt="none", ecolor="k", capsize=2)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xticks(x, [r["bin"] for r in rows], rotation=rot, fontsize=7)
        ax.set_title(f"gap by {name} ({br[name]['unit']})", fontsize=8)
        ax.set_ylabel("gap (m)")

    fig, axs = plt.subplots(1, 2, figsize=(10, 3.6))
    bars(axs[0], "field_radius")
    rows = br["field_map"]["bins"]
    r_, c_ = (int(rows[-1]["bin"][1:].split("c")[0]) + 1, int(rows[-1]["bin"].split("c")[1]) + 1)
    grid = np.array([r["gap_m"] if r["gap_m"] is not None else np.nan for r in rows]).reshape(r_, c_)
    lim = np.nanmax(np.abs(grid)) if np.isfinite(grid).any() else 1
    im = axs[1].imshow(grid, cmap="RdBu_r", vmin=-lim, vmax=lim)
    for k, r in enumerate(rows):
        if r["significant"]:
            axs[1].text(k % c_, k // c_, "*", ha="center", va="center")
    axs[1].set_title("gap map (m; * significant)", fontsize=8)
    fig.colorbar(im, ax=axs[1])
    fig.tight_layout()
    fig.savefig(out / "gap_where.png", dpi=110)
    plt.close(fig)

    fig, axs = plt.subplots(1, 4, figsize=(16, 3.4))
    for ax, name in zip(axs, ("depth", "defocus", "frame", "texture")):
        bars(ax, name, rot=30)
    fig.tight_layout()
    fig.savefig(out / "gap_by.png", dpi=110)
    plt.close(fig)

    ev = [e for e in d["effects_evaluated"] if e["round"] == 1 and not e.get("screened_out")]
    fig, ax = plt.subplots(figsize=(7, 3.2))
    if ev:
        x = np.arange(len(ev))
        m = np.array([e["closeness"] for e in ev])
        ax.bar(x - 0.2, m, 0.4, label="closer to the capture")
        ax.errorbar(x - 0.2, m, yerr=[m - [e["closeness_ci"][0] for e in ev], [e["closeness_ci"][1] for e in ev] - m],
                    fmt="none", ecolor="k", capsize=2)
        if ev[0]["share_of_gap"] is not None:  # no significant gap: no shares
            # shares as people should read them (verdict.share_view): clipped to 0..1, withheld (x) when the
            # effect's images moved away; intervals clipped to 0..1 as well
            shown = np.array([np.nan if e.get("share_shown", e["share_of_gap"]) is None
                              else e.get("share_shown", e["share_of_gap"]) for e in ev], float)
            lo = np.clip([e["ci_low"] for e in ev], 0, 1)
            hi = np.clip([e["ci_high"] for e in ev], 0, 1)
            ok = np.isfinite(shown)
            ax.bar(x[ok] + 0.2, shown[ok], 0.4, label="share of the gap (0..1)")
            ax.errorbar(x[ok] + 0.2, shown[ok], yerr=[np.maximum(shown[ok] - lo[ok], 0), np.maximum(hi[ok] - shown[ok], 0)],
                        fmt="none", ecolor="k", capsize=2)
            ax.plot(x[~ok] + 0.2, np.zeros((~ok).sum()), "kx", label="share withheld (images moved away)")
        ax.set_xticks(x, [e["effect"] for e in ev], rotation=20, fontsize=8)
        ax.axhline(0, color="k", lw=0.5)
        ax.legend(fontsize=8)
    ax.set_title("each effect added to the twin alone (95 % intervals)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "effects.png", dpi=110)
    plt.close(fig)


def recording(path: Path, items: list[dict]) -> None:
    """items: per capture {name, gt_m, pred_real_m, pred_twin_m, gap_m, twin_best_m (optional)} (H, W) arrays."""
    import rerun as rr

    rec = rr.RecordingStream(application_id="aat-diagnose", recording_id="diagnosis")
    rec.save(str(path))
    for it in items:
        base = f"captures/{it['name']}"
        for key in ("gt_m", "pred_real_m", "pred_twin_m", "pred_twin_best_m"):
            if it.get(key) is not None:
                a = np.where(np.isfinite(it[key]), it[key], 0).astype(np.float32)
                rec.log(f"{base}/{key}", rr.DepthImage(a, meter=1.0), static=True)
        gap = np.nan_to_num(it["gap_m"]).astype(np.float32)
        lim = max(float(np.abs(gap).max()), 1e-6)
        t = np.clip(gap / lim, -1, 1)
        rgb = np.stack([np.clip(1 + np.minimum(t, 0), 0, 1), 1 - np.abs(t), np.clip(1 - np.maximum(t, 0), 0, 1)], -1)
        rec.log(f"{base}/gap", rr.Image((rgb * 255).astype(np.uint8)), static=True)
        rec.log(f"{base}/gap_m", rr.Image(gap, color_model="L"), static=True)
    rec.flush()
    rec.disconnect()
