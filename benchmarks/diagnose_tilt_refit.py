"""How far the sensor-tilt fit's two steps land from a known tilt (docs/diagnosis.md, `sensor_tilt`): the amount
the focus sweep reads (least squares per region) and the amount refitted on binned twins (`fitters.refine_amount`),
remeasured after the renderer's per-anchor cell fix (c9c07bd). Before it, a -0.85 deg tilt of a 960 x 640
benchmark set was read as -0.54 deg from the sweep and -0.81 deg after the refit.

The tilted capture is made from the shipped sample's ground truth and all-in-focus image by the torch-free twin
renderer with the main model's simulator plus `sensor_tilt` (so the capture differs from its twin by the tilt
alone: no RAW development, the twin's own noise draw), then fitted by `fitters.fit_sensor_tilt` on twins without
it, as the diagnosis's first round fits it.

    python -m benchmarks.diagnose_tilt_refit [--tilts -0.85 0.5]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from benchmarks import ROOT


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tilts", type=float, nargs="+", default=[-0.85], help="tilt_x_deg of the made captures")
    ap.add_argument("--capture", default=str(ROOT / "captures" / "sample_rf50"))
    ap.add_argument("--model", default=str(ROOT / "models" / "rf50_dfvnet_aat_field.onnx"))
    a = ap.parse_args()
    from aat_deploy.diagnose import fitters
    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.diagnose.search import DiagnoseConfig
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.render import effects as fx

    model = DfFModel(a.model, threads=2)
    lens, _ = find_lens(model, None)
    twins = make_renderer(model, lens, find_surrogate(lens, None), torch_free=True)
    cap = load_capture_data(a.capture, model)
    cfg = DiagnoseConfig()
    factor = max(1, min(8, cap.frames.shape[-1] // cfg.search_px))
    print("| tilt_x (deg) | read from the sweep (deg, 95 % interval) | after the refit (deg; factor) | tilt_y read "
          "(deg) | seconds |")
    print("|---|---|---|---|---|")
    for tilt in a.tilts:
        t0 = time.time()
        frames = twins.linear(cap, cap.aif_linear, [fx.make("sensor_tilt", tilt_x_deg=tilt, tilt_y_deg=0.0)],
                              seed=cfg.seed)
        tilted = dataclasses.replace(cap, frames=np.clip(frames, 0, None).astype(np.float32), name="tilted")
        full = [fitters.fit_curves(twins.render(tilted, cap.aif_linear, [], seed=cfg.seed), factor)]
        state = fitters.FitState(twins, [tilted], [cap.aif_linear], [], fx.make, factor, cfg.fit_boot, cfg.seed,
                                 {}, full)
        sf = fitters.fit_sensor_tilt(state).report["shift_fit"]
        lo, hi = sf["params_ci"]["tilt_x_deg"]
        ref = sf.get("refined")
        after = f"{ref['params']['tilt_x_deg']:.3f}; {ref['factor']:.2f}" if ref else "not proposed"
        print(f"| {tilt} | {sf['params']['tilt_x_deg']:.3f} ({lo:.3f} to {hi:.3f}) | {after} | "
              f"{sf['params']['tilt_y_deg']:.3f} | {time.time() - t0:.0f} |", flush=True)


if __name__ == "__main__":
    main()
