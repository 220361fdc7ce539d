"""Twins of one capture with chosen effect combinations: how close each comes to the capture and what the model's
depth error on it is. For checking what `aat-diagnose`'s one-effect-at-a-time search cannot see, e.g. effects
that only matter together (BENCHMARKS.md, the shipped sample).

    python -m benchmarks.twin_combinations captures/sample_rf50 --model models/reproduce/dff_dfvnet_aat.onnx \\
        --combos ",noise,vignetting,noise+vignetting,noise+raw_pipeline,noise+vignetting+raw_pipeline" --seeds 1,2

Per combination (effects joined by '+', settings as name:k=v; '' = the model's own simulator) and noise seed:
the focus-curve distance to the capture (`aat_deploy.diagnose.compare`, natural-log units), the mean
|capture - twin| of the normalised stacks, and the model's mean absolute depth error (m) over the frame, its
right-most sixth and the rest. The capture's own error heads the table.
"""

from __future__ import annotations

import argparse

import numpy as np

from aat_deploy.diagnose.compare import focus_curves
from aat_deploy.diagnose.inputs import load_capture_data
from aat_deploy.diagnose.lookup import find_lens, find_surrogate
from aat_deploy.diagnose.session import make_renderer
from aat_deploy.infer.model import DfFModel
from aat_deploy.infer.normalise import normalise_stack
from aat_deploy.render import effects as fx


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", help="a capture folder with ground truth")
    ap.add_argument("--model", required=True)
    ap.add_argument("--lens")
    ap.add_argument("--psf")
    ap.add_argument("--combos", default=",noise,vignetting,raw_pipeline,noise+vignetting,noise+raw_pipeline,"
                    "noise+vignetting+raw_pipeline")
    ap.add_argument("--seeds", default="1,2", help="noise seeds of the twins")
    a = ap.parse_args()
    m = DfFModel(a.model, threads=2)
    lens, _ = find_lens(m, a.lens)
    twins = make_renderer(m, lens, find_surrogate(lens, a.psf))
    cap = load_capture_data(a.capture, m)
    real = normalise_stack(np.clip(cap.frames, 0, None))
    curves = focus_curves(real)
    aif = cap.aif_linear
    if aif is None:
        aif = m.infer(real, cap.focus_m.astype(np.float32)).aif
    edge = cap.gt_m.shape[1] * 5 // 6

    def errors(stack: np.ndarray) -> str:
        e = np.abs(m.infer(stack, cap.focus_m.astype(np.float32)).depth_m - cap.gt_m)
        return f"{np.nanmean(e):.3f} | {np.nanmean(e[:, edge:]):.3f} | {np.nanmean(e[:, :edge]):.3f}"

    print(f"\n{a.capture}, model {a.model} (simulator: {', '.join(fx.spec(e) for e in twins.base) or 'thin lens'})\n")
    print("| twin effects (added) | seed | focus-curve distance | mean abs stack diff. | MAE (m) | MAE right sixth | "
          "MAE rest |")
    print("|---|---|---|---|---|---|---|")
    print(f"| (the capture) | — | — | — | {errors(real)} |")
    for combo in a.combos.split(","):
        specs = [s for s in combo.split("+") if s]
        for seed in [int(s) for s in a.seeds.split(",")]:
            tw = twins.render(cap, aif, fx.parse(specs), seed=seed)
            d = float(np.mean(np.abs(curves - focus_curves(tw))))
            print(f"| {' + '.join(specs) or '(none)'} | {seed} | {d:.3f} | {np.abs(real - tw).mean():.4f} | "
                  f"{errors(tw)} |", flush=True)


if __name__ == "__main__":
    main()
