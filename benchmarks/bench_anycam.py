"""The any-camera model (`models/dfv_aat.onnx`, issue 35) on lenses it never saw, against the lens-specific nets and
the classical method given the same focus map.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_anycam [--lenses paper50 ef50 z35 rf50] [--protocol fixed paper]
        [--n 24] [--model models/dfv_aat.onnx] [--tile N] [--tables [stack_size schedule]] [--label NAME]
        [--out results] [--force]

Test stacks (training/train/testsets.py, cached in cache/heldout): whole-sensor renders through each lens with its
PSF surrogate, procedural scenes textured with the held-out photographs (n per lens and protocol) plus the real RGB-D
scenes Middlebury 2014 Motorcycle and NYU Depth V2 0045 (none of them in any training data); the camera-like
"fixed" schedule and the paper's protocol (focus distances spread over each image's own depth range). Held-out
lenses: the paper's 50 mm, the Canon EF50 and the Nikon Z35 (DiffOptics' scaled version, a phone-sized 1.57 mm lens
at 1.66 um pixels, so tested over 0.2-3 m; misread as a 2.29 mm lens until 2026-11-26, lenses/README.md); the RF50 is
inside the training family (its PSFs are in 15 % of the training data).

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
phone-like: 5 frames over the near range 0.5-2 m); `--lenses` with no lens runs only the tables. Results as JSON in
--out (`anycam_<label>.json`, maps `figures/anycam_<label>_<lens>_<protocol>_*.png`; without --label `anycam.json`),
tables printed for BENCHMARKS.md. The JSON is written after every lens and protocol and every table row, with each
scene's scores: a rerun of the same command (same model file, n, tile and overlap) skips what it holds and reprints
its tables, so a killed run resumes and short commands (one lens, one protocol, one table) add to one file; a file of
another model or setting is refused unless --force, which starts it afresh.
"""

from __future__ import annotations

import argparse
import hashlib
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


TABLES = ("stack_size", "schedule")


def table_specs(what: str, n: int) -> dict:
    """{row name: TestSetSpec} of one table on the paper lens (fixed protocol unless the row says)."""
    if what == "stack_size":
        return {str(s): test_spec("paper50", "fixed", n, stack_size=s, real=False) for s in STACK_SIZES}
    return {"even in diopters (10 frames)": test_spec("paper50", "fixed", n, real=False),
            "jittered (10 frames, up to 0.45 of a spacing)": test_spec("paper50", "fixed", n, jitter_d=0.45,
                                                                       real=False),
            "linear in depth over each scene (the paper's)": test_spec("paper50", "paper", n, real=False),
            "phone-like (5 frames over 0.5-2 m)": test_spec("paper50", "fixed", n, stack_size=5,
                                                            range_m=(0.5, 2.0), real=False)}


def tables(model_path: Path, n: int, threads: int, cache: str, tile: int | None = None,
           which: tuple[str, ...] = TABLES, done: dict | None = None, save=None) -> dict:
    """Stack-size and schedule tables on the paper lens: {table: {row: {label: {"procedural": [per-scene scores]}}}}.
    Rows already in `done` (same layout) are kept, not rerun; save(out) is called after every new row."""
    from training.train.testsets import load_test_set

    out = {w: dict((done or {}).get(w, {})) for w in which}
    fns = None
    for what in which:
        for row, spec in table_specs(what, n).items():
            if row in out[what]:
                continue
            if fns is None:
                fns = {k: v for k, v in methods(model_path, "paper50", threads, tile).items() if k in (DFV_MAP, CL_MAP)}
            print(f"paper50, {what.replace('_', ' ')} {row}", flush=True)
            out[what][row], _ = run_set(load_test_set(spec, cache), fns)
            if save is not None:
                save(out)
    for what in which:
        print_table(what, out[what], n)
    return out


def print_table(what: str, rows: dict, n: int) -> None:
    name = what.replace("_", " ")
    print(f"\n#### paper50, MAE by {name} ({n} procedural stacks, 95 % bootstrap)\n")
    print(f"| {name} | {DFV_MAP} | {CL_MAP} | ratio |\n|---|---|---|---|")
    for k, r in rows.items():
        cells = [fmt(summarise(r[lab]["procedural"])["mae"], 3) if lab in r else "–" for lab in (DFV_MAP, CL_MAP)]
        ratio = fmt(paired_ratio(r[DFV_MAP]["procedural"], r[CL_MAP]["procedural"]), 2) if DFV_MAP in r else "–"
        print(f"| {k} | {cells[0]} | {cells[1]} | {ratio} |")


def model_id(path: Path) -> str:
    """sha256 (first 12 hex) of the model file, '' without one: a resumed results file must be of the same model."""
    return hashlib.sha256(path.read_bytes()).hexdigest()[:12] if path.is_file() else ""


def tile_overlap(tile: int | None) -> str:
    """How dfv_aat's tiles overlap (`methods`), for the results file's identity: a quarter of --tile, or the runtime's
    own share of the model's aat.tile_px (`aat_deploy.anycam.model.own_tiles`: an eighth since 2026-11-26, a quarter
    before; a results file of the earlier runtime has no overlap, so it is not added to)."""
    if tile == 0:
        return "whole frames"
    if tile:
        return f"{tile // 4} px"
    from aat_deploy.anycam.model import own_tiles

    return f"{own_tiles(1024)[1] / 1024:g} of aat.tile_px"


def previous(path: Path, ident: dict, force: bool) -> dict:
    """The results file to add to: its content when it was made with the same `ident` (model file, n, tile,
    overlap), a fresh one with --force or none there; else SystemExit with one line naming the file and what differs."""
    if force or not path.is_file():
        return {**ident, "lenses": {}}
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise SystemExit(f"{path}: not a results file of this benchmark ({e}); --force starts it afresh") from None
    diff = [f"{k} {old.get(k)!r} here, {v!r} now" for k, v in ident.items() if old.get(k) != v]
    if diff:
        raise SystemExit(f"{path}: made with another setting ({'; '.join(diff)}); use another --label or --out, "
                         "or --force to start it afresh")
    old.setdefault("lenses", {})
    return old


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lenses", nargs="*", default=list(LENSES), choices=list(LENSES),
                    help="held-out lenses (default all; none: only --tables)")
    ap.add_argument("--protocol", nargs="+", default=["fixed", "paper"], choices=["fixed", "paper"])
    ap.add_argument("--n", type=int, default=24, help="procedural scenes per lens and protocol (default 24)")
    ap.add_argument("--model", type=Path, default=ROOT / "models" / "dfv_aat.onnx")
    ap.add_argument("--tables", nargs="*", choices=TABLES, default=None,
                    help="also the stack-size and/or schedule tables (paper lens, max(8, n/2) scenes; alone: both)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--tile", type=int, default=None,
                    help="run dfv_aat in tiles of this side (px; 0 = whole frames); default: the model's aat.tile_px")
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"))
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--label", default="", help="name of the results: anycam_<label>.json and its figures")
    ap.add_argument("--force", action="store_true", help="start the results file afresh instead of adding to it")
    a = ap.parse_args(argv)
    from training.train.testsets import load_test_set

    if not a.model.is_file():
        print(f"{a.model}: no such model (train it: scripts/train_dfv_aat.sh); only the baselines run", flush=True)
    stem = f"anycam_{a.label}" if a.label else "anycam"
    path = a.out / f"{stem}.json"
    ident = {"model": str(a.model), "model_sha256": model_id(a.model), "n": a.n, "tile": a.tile,
             "overlap": tile_overlap(a.tile)}
    results = previous(path, ident, a.force)

    def save() -> None:
        a.out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps(results, indent=1, default=float))

    for lens_key in a.lenses:
        spec = LENSES[lens_key]
        if not (ROOT / spec["psf"]).is_file():
            print(f"{lens_key}: {spec['psf']} missing (configs/psf_*.json: aat-psf fit, export, stamp); skipped")
            continue
        fns = None
        for protocol in a.protocol:
            done = results["lenses"].get(lens_key, {}).get(protocol)
            if done is not None:  # resumed: print it again from the stored scores
                print_lens(lens_key, protocol, done["per_image"], done["ratios"], a.n)
                continue
            fns = fns or methods(a.model, lens_key, a.threads, a.tile)
            print(f"{lens_key}, {protocol} protocol", flush=True)
            items = load_test_set(test_spec(lens_key, protocol, a.n), a.cache)
            res, maps = run_set(items, fns)
            pairs = [(DFV_MAP, CL_MAP, "<= 0.7"), (DFV_MAP, DFV_THIN, "<= 0.75 (paper lens)")]
            pairs += [(DFV_MAP, lab, "<= 1.1" if lens_key == "paper50" else "<= 1.0") for lab in spec["specific"]]
            ratios = ratio_rows(res, pairs)
            print_lens(lens_key, protocol, res, ratios, a.n)
            results["lenses"].setdefault(lens_key, {})[protocol] = {
                "summary": {lab: {k: summarise(v) if k == "procedural" else v for k, v in r.items()}
                            for lab, r in res.items()}, "ratios": ratios, "per_image": res}
            if maps:
                from benchmarks.bench_table2 import field_figures

                field_figures(maps, a.out / "figures" / f"{stem}_{lens_key}_{protocol}.png",
                              f"{lens_key}, {protocol} protocol: MAE against field radius")
            save()
    if a.tables is not None:
        n_tab = max(8, a.n // 2)
        which = tuple(a.tables) or TABLES

        def save_tables(t: dict) -> None:
            results["tables"] = {**results.get("tables", {}), **t, "n": n_tab}
            save()

        results["tables"] = {**results.get("tables", {}), "n": n_tab}
        tables(a.model, n_tab, a.threads, a.cache, a.tile, which, results["tables"], save_tables)
    save()
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
