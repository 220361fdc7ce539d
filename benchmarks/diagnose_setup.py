"""Models for the diagnosis benchmark (`bench_diagnose.py`): the RF50 on a 288x192 working resolution, its PSF
surrogate, and small DFVNets trained with the AAT and the thin-lens simulators. Resumable:

    python -m benchmarks.diagnose_setup                  # full frame, 125 um pixels: ~25 min on 2 cores
    python -m benchmarks.diagnose_setup --variant crop4  # centre 9 x 6 mm crop, 31.25 um pixels: ~15 min

Variants (`VARIANTS`): `full` images the whole 36 x 24 mm frame with 125 um pixels, so that hundreds of twins
render in minutes; there the RF50's colour is sub-pixel (about 0.04 D of focus between red and blue, half a
pixel of blur), so `chromatic` is benchmarked on `crop4`, the frame's centre at 4x finer pixels (colour about 2 px
of blur), where field-dependent effects such as tilt are weak instead. Each goes to its own cache folder.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
W, H = 288, 192
STEPS = 800


@dataclasses.dataclass(frozen=True)
class Variant:
    folder: str  # under cache/
    sensor_mm: tuple[float, float]  # imaged part of the sensor, centred on the axis
    simulators: tuple[str, ...]  # base models to train


VARIANTS = {
    "full": Variant("bench_diagnose", (36.0, 24.0), ("aat", "thin_lens")),
    "crop4": Variant("bench_diagnose_crop4", (9.0, 6.0), ("aat",)),
    # the shipped models at their full 960 x 640 (models/): nothing to set up; bench_diagnose takes the files
    "shipped": Variant("bench_diagnose_shipped", (36.0, 24.0), ()),
}


def setup_dir(variant: str) -> Path:
    return ROOT / "cache" / VARIANTS[variant].folder


def run(cmd: list[str]) -> None:
    print("+", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT, env={**os.environ, "OMP_WAIT_POLICY": "PASSIVE"})


def main() -> None:
    import argparse

    from aat_deploy.lens.io import load_lens, save_lens

    ap = argparse.ArgumentParser(description="Models for the diagnosis benchmark (bench_diagnose.py).")
    ap.add_argument("--variant", choices=sorted(VARIANTS), default="full")
    var = VARIANTS[ap.parse_args().variant]
    if not var.simulators:
        print("nothing to set up: this variant uses the shipped models (bench_diagnose.py takes their files)")
        return
    OUT = ROOT / "cache" / var.folder
    OUT.mkdir(parents=True, exist_ok=True)
    lens_path = OUT / "rf50_288x192.json"
    if not lens_path.exists():
        lens = load_lens(ROOT / "lenses" / "canon_rf50mm_f1.8.json")
        sensor = dataclasses.replace(lens.sensor, width_mm=var.sensor_mm[0], height_mm=var.sensor_mm[1],
                                     width_px=W, height_px=H)
        save_lens(dataclasses.replace(lens, sensor=sensor), lens_path)
    psf_cfg = OUT / "psf_rf50_288.json"
    psf_cfg.write_text(json.dumps({
        "lens": str(lens_path), "near_m": 0.3, "far_m": 20.0, "kernel_size": 11, "margin_px": 4.0,
        "wavelength_nm": 589.0,
        "train_axis": {"n": 30000, "n_rays": 1024, "seed": 1},
        "train_field": {"n": 30000, "n_rays": 1024, "seed": 2},
        "val": {"n": 1024, "n_rays": 4096, "seed": 3},
        "eval": {"n_focus": 4, "n_depth": 8, "rows": 3, "cols": 4, "n_rays": 2048, "seed": 4},
        "grid": {"nf": 8, "nd": 8, "ny": 3, "nx": 4, "n_rays": 1024},
        "fits": {"rot": {"minutes": 4.0, "lr": 1e-3, "loss": "l1"}},
    }, indent=1))
    psf = OUT / "psf.onnx"
    if not psf.exists():
        run(["aat-psf", "fit", "--config", str(psf_cfg), "--only", "rot"])
        run(["aat-psf", "export", "--config", str(psf_cfg), "--out", str(psf)])
    base = json.loads((ROOT / "configs" / "dff_dfvnet_aat.json").read_text())
    for sim in var.simulators:
        name = f"diag_dfv_{'aat' if sim == 'aat' else 'thin'}"
        onnx = OUT / f"{name}.onnx"
        if onnx.exists():
            continue
        cfg = dict(base, name=name, simulator=sim, lens=str(lens_path), steps=STEPS, checkpoint_every=100,
                   val_every=0, comment="diagnosis benchmark base model (benchmarks/diagnose_setup.py)")
        for part, n, seed in (("data", 256, 0), ("val_data", 8, 100000)):
            cfg[part] = dict(base[part], n_items=n, seed=seed, psf=str(psf), cache_dir=str(OUT / "stacks"))
        cfg_path = OUT / f"{name}.json"
        cfg_path.write_text(json.dumps(cfg, indent=1))
        run(["aat-train", "--config", str(cfg_path), "--out", str(OUT / "runs" / name), "--resume", "--no-progress"])
        run([sys.executable, "-c", "import sys; from training.train.export import export_checkpoint; "
             "export_checkpoint(sys.argv[1], sys.argv[2])", str(OUT / "runs" / name / "model.pt"), str(onnx)])


if __name__ == "__main__":
    main()
