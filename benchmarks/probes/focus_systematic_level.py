"""Each frame's systematic allowance from the level misfit the capture itself shows (issue 32, scene 2038), judged
on stored fits before any estimator change: `focusfit.frame_systematic` with `from_level` (never below the
capture's `level_misfit`, log units, times the frame's own `level_sensitivity`) and two other forms (`VARIANTS`)
against the code before (SYSTEMATIC_D scaled by the frame's sensitivity over the median frame's alone).

Every benchmark set of a scene is a copy of the same images with other reported focus distances, so each row's
level sensitivity and level misfit are measured on its scene's untouched copy's sweep (cached by
`focus_scene_coverage`, the first round's re-anchored sweep made robust by `focusrobust.prepare`) at the row's own
per-frame estimates; both allowances are computed that way, so the comparison is like for like, and the row's
bootstrap spread is kept. Each row is then rescored as `bench_diagnose_focus.rescored` does (error scale, family
choice, corrected focus's standard errors, undetermined frames).

    python -m benchmarks.probes.focus_systematic_level results/diagnose_focus_fresh2_fitonly_v2.jsonl \
        results/diagnose_focus_fresh3_fitonly.jsonl [--out results/focus_systematic_level.md]
"""

from __future__ import annotations

import argparse
import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

from benchmarks import bench_diagnose_focus as bench
from benchmarks.probes import focus_scene_coverage as fsc

# the allowances compared (diopters per frame, at most MAX_ERROR_D), m the capture's `level_misfit` (log units), k
# the frame's `level_sensitivity`: the code before issue 32's scene-2038 change (`frame_systematic(from_level=False)`:
# SYSTEMATIC_D times max(1, |k| over the median frame's |k|)); max(SYSTEMATIC_D, m |k|), the form declared first and
# rejected on these rows; SYSTEMATIC_D and m |k| in quadrature (rejected: it misses a misfit in one frame the other
# frames do not show, `focusfit.frame_systematic`); the larger of the median-scaled allowance and m |k|
# (`frame_systematic(from_level=True)`, the code now)
VARIANTS = {"median": "SYSTEMATIC_D scaled against the median frame (the code before)",
            "level_max": "max(SYSTEMATIC_D, level misfit x |k|) (declared first)",
            "level_quadrature": "SYSTEMATIC_D and level misfit x |k| in quadrature",
            "median_or_level": "max(the median-scaled allowance, level misfit x |k|) (`frame_systematic`, the code now)"}


def prepared_none(capture: str, cache: Path):
    """The scene's untouched copy's prepared sweep (None when its sweep is not cached)."""
    from aat_deploy.diagnose import focusrobust as fr

    if not (cache / f"{capture}_none.npz").exists():
        return None
    sweep, *_ = fsc.sweep_of(f"{capture}:none", cache, 1)
    return fr.prepare(sweep)[0]


def variants(rows: list[dict], cache: Path) -> tuple[dict, dict]:
    """{variant: rescored rows} for 'code' (the code's allowance) and 'level' (from the level misfit), on the
    untouched copies' sweeps; and per scene the level misfit and sensitivities of the untouched copy."""
    from aat_deploy.diagnose import focusfit as ff

    out: dict = {v: [] for v in VARIANTS}
    info: dict = {}
    preps: dict = {}
    for r in rows:
        cap = r["capture"]
        if cap not in preps:
            preps[cap] = prepared_none(cap, cache)
        prep = preps[cap]
        fams = {x["family"]: x for x in r.get("families") or []}
        if prep is None or "per_frame" not in fams or not r.get("frame_systematic_d"):
            continue
        d = np.asarray(fams["per_frame"]["true_d"], np.float64)
        if r["kind"] == "none":
            info[cap] = (float(ff.level_misfit(prep, d)[0]), ff.level_sensitivity(prep, d)[0])
        median = ff.frame_systematic(prep, d, from_level=False)
        lev = ff.level_misfit(prep, d)[:, None] * np.abs(ff.level_sensitivity(prep, d))
        for name in VARIANTS:
            sys_d = np.minimum({"median": median, "level_max": np.maximum(ff.SYSTEMATIC_D, lev),
                                "level_quadrature": np.hypot(ff.SYSTEMATIC_D, lev),
                                "median_or_level": ff.frame_systematic(prep, d, from_level=True)}[name],
                               ff.MAX_ERROR_D)
            new = bench.rescored({**r, "frame_systematic_d": np.round(sys_d, 5).tolist()}, f"{name} (stored fits)")
            if new is not None:
                out[name].append({**new, "frame_systematic_d": np.round(sys_d, 5).tolist()})
    return out, info


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+")
    ap.add_argument("--cache", default=str(fsc.SWEEP_CACHE))
    ap.add_argument("--out", help="also write the output here (markdown)")
    a = ap.parse_args()
    if a.out and Path(a.out).resolve() in {Path(f).resolve() for f in a.results}:
        raise SystemExit(f"{a.out}: is one of the results read; choose another --out")
    rows = list({(r["capture"], r["kind"]): r for f in a.results
                 for r in (json.loads(x) for x in Path(f).read_text().splitlines() if x.strip())}.values())
    res, info = variants(rows, Path(a.cache))
    buf = io.StringIO()
    with redirect_stdout(buf):
        print("\n### Each scene's untouched copy: level misfit (log) and level sensitivity k (D per log unit)\n")
        print("| scene | level misfit (log) | k, frames near to far | allowance scaled against the median frame (D) | "
              "the code now, never below level misfit x |k| (D) |")
        print("|---|---|---|---|---|")
        by = {v: {(r["capture"], r["kind"]): r for r in rs} for v, rs in res.items()}
        for cap, (m, k) in sorted(info.items()):
            c, lv = by["median"].get((cap, "none")), by["median_or_level"].get((cap, "none"))
            print(f"| {cap} | {m:.3f} | {' '.join(f'{x:+.2f}' for x in k)} | "
                  f"{' '.join(f'{x:.3f}' for x in np.asarray(c['frame_systematic_d'])[0]) if c else '-'} | "
                  f"{' '.join(f'{x:.3f}' for x in np.asarray(lv['frame_systematic_d'])[0]) if lv else '-'} |")
        for v, label in VARIANTS.items():
            print(f"\n### {label}, rescored from the stored fits\n")
            bench.table(res[v])
            for cap in sorted({r["capture"] for r in res[v]}):
                rs = [r for r in res[v] if r["capture"] == cap]
                err = [r for r in rs if r["kind"] != "none"]
                within = sum(r["corrected_max_err_d"] <= 0.02 and not r.get("frames_undetermined") for r in err)
                print(f"- {cap}: family right {sum(r['family_ok'] for r in rs)}/{len(rs)}, within 0.02 D "
                      f"{within}/{len(err)}")
        for v in VARIANTS:
            if v == "median":
                continue
            print(f"\n### Sets whose family or precision changed (median -> {v})\n")
            for key in sorted(set(by["median"]) & set(by[v])):
                x, y = by["median"][key], by[v][key]
                wx = x["corrected_max_err_d"] <= 0.02 and not x.get("frames_undetermined")
                wy = y["corrected_max_err_d"] <= 0.02 and not y.get("frames_undetermined")
                if x["family"] != y["family"] or (wx != wy and x["kind"] != "none"):
                    print(f"- {key[0]} {key[1]}: {x['family']} -> {y['family']} (true {x['family_true']}); max "
                          f"error {x['corrected_max_err_d']:.3f} -> {y['corrected_max_err_d']:.3f} D; undetermined "
                          f"{x.get('frames_undetermined')} -> {y.get('frames_undetermined')}")
    text = buf.getvalue()
    print(text, end="")
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(Path(a.out), "# Systematic allowance from the capture's level misfit (issue 32)\n\n"
                          f"`python -m benchmarks.probes.focus_systematic_level {' '.join(a.results)}`\n" + text)


if __name__ == "__main__":
    main()
