"""`aat-psf`: ray-traced PSFs, surrogates and their export.

    aat-psf show LENS --focus-m 1.5 --depths-m 1.2,1.5,2 --fields-deg 0,12,23.5 --png out.png [--model M.onnx]
    aat-psf fit --config configs/psf_rf50.json [--device auto|cpu|cuda[:N]|mps]
    aat-psf export --config configs/psf_rf50.json --out models/psf_rf50.onnx [--force]

Field angles are chief-ray angles along the image diagonal (towards the top-right corner); distances are metres
from the sensor plane.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from aat_deploy.cli.common import parser, run_or_hint, subparser
from aat_deploy.io.atomic import atomic_file
from aat_deploy.shipped import resolve, shipped_dir
from training.devices.options import add_device_argument


def _floats(text: str) -> list[float]:
    try:
        return [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def field_from_angle(lens, angle_deg: float) -> tuple[float, float]:
    """Normalised field (x = y, on the diagonal) whose object direction makes `angle_deg` with the axis."""
    from aat_deploy.optics.paraxial import paraxial_data

    r = math.tan(math.radians(angle_deg)) * paraxial_data(lens).efl_mm / lens.sensor.half_diagonal_mm
    return r, r


def _default_model(lens) -> Path | None:
    models = shipped_dir("models")
    for p in sorted(models.glob("psf_*.onnx")) if models else []:
        try:
            from aat_deploy.psf.surrogate import PSFSurrogate

            if PSFSurrogate(p).lens_hash == lens.prescription_hash():
                return p
        except Exception:
            continue
    return None


def cmd_show(a) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch

    from aat_deploy.lens.io import load_lens
    from aat_deploy.psf.kernel import KernelSpec
    from training.psf.raytrace import raytrace_psfs
    from training.psf.surrogates import GaussianPSF

    out = Path(a.png)
    if out.exists() and not a.force:
        raise SystemExit(f"aat-psf: error: {out}: exists (use --force to overwrite)")
    lens = load_lens(a.lens)
    model_path = None if a.model == "none" else Path(a.model) if a.model else _default_model(lens)
    surrogate = None
    if model_path is not None:
        from aat_deploy.psf.surrogate import PSFSurrogate

        surrogate = PSFSurrogate(model_path)
        if surrogate.lens_hash != lens.prescription_hash():
            raise SystemExit(f"aat-psf: error: {model_path}: made for another lens ({surrogate.meta['aat.lens_name']})")
    k = surrogate.kernel_size if surrogate else a.kernel_size
    spec = KernelSpec.for_lens(lens, k, float(surrogate.meta["aat.margin_px"]) if surrogate else 4.0)
    fields = [field_from_angle(lens, f) for f in a.fields_deg]
    fx, fy, dd = (np.array(v) for v in zip(*[(x, y, d) for (x, y) in fields for d in a.depths_m]))
    rt = raytrace_psfs(lens, fx, fy, dd, a.focus_m, spec, n_rays=a.rays)
    q = torch.tensor(np.stack([fx, fy, dd, np.full_like(dd, a.focus_m)], -1), dtype=torch.float32)
    gauss = GaussianPSF(lens, spec, 0.1, 1000.0)(q).numpy()
    rows = [("ray traced", rt.kernels.numpy())]
    if surrogate is not None:
        rows.append((f"surrogate ({model_path.name})", surrogate.query(fx, fy, dd, a.focus_m)[0]))
    rows.append(("thin-lens Gaussian", gauss))
    nr, nc = len(fields) * len(rows), len(a.depths_m)
    fig, axes = plt.subplots(nr, nc, figsize=(2.1 * nc + 1.2, 2.0 * nr), squeeze=False)
    for fi, ang in enumerate(a.fields_deg):
        for ri, (label, ker) in enumerate(rows):
            for di, d in enumerate(a.depths_m):
                i = fi * len(a.depths_m) + di
                ax = axes[fi * len(rows) + ri, di]
                vmax = float(rows[0][1][i].max()) or 1.0
                ax.imshow(ker[i], cmap="inferno", vmin=0, vmax=vmax, interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                if fi == 0 and ri == 0:
                    ax.set_title(f"depth {d:g} m", fontsize=9)
                ax.text(0.02, 0.98, f"cell {rt.scale[i]:.2g} px\nsum {ker[i].sum():.2f}", color="w", fontsize=6,
                        va="top", transform=ax.transAxes)
                if di == 0:
                    ax.set_ylabel(f"{ang:g}°\n{label}", fontsize=7)
    fig.suptitle(f"{lens.name}: PSFs focused at {a.focus_m:g} m ({k}x{k} cells, {a.rays} rays)", fontsize=9)
    fig.tight_layout()
    with atomic_file(out) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    print(f"wrote {out}" + ("" if surrogate else " (no surrogate for this lens: ray-traced and Gaussian only)"))
    return 0


def cmd_fit(a) -> int:
    import torch

    from training.devices.select import resolve_device
    from training.psf.experiment import PSFExperiment

    resolve_device(a.device)  # a missing GPU is refused before any tracing
    torch.set_num_threads(a.threads)
    exp = PSFExperiment.load(a.config)
    lens = exp.lens_obj()
    data = exp.datasets(lens, device=a.device)
    for name in a.only or list(exp.fits):
        _, cfg = exp.run_fit(name, lens, data, device=a.device)
        last = cfg.history[-1] if cfg.history else {}
        print(f"{name}: validation l1 {last.get('l1', float('nan')):.3e} after {last.get('minutes', 0):.1f} min; "
              f"checkpoint {exp.checkpoint(name, lens=lens)}")
    return 0


def cmd_export(a) -> int:
    import torch

    from training.psf.experiment import PSFExperiment
    from training.psf.export import PARITY_TOL, export_psf_onnx
    from training.psf.fit import make_model

    exp = PSFExperiment.load(a.config)
    lens = exp.lens_obj()
    ckpt = exp.checkpoint(a.fit, lens=lens)
    if not ckpt.exists():
        raise SystemExit(f"aat-psf: error: {ckpt}: no checkpoint; run `aat-psf fit --config {a.config}` first")
    model = make_model("rot" if a.fit.startswith("rot") else "paper_mlp", lens, exp.spec(lens), exp.near_m,
                       exp.far_m)
    st = torch.load(ckpt, map_location="cpu", weights_only=False)
    model.load_state_dict(st["model"])
    hist = st.get("history") or [{}]
    md = export_psf_onnx(model, lens, a.out, force=a.force, extra_metadata={
        "config": Path(exp.source).name,
        "fit": a.fit,
        "wavelength_nm": exp.wavelength_nm,
        "training_minutes": f"{st['elapsed'] / 60:.2f}",
        "validation_l1": f"{hist[-1].get('l1', float('nan')):.4e}",
        "command": f"aat-psf fit --config {a.config} && aat-psf export --config {a.config} --out {a.out}",
    })
    print(f"wrote {a.out} ({md['aat.model']}, lens {md['aat.lens_hash']}); onnxruntime matches torch "
          f"(float32 rounding, within {PARITY_TOL:g} relative)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = parser("aat-psf", "Ray-traced PSFs and PSF surrogates (needs the train extra).", quiet=False)
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="{show,fit,export}")
    p = subparser(sub, "show", "grid of ray-traced, surrogate and Gaussian PSFs")
    p.add_argument("lens", metavar="LENS", help="lens file (.json, .zmx, .txt)")
    p.add_argument("--focus-m", type=float, required=True, help="focus distance, m from the sensor")
    p.add_argument("--depths-m", type=_floats, required=True, help="object distances, m from the sensor (comma-separated)")
    p.add_argument("--fields-deg", type=_floats, required=True, help="field angles in degrees (comma-separated)")
    p.add_argument("--png", required=True, help="the PNG to write")
    p.add_argument("--model", default=None,
                   help="ONNX surrogate (default: models/psf_*.onnx made for this lens; 'none' = no surrogate)")
    p.add_argument("--rays", type=int, default=8192, help="rays per PSF (default 8192)")
    p.add_argument("--kernel-size", type=int, default=11, help="window size when no surrogate is shown")
    p.add_argument("--force", action="store_true", help="overwrite an existing PNG")
    p.set_defaults(func=cmd_show)
    p = subparser(sub, "fit", "trace the datasets (cached) and fit the surrogates of a config (resumable)")
    p.add_argument("--config", required=True, help="PSF experiment config (configs/psf_*.json)")
    p.add_argument("--only", nargs="*", help="fit names to run (default: all in the config)")
    p.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    add_device_argument(p)
    p.set_defaults(func=cmd_fit)
    p = subparser(sub, "export", "export a fitted surrogate to ONNX with metadata")
    p.add_argument("--config", required=True, help="the config the surrogate was fitted with")
    p.add_argument("--fit", default="rot", help="which fit of the config (default: rot)")
    p.add_argument("--out", required=True, help="the .onnx to write")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.set_defaults(func=cmd_export)
    return ap


def main(argv: list[str] | None = None) -> int:
    return run_or_hint("aat-psf", _main, argv)


def _main(argv: list[str] | None) -> int:
    a = build_parser().parse_args(argv)
    if getattr(a, "lens", None):
        a.lens = str(resolve(a.lens, "lenses"))  # a path, or a shipped lens's name
    try:
        return a.func(a)
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"aat-psf: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
