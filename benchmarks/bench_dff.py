"""The paper's Table 2 on our models: AAT vs thin-lens training, tested on stacks rendered through the real lens.

    OMP_WAIT_POLICY=PASSIVE python benchmarks/bench_dff.py [--n 12] [--figures DIR] [MODEL.onnx ...]

Test sets (never seen in training; all rendered with the RF50's PSFs, the `aat` simulator; fixed schedule of
8 focus distances even in diopters over 0.5-10 m, the training schedule, never derived from the depth):
- procedural: `--n` held-out procedural scenes (seed 777777) at the full 640 x 960 sensor;
- middlebury: the real Middlebury 2014 Motorcycle scene (2.1-5.0 m) scaled to cover the sensor.
Models are the shipped ONNX files, run with onnxruntime exactly as `aat-infer` runs them. Metrics per image,
then averaged (aat_deploy.metrics); depth in metres from the sensor. Also MAE by field zone (normalised radius
< 0.33 centre, > 0.66 outer) and a figure of the mean error over the field per model.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ["dff_aifnet_thin", "dff_aifnet_aat", "dff_dfvnet_thin", "dff_dfvnet_aat"]
COLS = ("mae", "mse", "rmse", "abs_rel", "sq_rel", "delta1", "delta2", "delta3")


def test_sets(n: int):
    import torch

    from aat_deploy.normalise import PERCENTILE
    from training.cli.render import fit_to_sensor
    from training.data.rgbd import fill_depth, load_middlebury_motorcycle
    from training.data.stacks import FocalStackDataset, StackDataConfig

    hs, ws = 640, 960
    cfg = StackDataConfig(simulator="aat", height=hs, width=ws, stack_size=8, n_items=n, seed=777777,
                          margin_px=0, cell_px=64)
    ds = FocalStackDataset(cfg)
    procedural = []
    for i in range(n):
        it = ds.render(i)
        procedural.append((it["stack"], it["focus_m"], it["depth_m"]))
        print(f"procedural {i + 1}/{n}", flush=True)
    rgb, gt = load_middlebury_motorcycle()
    rgb, gt = fit_to_sensor(rgb, gt, (hs, ws))
    st = ds.sim.render_stack(torch.from_numpy(rgb.transpose(2, 0, 1).copy()), torch.from_numpy(fill_depth(gt)),
                             ds.schedule.distances())
    fr = st.frames.numpy()
    p = np.float32(np.percentile(fr, PERCENTILE))
    middlebury = [(np.clip(fr / p, 0, 1).astype(np.float32), st.focus_m.astype(np.float32), gt)]
    return {"procedural": procedural, "middlebury": middlebury}


def zone_masks(h: int, w: int):
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot((xx + 0.5 - w / 2) / (w / 2), (yy + 0.5 - h / 2) / (h / 2)) / np.sqrt(2)
    return {"centre": r < 0.33, "outer": r > 0.66}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("models", nargs="*")
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--figures", default=str(ROOT / "benchmarks/figures"))
    args = ap.parse_args()
    from aat_deploy.metrics import MetricAccumulator
    from aat_deploy.model import DfFModel

    paths = [Path(m) for m in args.models] or [ROOT / "models" / f"{n}.onnx" for n in DEFAULT]
    sets = test_sets(args.n)
    results, maps = {}, {}
    for path in paths:
        model = DfFModel(path, threads=2)
        label = f"{'AAT' if model.meta.get('aat.simulator') == 'aat' else 'Baseline'} {path.stem.split('_')[1]}"
        for sname, items in sets.items():
            acc = MetricAccumulator()
            zones = {"centre": [], "outer": []}
            for stack, focus, gt in items:
                out = model.infer(stack, focus)
                acc.add(out.depth_m, gt)
                for z, m in zone_masks(*gt.shape).items():
                    v = m & (gt > 0)
                    zones[z].append(float(np.abs(out.depth_m[v] - gt[v]).mean()))
            res = acc.result()
            res.update({f"mae_{z}": float(np.mean(v)) for z, v in zones.items()})
            results[(label, sname)] = res
            if sname == "procedural":
                maps[label] = acc.error_map()
        print(f"done {path.name}", flush=True)

    for sname in sets:
        print(f"\n### Test set: {sname} ({len(sets[sname])} stack{'s' if len(sets[sname]) > 1 else ''}, RF50 PSFs)\n")
        print("| model | MAE | MSE | RMSE | AbsRel | SqRel | δ1 | δ2 | δ3 | MAE centre | MAE outer |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for (label, s), r in results.items():
            if s == sname:
                print(f"| {label} | " + " | ".join(f"{r[c]:.4f}" for c in COLS)
                      + f" | {r['mae_centre']:.4f} | {r['mae_outer']:.4f} |")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(maps), figsize=(4.2 * len(maps), 3.4))
    vmax = np.nanpercentile(np.stack(list(maps.values())), 98)
    for ax, (label, m) in zip(np.atleast_1d(axes), maps.items()):
        im = ax.imshow(m, cmap="magma", vmin=0, vmax=vmax)
        ax.set_title(f"{label}: mean |error| (m)", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes, shrink=0.8)
    out = Path(args.figures)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "dff_error_over_field.png", dpi=110)
    print(f"wrote {out / 'dff_error_over_field.png'}")


if __name__ == "__main__":
    main()
