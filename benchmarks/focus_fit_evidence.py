"""Why per-frame focus estimation failed on the shipped sample, and what each fix does (issue 32; the numbers and
the figure in docs/diagnosis.md, "Why the focus fit failed on the sample").

    python -m benchmarks.focus_fit_evidence [CAPTURE] [--scale 1.1] [--figure docs/diagnosis_focus.png]

1. Brightness: every frame's mean as recorded (the DNG's mosaic, black level removed, over the white level) and
   as developed by LibRaw with its default `adjust_maximum_thr` (what the runtime did before) and as the runtime
   develops it now (against the file's white level).
2. Per-frame focus estimates (the `per_frame` family: every frame's focus free within +-0.4 D of its reported
   value) against the truth, on the capture and on a copy whose reported distances are `--scale` times the true
   ones (the issue's experiment), for the focus fit as it was and with each candidate cause removed:
   the old RAW development; the noise floor (per-region floors, `focusrobust.fit_floors`); the frames' exposure
   (`focusrobust.frame_gains_log`); region weights; the binning correction; textureless regions left out; a twin
   with the capture's own noise and vignetting. Each line also gives the family the fit then chooses and the
   largest error of its corrected focus.
3. The figure: the brightness, the per-frame errors of the main variants, and two regions' focus curves (a
   textured one and a textureless one) against the twin's with and without its floor.

The twins are the shipped main model's (`models/rf50_dfvnet_aat_field.onnx`), binned as the diagnosis's search
bins them (960 x 640 to 240 x 160); torch-free.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def developed_old(path: Path) -> np.ndarray:
    """(H, W, 3) linear RGB as the runtime developed a DNG before issue 32: LibRaw's default adjust_maximum_thr
    (0.75), which rescales a frame whose brightest pixel exceeds 0.75 of the white level to that pixel."""
    import rawpy

    with rawpy.imread(io.BytesIO(path.read_bytes())) as r:
        rgb = r.postprocess(use_camera_wb=True, gamma=(1, 1), no_auto_bright=True, output_bps=16,
                            output_color=rawpy.ColorSpace.sRGB)
    return rgb.astype(np.float32) / 65535.0


def recorded_mean(path: Path) -> tuple[float, float]:
    """(mean, max) of the DNG's mosaic, black level removed, over the white level."""
    import rawpy

    with rawpy.imread(io.BytesIO(path.read_bytes())) as r:
        raw = r.raw_image_visible.astype(np.float64)
        black, white = float(np.mean(r.black_level_per_channel)), float(r.white_level)
    x = (raw - black) / (white - black)
    return float(x.mean()), float(x.max())


def sweep_for(twins, cap, chain: list, factor: int, correction: str = "twin"):
    """The diagnosis's focus sweep of one capture with the twin's effects `chain`; its binning correction anchored
    at the twin's focus ("twin", `fitters.focus_sweep`), there and at the frames' estimated focus ("estimates",
    `anchors.reanchored_sweep`, what the diagnosis does), or none ("none")."""
    from aat_deploy.diagnose import anchors, fitters
    from aat_deploy.diagnose import focusrobust as fr
    from aat_deploy.render import effects as fx

    full = [fitters.fit_curves(twins.render(cap, cap.aif_linear, chain, seed=0), factor)] \
        if correction != "none" else None
    state = fitters.FitState(twins, [cap], [cap.aif_linear], chain, fx.make, factor, 0, 0, {}, full)
    if correction == "estimates":
        return anchors.reanchored_sweep(state, fitters.focus_sweep(state, correct=False),
                                        lambda d: np.asarray(fr.prepare(d)[1]["frame_focus_d"][-1]))[0]
    return fitters.focus_sweep(state)


def with_frames(data, frames: np.ndarray, factor: int):
    """The sweep with the capture's curves and brightness measured on other frames (S, 3, H, W) linear."""
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose.binned import bin_frames
    from aat_deploy.diagnose.compare import focus_curves, region_brightness
    from aat_deploy.infer.normalise import normalise_stack

    st = normalise_stack(bin_frames(frames, factor))
    return dataclasses.replace(data, capture=focus_curves(st, ff.FIT_GRID).mean(-1)[None],
                               capture_lum=region_brightness(st, ff.FIT_GRID)[None])


def estimate(data, truth_d: np.ndarray, cfg, old_fit: bool, weight=None) -> dict:
    """Per-frame estimates and the chosen family on `data`: the fit as it was (old_fit: no robust preparation) or
    `focusrobust.prepare` with cfg."""
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose import focusrobust as fr

    d = data if weight is None else dataclasses.replace(data, weight=weight)
    if not old_fit:
        d, _ = fr.prepare(d, cfg)
    fits = ff.fit_families(d)
    best = ff.select(fits)
    per = fits["per_frame"].true_d[0]
    rep = d.reported_d[0]
    bound = (np.abs(np.abs(per - rep) - ff.MAX_ERROR_D) < 0.002) & (np.abs(np.abs(truth_d - rep) - ff.MAX_ERROR_D) > 0.01)
    return {"err": per - truth_d, "family": best.name, "params": best.params,
            "corrected_max": float(np.abs(best.true_d[0] - truth_d).max()), "on_bound": int(bound.sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", nargs="?", default=str(ROOT / "captures" / "sample_rf50"))
    ap.add_argument("--scale", type=float, default=1.1, help="the copy's reported distance over the true one")
    ap.add_argument("--model", default=str(ROOT / "models" / "rf50_dfvnet_aat_field.onnx"))
    ap.add_argument("--figure", default=str(ROOT / "docs" / "diagnosis_focus.png"))
    ap.add_argument("--json", help="also write the numbers here")
    a = ap.parse_args()
    from tqdm import tqdm

    from aat_deploy.diagnose import focusrobust as fr
    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.render import effects as fx
    from benchmarks.bench_diagnose_focus import make_copy

    cap_dir = Path(a.capture)
    files = sorted(cap_dir.glob("frame_*.dng"))
    model = DfFModel(a.model, threads=2)
    lens, _ = find_lens(model, None)
    twins = make_renderer(model, lens, find_surrogate(lens, None), torch_free=True)
    factor = max(1, min(8, model.sensor_px[0] // 240))  # the diagnosis's search binning (DiagnoseConfig.search_px)

    # 1. brightness
    rec = [recorded_mean(p) for p in files]
    old = np.stack([developed_old(p).transpose(2, 0, 1) for p in files])
    cap = load_capture_data(cap_dir, model, use_exiftool=False)
    if old.shape != cap.frames.shape:
        raise SystemExit(f"{cap_dir}: frames are not at the model's sensor size; this script reads them as they are")
    bright = {"recorded": [m for m, _ in rec], "recorded_max": [x for _, x in rec],
              "developed_before": old.mean((1, 2, 3)).tolist(), "developed_now": cap.frames.mean((1, 2, 3)).tolist()}
    print("## Brightness per frame (mean of the linear frame; 1 = white level)\n")
    print("| frame | focus m | recorded (mosaic) | brightest recorded pixel | developed before (LibRaw default) | "
          "developed now | before / now |")
    print("|---|---|---|---|---|---|---|")
    for i, f in enumerate(cap.focus_m):
        print(f"| {i} | {f:.3f} | {bright['recorded'][i]:.4f} | {bright['recorded_max'][i]:.3f} | "
              f"{bright['developed_before'][i]:.4f} | {bright['developed_now'][i]:.4f} | "
              f"{bright['developed_before'][i] / bright['developed_now'][i]:.3f} |")

    # 2. focus estimates: the capture (reported = true) and the scaled copy
    truth_d = 1.0 / cap.focus_m
    none = fr.RobustConfig(floors=False, gains=False, weights=False)
    variants = [  # (label, development, chain, binning correction, old fit?, robust config, texture-only weights)
        ("as it was: old development, old fit", "old", [], "twin", True, none, False),
        ("old fit, development fixed", "now", [], "twin", True, none, False),
        ("old fit, development fixed, textureless half of the regions left out", "now", [], "twin", True, none,
         True),
        ("old fit, development fixed, twin with the capture's noise and vignetting", "now",
         ["vignetting", "noise"], "twin", True, none, False),
        ("old development, exposure gains only", "old", [], "twin", False,
         fr.RobustConfig(floors=False, weights=False), False),
        ("development fixed, noise floors only", "now", [], "twin", False,
         fr.RobustConfig(gains=False, weights=False), False),
        ("old development, floors and exposure gains", "old", [], "twin", False, fr.RobustConfig(weights=False),
         False),
        ("floors, gains and weights, old development", "old", [], "twin", False, fr.RobustConfig(), False),
        ("floors, gains and weights, development fixed", "now", [], "twin", False, fr.RobustConfig(), False),
        ("the same without the binning correction", "now", [], "none", False, fr.RobustConfig(), False),
        ("new fit: the correction also anchored at the estimates", "now", [], "estimates", False, fr.RobustConfig(),
         False),
    ]
    results = {"brightness": bright, "truth_d": truth_d.tolist(), "estimates": {}}
    with tempfile.TemporaryDirectory() as tmp:
        copy_root = make_copy(cap_dir, Path(tmp), np.asarray(cap.focus_m) * a.scale)
        copy = load_capture_data(copy_root / cap_dir.name, model, use_exiftool=False)
        sweeps = {}
        jobs = [(name, c) for name, c in (("capture", cap), (f"copy x{a.scale:g}", copy))]
        bar = tqdm(total=len(jobs) * len(variants), desc="variants", unit="fit")
        for name, c in jobs:
            print(f"\n## Per-frame focus estimate minus the truth (D): {name} (reported = "
                  f"{'true' if c is cap else f'{a.scale:g} x true distance'})\n")
            print("| variant | " + " | ".join(f"f{i}" for i in range(len(truth_d))) +
                  " | rms | on a bound | family | corrected focus max error (D) |")
            print("|---|" + "---|" * (len(truth_d) + 4))
            for label, dev, chain, corr, old_fit, cfg, texture_only in variants:
                key = (name, tuple(chain), corr)
                if key not in sweeps:
                    sweeps[key] = sweep_for(twins, c, [fx.make(e) for e in chain], factor, corr)
                data = sweeps[key]
                if dev == "old":
                    data = with_frames(data, old, factor)
                w = None
                if texture_only:
                    rng_t = data.twin.max(-1) - data.twin.min(-1)
                    w = data.weight * (rng_t >= np.median(rng_t))
                r = estimate(data, truth_d, cfg, old_fit, w)
                results["estimates"].setdefault(name, {})[label] = {k: (v.tolist() if isinstance(v, np.ndarray)
                                                                        else v) for k, v in r.items()}
                print(f"| {label} | " + " | ".join(f"{x:+.3f}" for x in r["err"]) +
                      f" | {np.sqrt(np.mean(r['err'] ** 2)):.3f} | {r['on_bound']} | {r['family']} | "
                      f"{r['corrected_max']:.3f} |", flush=True)
                bar.update()
        bar.close()
        curves = region_examples(sweeps[("capture", (), "twin")], truth_d)
    results["regions"] = curves
    figure(Path(a.figure), results, cap.focus_m)
    print(f"\nfigure: {a.figure}")
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1, default=float))


def region_examples(data, truth_d: np.ndarray) -> dict:
    """A textured and a textureless region: the capture's curve, the twin's at the true focus, and the twin's with
    its fitted floor (each shifted to the capture's mean)."""
    from aat_deploy.diagnose import focusrobust as fr

    rng_t = data.twin.max(-1)[0] - data.twin.min(-1)[0]
    tw = fr.twin_at(data, truth_d[None])[0]
    beta = fr.fit_floors(data, truth_d[None])[0]
    tw_f = fr.twin_at(fr.floored(data, beta[None]), truth_d[None])[0]
    out = {}
    for label, r in (("textured", int(np.argmax(rng_t))), ("textureless", int(np.argmin(rng_t)))):
        c = data.capture[0, r]
        out[label] = {"region": r, "capture": (c - c.mean()).tolist(), "twin": (tw[r] - tw[r].mean()).tolist(),
                      "twin_floored": (tw_f[r] - tw_f[r].mean()).tolist()}
    return out


def figure(path: Path, res: dict, focus_m: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aat_deploy.io.atomic import atomic_file

    fig, ax = plt.subplots(1, 4, figsize=(17, 3.8))
    b = res["brightness"]
    i = np.arange(len(focus_m))
    ax[0].plot(i, b["recorded"], "k.-", label="recorded (mosaic)")
    ax[0].plot(i, b["developed_before"], "r.-", label="developed before (LibRaw default)")
    ax[0].plot(i, b["developed_now"], "b.--", label="developed now")
    ax[0].set(title="frame brightness", xlabel="frame (near to far)", ylabel="mean (white = 1)")
    ax[0].legend(fontsize=7)
    for k, (name, est) in enumerate(res["estimates"].items()):
        a = ax[1 + k]
        for label, style in (("as it was: old development, old fit", "r.-"), ("old fit, development fixed", "m.-"),
                             ("development fixed, noise floors only", "g.-"),
                             ("new fit: the correction also anchored at the estimates", "b.-")):
            if label in est:
                a.plot(i, est[label]["err"], style, label=label)
        a.axhline(0, color="k", lw=0.5)
        a.axhspan(-0.02, 0.02, color="0.9")
        a.set(title=f"per-frame focus error: {name}", xlabel="frame (near to far)", ylabel="estimate - truth (D)",
              ylim=(-0.45, 0.45))
        a.legend(fontsize=6)
    a = ax[3]
    for label, col in (("textured", "b"), ("textureless", "g")):
        r = res["regions"][label]
        a.plot(i, r["capture"], col + "o-", label=f"capture, {label} region {r['region']}")
        a.plot(i, r["twin"], col + ":", label="twin at the true focus")
        a.plot(i, r["twin_floored"], col + "--", label="twin with its fitted floor")
    a.set(title="log focus measure (mean removed)", xlabel="frame (near to far)")
    a.legend(fontsize=6)
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


if __name__ == "__main__":
    main()
