"""The any-camera model (`models/dfv_aat.onnx`, issue 35) on lenses it never saw, against the lens-specific nets and
the classical method given the same focus map.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_anycam [--lenses paper50 ef50 z35 rf50] [--protocol fixed paper]
        [--n 24] [--model models/dfv_aat.onnx] [--tile N] [--tables] [--out results]

Test stacks (training/train/testsets.py, cached in cache/heldout): whole-sensor renders through each lens with its
PSF surrogate, procedural scenes textured with the held-out photographs (n per lens and protocol) plus the real RGB-D
scenes Middlebury 2014 Motorcycle and NYU Depth V2 0045 (none of them in any training data); the camera-like
"fixed" schedule and the paper's protocol (focus distances spread over each image's own depth range). Held-out
lenses: the paper's 50 mm, the Canon EF50 and the Nikon Z35 (DiffOptics' scaled version, a phone-sized 2.3 mm lens
at 1.66 um pixels, so tested over 0.2-3 m); the RF50 is inside the training family (its PSFs are in 15 % of the
training data).

Methods, all as the runtime runs them:
- `dfv_aat, lens map`: the any-camera model given the lens's best-focus map (`aat-infer --model dfv_aat --lens`);
- `dfv_aat, thin-lens map`: the same model told only the nominal focus distances (the aberration-aware gain);
- `Classical, lens map` / `Classical, thin lens`: `--method focus` with the same map / without;
- the lens-specific AAT DFVNet where one exists (paper lens: `paper50_dfvnet_aat`; RF50: the main model
  `rf50_dfvnet_aat_field`).
Metrics per image then the mean over images (aat_deploy.metrics, metres from the sensor), MAE centre / outer field;
95 % bootstrap intervals over scenes; paired ratios with a paired bootstrap (bench_table2). The two real scenes are
reported one by one (two scenes: no interval over scenes). --tables adds, on the paper lens (fixed protocol, n/2
scenes): MAE by stack size (3, 5, 8, 12, 16 frames) and by schedule (even in diopters, jittered, linear in depth,
phone-like: 5 frames over the near range 0.5-2 m). Results as JSON in --out, tables printed for BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from aat_deploy.eval.score import scene_scores as score  # one scoring for every DfF table
from aat_deploy.eval.stats import fmt_interval as fmt
from aat_deploy.eval.stats import paired_ratio, summarise
from aat_deploy.io.atomic import write_text_atomic
from benchmarks import RESULTS

ROOT = Path(__file__).resolve().parents[1]

LENSES = {
    "paper50": {"lens": "lenses/paper_50mm_f2.8.json", "psf": "models/psf_paper50.onnx", "stack_size": 10,
                "range_m": (0.5, 10.0), "specific": {"AAT DFVNet (lens-specific)": "models/paper50_dfvnet_aat.onnx"}},
    "ef50": {"lens": "lenses/canon_ef50mm_f1.8.json", "psf": "models/psf_ef50.onnx", "stack_size": 8,
             "range_m": (0.5, 10.0), "specific": {}},
    "z35": {"lens": "lenses/nikon_z35_f1.8_diffoptics.json", "psf": "models/psf_z35.onnx", "stack_size": 8,
            "range_m": (0.2, 3.0), "specific": {}},
    "rf50": {"lens": "lenses/canon_rf50mm_f1.8.json", "psf": "models/psf_rf50.onnx", "stack_size": 8,
             "range_m": (0.5, 10.0), "specific": {"main model (RF50 field DFVNet)": "models/rf50_dfvnet_aat_field.onnx"}},
}
DFV_MAP, DFV_THIN, CL_MAP, CL_THIN = ("dfv_aat, lens map", "dfv_aat, thin-lens map", "Classical, lens map",
                                      "Classical, thin lens")
STACK_SIZES = (3, 5, 8, 12, 16)


def methods(model_path: Path, lens_key: str, threads: int, tile: int | None = None) -> dict:
    """{label: fn(item) -> (depth_m, aif)} for one lens."""
    from aat_deploy.anycam.maps import FocusMapping
    from aat_deploy.anycam.model import FocusMapModel, mapping_from_args
    from aat_deploy.focus import classical_depth
    from aat_deploy.focus.bestfocus import for_lens
    from aat_deploy.infer.model import DfFModel

    spec = LENSES[lens_key]
    lens = ROOT / spec["lens"]
    fmap, _ = for_lens(lens, compute=False)
    out = {}
    if model_path.is_file():
        with_map = FocusMapModel(model_path, threads=threads, mapping=mapping_from_args(lens=lens))
        thin = FocusMapModel(model_path, threads=threads, mapping=FocusMapping("thin_lens"))

        def dfv(model):
            def fn(it):  # the camera's optics from the lens file either way; only the focus map differs
                r = model.bound(with_map.mapping_optics(it.stack.shape[-1]), it.focus_m).infer(
                    it.stack, it.focus_m, tile=tile, overlap=(tile or 0) // 4 or 32)
                return r.depth_m, r.aif
            return fn

        out[DFV_MAP] = dfv(with_map)
        out[DFV_THIN] = dfv(thin)
    for label, p in spec["specific"].items():
        if (ROOT / p).is_file():
            net = DfFModel(ROOT / p, threads=threads)
            out[label] = (lambda n: lambda it: (lambda r: (r.depth_m, r.aif))(n.infer(it.stack, it.focus_m)))(net)

    def classical(bf):
        def fn(it):
            r = classical_depth(it.stack, it.focus_m, bf)
            return r.depth_m, r.aif
        return fn

    out[CL_MAP] = classical(fmap)
    out[CL_THIN] = classical(None)
    return out


def test_spec(lens_key: str, protocol: str, n: int, stack_size: int | None = None, jitter_d: float = 0.0,
              range_m: tuple[float, float] | None = None, real: bool = True):
    from training.train.testsets import TestSetSpec

    s = LENSES[lens_key]
    near, far = range_m or s["range_m"]
    return TestSetSpec(s["lens"], s["psf"], stack_size or s["stack_size"], protocol=protocol, n_procedural=n,
                       focus_near_m=near, focus_far_m=far, scene_near_m=s["range_m"][0], scene_far_m=s["range_m"][1],
                       middlebury=real, nyu=real, jitter_d=jitter_d)


def run_set(items: dict, fns: dict) -> dict:
    """{label: {scene set: [per-image metrics]}} and the mean |error| maps of the procedural set."""
    res, maps = {}, {}
    for label, fn in fns.items():
        t0 = time.perf_counter()
        res[label] = {}
        for kind, its in items.items():
            per = []
            errs = []
            for it in its:
                d, a = fn(it)
                per.append(score(d, it.depth_m, a, it.aif))
                if kind == "procedural":
                    errs.append(np.where(it.depth_m > 0, np.abs(d - it.depth_m), np.nan))
            res[label][kind] = per
            if errs:
                maps[label] = np.nanmean(np.stack(errs), 0)
        print(f"  {label}: {time.perf_counter() - t0:.0f} s", flush=True)
    return res, maps


def ratio_rows(res: dict, pairs: list[tuple[str, str, str]]) -> list[dict]:
    rows = []
    for a, b, target in pairs:
        if a in res and b in res:
            pa, pb = res[a]["procedural"], res[b]["procedural"]
            row = {"a": a, "b": b, "target": target, "procedural": paired_ratio(pa, pb),
                   "procedural_outer": paired_ratio(pa, pb, "mae_outer")}
            for real in ("middlebury", "nyu"):
                if real in res[a]:
                    row[real] = res[a][real][0]["mae"] / res[b][real][0]["mae"]
            rows.append(row)
    return rows


def print_lens(lens_key: str, protocol: str, res: dict, ratios: list[dict], n: int) -> None:
    print(f"\n#### {lens_key}, {protocol} protocol: {n} procedural stacks (95 % bootstrap over scenes), then the real "
          "RGB-D scenes\n")
    print("| method | MAE | AbsRel | δ1 | MAE centre | MAE outer | Middlebury MAE | NYU MAE |\n|---|---|---|---|---|---|---|---|")
    for label, r in res.items():
        s = summarise(r["procedural"])
        real = [f"{r[k][0]['mae']:.3f}" if k in r else "–" for k in ("middlebury", "nyu")]
        print(f"| {label} | {fmt(s['mae'], 3)} | {fmt(s['abs_rel'], 3)} | {fmt(s['delta1'], 3)} | "
              f"{fmt(s['mae_centre'], 3)} | {fmt(s['mae_outer'], 3)} | {real[0]} | {real[1]} |")
    if ratios:
        print("\n| ratio of MAE | target | procedural | outer field | Middlebury | NYU |\n|---|---|---|---|---|---|")
        for r in ratios:
            real = [f"{r[k]:.2f}" if k in r else "–" for k in ("middlebury", "nyu")]
            print(f"| {r['a']} / {r['b']} | {r['target']} | {fmt(r['procedural'], 2)} | "
                  f"{fmt(r['procedural_outer'], 2)} | {real[0]} | {real[1]} |")


def tables(model_path: Path, n: int, threads: int, cache: str, tile: int | None = None) -> dict:
    """Stack-size and schedule tables on the paper lens (fixed protocol)."""
    from training.train.testsets import load_test_set

    fns = {k: v for k, v in methods(model_path, "paper50", threads, tile).items() if k in (DFV_MAP, CL_MAP)}
    out = {"stack_size": {}, "schedule": {}}
    for s in STACK_SIZES:
        items = load_test_set(test_spec("paper50", "fixed", n, stack_size=s, real=False), cache)
        out["stack_size"][s], _ = run_set(items, fns)
    schedules = {"even in diopters (10 frames)": test_spec("paper50", "fixed", n, real=False),
                 "jittered (10 frames, up to 0.45 of a spacing)": test_spec("paper50", "fixed", n, jitter_d=0.45,
                                                                            real=False),
                 "linear in depth over each scene (the paper's)": test_spec("paper50", "paper", n, real=False),
                 "phone-like (5 frames over 0.5-2 m)": test_spec("paper50", "fixed", n, stack_size=5,
                                                                 range_m=(0.5, 2.0), real=False)}
    for name, spec in schedules.items():
        out["schedule"][name], _ = run_set(load_test_set(spec, cache), fns)
    for what, rows in out.items():
        print(f"\n#### paper50, MAE by {what.replace('_', ' ')} ({n} procedural stacks, 95 % bootstrap)\n")
        print(f"| {what.replace('_', ' ')} | {DFV_MAP} | {CL_MAP} | ratio |\n|---|---|---|---|")
        for k, r in rows.items():
            cells = [fmt(summarise(r[lab]["procedural"])["mae"], 3) if lab in r else "–" for lab in (DFV_MAP, CL_MAP)]
            ratio = fmt(paired_ratio(r[DFV_MAP]["procedural"], r[CL_MAP]["procedural"]), 2) if DFV_MAP in r else "–"
            print(f"| {k} | {cells[0]} | {cells[1]} | {ratio} |")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lenses", nargs="+", default=list(LENSES), choices=list(LENSES))
    ap.add_argument("--protocol", nargs="+", default=["fixed", "paper"], choices=["fixed", "paper"])
    ap.add_argument("--n", type=int, default=24, help="procedural scenes per lens and protocol (default 24)")
    ap.add_argument("--model", type=Path, default=ROOT / "models" / "dfv_aat.onnx")
    ap.add_argument("--tables", action="store_true", help="also the stack-size and schedule tables (paper lens)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--tile", type=int, default=None,
                    help="run dfv_aat in tiles of this side (px; 0 = whole frames); default: the model's aat.tile_px")
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"))
    ap.add_argument("--out", type=Path, default=RESULTS)
    a = ap.parse_args(argv)
    from training.train.testsets import load_test_set

    if not a.model.is_file():
        print(f"{a.model}: no such model (train it: scripts/train_dfv_aat.sh); only the baselines run", flush=True)
    results = {"model": str(a.model), "n": a.n, "lenses": {}}
    for lens_key in a.lenses:
        spec = LENSES[lens_key]
        if not (ROOT / spec["psf"]).is_file():
            print(f"{lens_key}: {spec['psf']} missing (configs/psf_*.json: aat-psf fit, export, stamp); skipped")
            continue
        fns = methods(a.model, lens_key, a.threads, a.tile)
        for protocol in a.protocol:
            print(f"{lens_key}, {protocol} protocol", flush=True)
            items = load_test_set(test_spec(lens_key, protocol, a.n), a.cache)
            res, maps = run_set(items, fns)
            pairs = [(DFV_MAP, CL_MAP, "<= 0.7"), (DFV_MAP, DFV_THIN, "<= 0.75 (paper lens)")]
            pairs += [(DFV_MAP, lab, "<= 1.1" if lens_key == "paper50" else "<= 1.0") for lab in spec["specific"]]
            ratios = ratio_rows(res, pairs)
            print_lens(lens_key, protocol, res, ratios, a.n)
            results["lenses"].setdefault(lens_key, {})[protocol] = {
                "summary": {lab: {k: summarise(v) if k == "procedural" else v for k, v in r.items()}
                            for lab, r in res.items()}, "ratios": ratios}
            if maps:
                from benchmarks.bench_table2 import field_figures

                field_figures(maps, a.out / "figures" / f"anycam_{lens_key}_{protocol}.png",
                              f"{lens_key}, {protocol} protocol: MAE against field radius")
    if a.tables:
        results["tables"] = tables(a.model, max(8, a.n // 2), a.threads, a.cache, a.tile)
    a.out.mkdir(parents=True, exist_ok=True)
    path = a.out / "anycam.json"
    write_text_atomic(path, json.dumps(results, indent=1, default=float))
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
