"""The paper's Table 2 (and its Table 3, the all-in-focus image), with intervals: AAT vs thin-lens training on one
lens, tested on held-out stacks rendered through that lens (training/train/testsets.py).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_table2 --lens paper50 --protocol paper fixed [--n 32]
    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_table2 --lens rf50 --protocol fixed
    ... [--models A.onnx B.onnx ...] [--no-classical] [--tile 192] [--out results]
    ... --effects noise,vignetting,raw_pipeline     (capture effects on the test stacks; the nets never saw them)

Models default to `models/<lens>_{dfvnet,aifnet}_{aat,thin}[_field].onnx` that exist. They run with onnxruntime
exactly as `aat-infer` runs them (aat_deploy.infer.model.DfFModel; a field-aware model gets each pixel's sensor position).
Beside them, the simplest honest baseline on the same stacks: the runtime's classical focus-measure method
(aat_deploy.focus, when present), with the nominal (thin-lens) focus mapping and with the lens's best-focus map.

Metrics per image, then the mean over images (aat_deploy.metrics), depth in metres from the sensor, over valid
ground truth; MAE in the centre (field radius < 0.33) and the outer field (> 0.66), the zones of
`aat_deploy.eval.stats` (circular radius over the half-diagonal, 1 = corner; per scene `scene_scores`); all-in-focus PSNR
and SSIM (normalised units, data range 1). 95 % intervals: bootstrap over scenes (procedural set; Middlebury is
one scene, no interval). "ratio" rows: mean MAE of the AAT model / mean MAE of its thin-lens twin, with a paired
bootstrap interval over scenes; the same for each AAT model against the aberration-aware classical method, and for
a field-aware or AiF-loss model against the same net without; beside each, the paired difference of AiF PSNR
(dB, the paper's Table 3 comparison). Results
as JSON in --out, tables printed (markdown) for BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

from aat_deploy.eval.score import scene_scores as score  # noqa: F401 (re-exported, below)
from aat_deploy.eval.stats import (
    N_BOOT,  # noqa: F401
    field_radius,
    paired_diff,
    paired_ratio,
    summarise,
)
from aat_deploy.eval.stats import fmt_interval as fmt
from aat_deploy.io.atomic import write_text_atomic
from benchmarks import FIGURES, RESULTS
from training.train.testsets import LENSES

ROOT = Path(__file__).resolve().parents[1]


# score, summarise, paired_ratio, paired_diff, fmt, N_BOOT and LENSES stay importable from here (as the scripts of work in
# progress import them) until benchmarks/ becomes a package; new code imports aat_deploy.eval.stats / .score and training.train.testsets.

KEYS = ("mae", "mse", "rmse", "abs_rel", "sq_rel", "delta1", "delta2", "delta3", "mae_centre", "mae_outer",
        "psnr", "ssim")
CLASSICAL_AA = "Classical focus, aberration-aware"
AIF_LOSS = " + AiF loss"  # label suffix of the nets fine-tuned with an all-in-focus term (configs/table2/*_aif.json)
ABLATIONS = (" + field", AIF_LOSS)


def field_figures(maps: dict[str, np.ndarray], path: Path, title: str) -> None:
    """Mean |error| over the sensor per model (one panel each) and MAE against field radius: the paper's Fig. 9."""
    from training.train.heldout import ModelResult, plot_error_over_field, plot_error_vs_radius

    results = []
    for lab, emap in maps.items():
        r = field_radius(*emap.shape)
        edges = np.linspace(0, 1, 11)
        prof = np.array([np.nanmean(emap[(r >= lo) & (r < hi if hi < 1 else r <= hi)]) for lo, hi in
                         zip(edges[:-1], edges[1:])])
        results.append(ModelResult(lab, {}, emap, edges, prof))
    plot_error_over_field(results, path.with_name(path.stem + "_field.png"))
    plot_error_vs_radius(results, path.with_name(path.stem + "_radius.png"), title)


def run_model(path: Path, items, threads: int, tile: int | None = None) -> tuple[list[dict], np.ndarray, dict]:
    from aat_deploy.infer.model import DfFModel

    model = DfFModel(path, threads=threads)
    per, err = [], []
    for it in items:
        out = model.infer(it.stack, it.focus_m, tile=tile)
        per.append(score(out.depth_m, it.depth_m, out.aif, it.aif))
        valid = it.depth_m > 0
        err.append(np.where(valid, np.abs(out.depth_m - it.depth_m), np.nan))
    return per, np.nanmean(np.stack(err), 0), dict(model.meta)


def classical_methods(lens_path: str):
    """[(label, fn(item) -> (depth, aif))] of the runtime's classical focus method (aat_deploy.focus, default
    settings): the thin-lens mapping, and the lens's calibrated best-focus map when
    `<lens folder>/best_focus/<lens stem>.json` exists (`aat-lens focus-map LENS`)."""
    from aat_deploy.focus import classical_depth
    from aat_deploy.focus.bestfocus import load_json, map_path_for_lens

    def run(fmap):
        def fn(it):
            r = classical_depth(it.stack, it.focus_m, fmap)
            return r.depth_m, r.aif
        return fn

    out = [("Classical focus, thin-lens mapping", run(None))]
    mp = map_path_for_lens(ROOT / lens_path)
    if mp.is_file():
        out.append((CLASSICAL_AA, run(load_json(mp))))
    return out


def label_of(meta: dict, path: Path) -> str:
    from training.nets.registry import NETS

    spec = NETS.get(str(meta.get("aat.net")))
    net = spec.label if spec else path.stem
    sim = "AAT" if meta.get("aat.simulator") == "aat" else "Baseline"
    return (f"{sim} {net}" + (" + field" if int(meta.get("aat.field_channels") or 0) else "")
            + (AIF_LOSS if str(meta.get("aat.config_name", "")).endswith("_aif") else ""))


def unique_label(label: str, path: Path, taken) -> str:
    """`label`, or when another model of the run has it (the first RF50 DFVNets beside the current ones) the label
    with the model's family, its file stem less the simulator ("AAT DFVNet (dff_dfvnet)"), so that no row replaces
    another and an AAT net still finds its thin-lens twin ("Baseline DFVNet (dff_dfvnet)")."""
    if label not in taken:
        return label
    family = re.sub(r"_(aat|thin)$", "", path.stem)
    out = f"{label} ({family})"
    return out if out not in taken else f"{label} ({path.stem})"


def table(rows: list[tuple[str, dict]]) -> str:
    head = ("| model | MAE | MSE | RMSE | AbsRel | SqRel | δ1 | δ2 | δ3 | MAE centre | MAE outer | AiF PSNR | AiF SSIM |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for label, s in rows:
        cells = [fmt(s[k], 2 if k == "psnr" else 4) for k in KEYS]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lens", choices=sorted(LENSES), required=True)
    ap.add_argument("--protocol", nargs="+", choices=("fixed", "paper"), default=["fixed"])
    ap.add_argument("--n", type=int, default=32, help="held-out procedural scenes")
    ap.add_argument("--models", nargs="*", help="ONNX models (default: models/<lens>_*.onnx)")
    ap.add_argument("--no-classical", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--tile", type=int, default=0,
                    help="run the nets in tiles of this side (px, as `aat-infer --tile`); 0 = whole image")
    ap.add_argument("--effects", default="",
                    help="capture effects rendered on top of the test stacks (comma-separated, as aat-render "
                         "--effects), e.g. noise,vignetting,raw_pipeline; results get a _fx-<names> suffix")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--figures", default=str(FIGURES))
    a = ap.parse_args(argv)
    from training.train.testsets import TestSetSpec, load_test_set

    spec_l = LENSES[a.lens]
    paths = [Path(m) for m in a.models] if a.models else sorted((ROOT / "models").glob(f"{a.lens}_*.onnx"))
    if not paths and a.no_classical:
        raise SystemExit(f"no models for {a.lens}: pass --models")
    effects = tuple(e.strip() for e in a.effects.split(",") if e.strip())
    try:  # a misspelt effect: one line before anything is rendered
        from aat_deploy.render import effects as fx
        fx.parse(list(effects))
    except ValueError as e:
        raise SystemExit(f"bench_table2.py: --effects: {e}")
    suffix = (f"_tile{a.tile}" if a.tile else "") + ("_fx-" + "-".join(e.split(":")[0] for e in effects)
                                                     if effects else "")
    for protocol in a.protocol:
        spec = TestSetSpec(spec_l["lens"], spec_l["psf"], spec_l["stack_size"], protocol=protocol, n_procedural=a.n,
                           effects=effects)
        sets = load_test_set(spec, str(ROOT / "cache/heldout"))
        result = {"lens": a.lens, "protocol": protocol, "spec": spec.__dict__, "tile_px": a.tile,
                  "effects": list(effects), "sets": {}}
        for sname, items in sets.items():
            rows, per_model, maps = [], {}, {}
            for path in paths:
                t0 = time.time()
                per, err_map, meta = run_model(path, items, a.threads, a.tile or None)
                lab = unique_label(label_of(meta, path), path, per_model)
                per_model[lab] = per
                maps[lab] = err_map
                rows.append((lab, summarise(per, KEYS)))
                print(f"{sname} {protocol}: {lab} ({path.name}) {time.time() - t0:.0f} s", file=sys.stderr)
            if not a.no_classical:
                for lab, fn in classical_methods(spec_l["lens"]):
                    per, errs = [], []
                    for it in items:
                        depth, aif = fn(it)
                        per.append(score(depth, it.depth_m, aif, it.aif))
                        errs.append(np.where(it.depth_m > 0, np.abs(depth - it.depth_m), np.nan))
                    maps[lab] = np.nanmean(np.stack(errs), 0)
                    per_model[lab] = per
                    rows.append((lab, summarise(per, KEYS)))
            ratios = {}
            for lab in per_model:
                if lab.startswith("AAT "):
                    # its thin-lens twin, the classical baseline on the same stacks (the "<= 0.7 x" target) and,
                    # for a field-aware net, the same net without field channels (the ablation)
                    twin = "Baseline " + lab[4:].replace(" + field", "")
                    refs = [twin, CLASSICAL_AA] + [lab[:-len(x)] for x in ABLATIONS if lab.endswith(x)]
                    for ref in refs:
                        if ref in per_model:
                            ratios[f"{lab} / {ref}"] = {k: paired_ratio(per_model[lab], per_model[ref], k)
                                                        for k in ("mae", "mae_centre", "mae_outer")}
                            ratios[f"{lab} / {ref}"]["psnr_diff_db"] = paired_diff(per_model[lab], per_model[ref])
            if a.figures and maps:
                field_figures(maps, Path(a.figures) / f"table2_{a.lens}_{protocol}{suffix}_{sname}.png",
                              f"{a.lens}, {protocol} protocol, {sname}: MAE vs field radius")
            result["sets"][sname] = {"n_scenes": len(items), "rows": dict(rows), "ratios": ratios,
                                     "per_scene": per_model}
            print(f"\n### {a.lens}, protocol {protocol}{', effects ' + ','.join(effects) if effects else ''}"
                  f"{' (focus from each scene’s ground-truth range)' if protocol == 'paper' else ''}: "
                  f"{sname}, {len(items)} stack{'s' if len(items) > 1 else ''}\n")
            print(table(rows))
            if ratios:
                print("\n| ratio (paired over scenes) | MAE | MAE centre | MAE outer | AiF PSNR difference (dB) |"
                      "\n|---|---|---|---|---|")
                for k, r in ratios.items():
                    print(f"| {k} | {fmt(r['mae'], 3)} | {fmt(r['mae_centre'], 3)} | {fmt(r['mae_outer'], 3)} | "
                          f"{fmt(r['psnr_diff_db'], 2)} |")
        out = Path(a.out) / f"table2_{a.lens}_{protocol}{suffix}.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out, json.dumps(result, indent=1, default=float))
        print(f"\nwrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
