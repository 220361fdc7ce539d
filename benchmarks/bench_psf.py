"""PSF surrogates on the paper's evaluation grid, and ray-traced PSF throughput.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_psf [--config configs/psf_rf50.json] [--figures DIR]

Evaluation: 20 focus distances x 40 depths (both even in diopters over 0.3..20 m from the sensor) x 8 x 10 field
positions, ground truth ray-traced with 4096 rays. Error definition: for every PSF, kernels in the common
representation (energy per cell, k x k, scale-adaptive cells, centred on the chief ray); l1 = mean over PSFs and
cells of |pred - truth|, l2 = mean of (pred - truth)^2. Build time = ray tracing of the method's data plus its
fitting (wall clock, 2 cores). Prints markdown tables; writes figures (accuracy per training minute).
Datasets and fits are cached (cache/), so a rerun only evaluates.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks import FIGURES

ROOT = Path(__file__).resolve().parents[1]


def throughput(lens, n_psf: int = 4096, n_rays: int = 1024) -> list[tuple[str, float]]:
    from training.psf.raytrace import raytrace_psfs

    rng = np.random.default_rng(0)
    x, y = rng.uniform(-1, 1, n_psf), rng.uniform(-1, 1, n_psf)
    d, f = 1 / rng.uniform(0.05, 3.3, n_psf), 1 / rng.uniform(0.05, 3.3, n_psf)
    rows = []
    for threads, compiled in ((1, False), (2, False), (1, True), (2, True)):
        torch.set_num_threads(threads)
        raytrace_psfs(lens, x[:256], y[:256], d[:256], f[:256], n_rays=n_rays, compiled=compiled, chunk=256)
        t0 = time.perf_counter()
        raytrace_psfs(lens, x, y, d, f, n_rays=n_rays, compiled=compiled, chunk=256)
        rows.append((f"{threads} thread{'s' if threads > 1 else ''}, {'compiled' if compiled else 'eager'}",
                     n_psf / (time.perf_counter() - t0)))
    torch.set_num_threads(2)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "configs/psf_rf50.json"))
    ap.add_argument("--figures", default=str(FIGURES))
    ap.add_argument("--cache", default=None)
    ap.add_argument("--skip-throughput", action="store_true")
    a = ap.parse_args()
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    torch.set_num_threads(2)

    from training.psf.dataset import eval_grid
    from training.psf.experiment import PSFExperiment
    from training.psf.fit import psf_errors
    from training.psf.raytrace import raytrace_psfs
    from training.psf.surrogates import GaussianPSF, GridPSF, n_params

    exp = PSFExperiment.load(a.config)
    lens = exp.lens_obj()
    spec = exp.spec(lens)
    cache = Path(a.cache) if a.cache else None

    tp = [] if a.skip_throughput else throughput(lens)

    # Ground truth on the paper's grid, and an independent default-ray-count trace (the noise floor).
    e = exp.eval
    g = eval_grid(lens, e["n_focus"], e["n_depth"], e["rows"], e["cols"], exp.near_m, exp.far_m)
    q = torch.from_numpy(np.stack([g["x"], g["y"], g["depth_m"], g["focus_m"]], -1)).float()
    t0 = time.perf_counter()
    gt = raytrace_psfs(lens, g["x"], g["y"], g["depth_m"], g["focus_m"], spec, n_rays=e["n_rays"],
                       wavelength_nm=exp.wavelength_nm, seed=e["seed"], compiled=True, chunk=256)
    t_gt = time.perf_counter() - t0
    t0 = time.perf_counter()
    rt2048 = raytrace_psfs(lens, g["x"], g["y"], g["depth_m"], g["focus_m"], spec, n_rays=2048,
                           wavelength_nm=exp.wavelength_nm, seed=e["seed"] + 1, compiled=True, chunk=256)
    t_rt = time.perf_counter() - t0
    truth = gt.kernels

    results = []  # (name, pred, build_s, params, query_s_per_100k, notes)

    def add(name, model, build_s, notes=""):
        with torch.no_grad():
            t0 = time.perf_counter()
            pred = torch.cat([model(q[i:i + 8192]) for i in range(0, q.shape[0], 8192)])
            dt = time.perf_counter() - t0
        results.append((name, pred, build_s, n_params(model), dt / q.shape[0] * 1e5, notes))

    add("Thin-lens Gaussian", GaussianPSF(lens, spec, exp.near_m, exp.far_m), 0.0, "CoC from EFL, F-number")
    results.append(("Ray tracing, 2048 rays", rt2048.kernels, t_rt, 0, t_rt / q.shape[0] * 1e5,
                    "independent trace: noise floor of the truth"))

    gr = exp.grid
    axes = GridPSF.axes(exp.near_m, exp.far_m, gr["nf"], gr["nd"], gr["ny"], gr["nx"])
    F, D, Y, X = np.meshgrid(*axes, indexing="ij")
    t0 = time.perf_counter()
    tab = raytrace_psfs(lens, X.ravel(), Y.ravel(), D.ravel(), F.ravel(), spec, n_rays=gr["n_rays"],
                        wavelength_nm=exp.wavelength_nm, seed=11, compiled=True, chunk=256).kernels
    t_grid = time.perf_counter() - t0
    grid = GridPSF(lens, spec, exp.near_m, exp.far_m, tab.view(*F.shape, spec.size, spec.size))
    add(f"Grid + multilinear ({gr['nf']}x{gr['nd']}x{gr['ny']}x{gr['nx']})", grid, t_grid,
        f"{F.size} traced PSFs")

    data = exp.datasets(lens, cache)
    histories = {}
    labels = {"rot": "RotPSF (ours)", "paper_mlp": "Paper MLP (MSE, lr 1e-4)",
              "paper_mlp_l1": "Paper MLP (our L1 loss, lr 3e-4)"}
    for name in exp.fits:
        model, cfg = exp.run_fit(name, lens, data, cache)
        trace_s = data["axis" if name.startswith("rot") else "field"]["_seconds"]
        histories[labels.get(name, name)] = cfg.history
        add(labels.get(name, name), model, trace_s + exp.fits[name]["minutes"] * 60,
            f"{exp.fits[name]['minutes']:g} min fit + {trace_s / 60:.1f} min tracing")

    l1_gauss = psf_errors(results[0][1], truth)[0]
    energy = gt.energy_in_window
    print(f"## PSF surrogates: {lens.name}\n")
    print(f"Config `{Path(a.config).relative_to(ROOT) if Path(a.config).is_relative_to(ROOT) else a.config}`; "
          f"evaluation grid {e['n_focus']} focus x {e['n_depth']} depths x {e['rows']}x{e['cols']} fields = "
          f"{q.shape[0]} PSFs, truth traced with {e['n_rays']} rays in {t_gt:.0f} s; kernel {spec.size}x{spec.size}, "
          f"{exp.wavelength_nm} nm. Energy inside the window (of the arriving energy): min {energy.min():.3f}, "
          f"1st percentile {np.percentile(energy, 1):.3f}, mean {energy.mean():.4f}.\n")
    print("| method | l1 (mean per cell) | l2 (mean per cell) | l1 vs Gaussian | build time (min) | parameters | "
          "query time per 100k PSFs (s) | notes |")
    print("|---|---|---|---|---|---|---|---|")
    for name, pred, build_s, params, qt, notes in results:
        l1, l2 = psf_errors(pred, truth)
        print(f"| {name} | {l1:.3e} | {l2:.3e} | {l1 / l1_gauss:.3f}x | {build_s / 60:.1f} | {params:,} | "
              f"{qt:.2f} | {notes} |")
    # Error by field zone (normalised image radius), the part aberrations change.
    from aat_deploy.optics.field import field_radius

    r = field_radius(lens, g["x"], g["y"])
    zones = [("centre r<0.33", r < 0.33), ("middle", (r >= 0.33) & (r < 0.66)), ("outer r>=0.66", r >= 0.66)]
    print("\n| method | " + " | ".join(f"l1 {z}" for z, _ in zones) + " |")
    print("|---|" + "---|" * len(zones))
    for name, pred, *_ in results:
        cells = [f"{psf_errors(pred[torch.from_numpy(m)], truth[torch.from_numpy(m)])[0]:.3e}" if m.any() else "—"
                 for _, m in zones]
        print(f"| {name} | " + " | ".join(cells) + " |")
    if tp:
        print(f"\n### Ray-traced PSF throughput (1024 rays, {spec.size}x{spec.size}, RF50, random field/depth/focus)\n")
        print("| configuration | PSFs / s | vs deeplens-core 2.5.6 (330-380 PSF/s, 1 core) |")
        print("|---|---|---|")
        for label, v in tp:
            print(f"| {label} | {v:.0f} | {v / 355:.1f}x |")

    figs = Path(a.figures)
    figs.mkdir(parents=True, exist_ok=True)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for label, hist in histories.items():
        if hist:
            ax.plot([h["minutes"] for h in hist], [h["l1"] for h in hist], label=label)
    ax.axhline(l1_gauss, color="k", ls="--", lw=1, label="thin-lens Gaussian")
    ax.axhline(psf_errors(rt2048.kernels, truth)[0], color="gray", ls=":", lw=1, label="ray tracing 2048 rays")
    ax.set_yscale("log")
    ax.set_xlabel("training time (min, 2 CPU cores)")
    ax.set_ylabel("l1 per cell on the validation set")
    ax.set_title(f"PSF surrogates: accuracy per training minute\n{lens.name}", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    out = figs / f"psf_accuracy_{Path(a.config).stem}.png"
    fig.savefig(out, dpi=110)
    print(f"\nwrote {out.relative_to(ROOT) if out.is_relative_to(ROOT) else out}")



if __name__ == "__main__":
    main()
