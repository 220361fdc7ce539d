"""Runtime inference: onnxruntime (what `aat-infer` runs) vs torch eager on the same net and input.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_runtime [--sizes small] [--hw 640x960] [--stack 8]
                                                               [--nets dfvnet,aifnet,dfvaat]

For each net, a freshly built model (weights do not change the speed) is exported exactly as the shipped
models are (training.nets.export), then one normalised (S, 3, H, W) stack is run by torch (`predict`, eager,
no grad) and by the runtime (`aat_deploy.infer.model.DfFModel.infer`), both on 2 threads; best of 3, one run.
Prints a table: seconds per stack each way, the ratio, and the max |difference| of the depths. The any-camera net
(`dfvaat`, the small DFVNet told per-pixel focus maps) runs as `aat-infer --model dfv_aat` runs it: its runtime time
includes making the maps (thin lens, a 50 mm f/1.8 camera); two rows: whole frames, and as shipped, in overlapping
tiles of the largest scenes it trained on (aat.tile_px; the depth difference of that row is tiled vs whole).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch

from benchmarks.timing import best_of

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="small")
    ap.add_argument("--hw", default="640x960")
    ap.add_argument("--stack", type=int, default=8)
    ap.add_argument("--nets", default="dfvnet,aifnet,dfvaat")
    args = ap.parse_args()
    h, w = (int(v) for v in args.hw.split("x"))
    torch.set_num_threads(2)
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.focus_table import diopter_grid
    from training.nets.export import dff_metadata, export_dff_onnx
    from training.nets.model import build_model, predict

    lens = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
    rng = np.random.default_rng(0)
    stack = rng.random((args.stack, 3, h, w), dtype=np.float32)
    focus = np.sort(diopter_grid(0.5, 10.0, args.stack)).astype(np.float32)
    rows = []
    for size in args.sizes.split(","):
        for net in args.nets.split(","):
            if net == "dfvaat":
                rows.extend(any_camera(size, stack, focus))
                continue
            torch.manual_seed(0)
            model = build_model(net, size).eval()
            with tempfile.TemporaryDirectory() as d:
                path = Path(d) / "m.onnx"
                md = dff_metadata(model, lens, simulator="aat", effects=[], focus_range_m=(0.5, 10.0),
                                  stack_range=(2, 16), config_hash="benchmark")
                export_dff_onnx(model, path, md)
                rt = DfFModel(path, threads=2)
                with torch.no_grad():
                    ref, t_torch = best_of(lambda m=model: predict(m, torch.from_numpy(stack)[None],
                                                                  torch.from_numpy(focus)[None]), repeat=3)
                out, t_ort = best_of(lambda rt=rt: rt.infer(stack, focus), repeat=3)
            diff = float(np.abs(out.depth_m - ref["depth_m"][0].numpy()).max())
            rows.append((f"{net} {size}", t_torch, t_ort, diff))
            print(f"done {net} {size}", flush=True)
    print(f"\n### DfF inference, one stack of {args.stack} x 3 x {h} x {w}, 2 threads\n")
    print("| net | torch eager | onnxruntime (aat-infer) | torch / ORT | max abs depth diff (m) |")
    print("|---|---|---|---|---|")
    for name, tt, to, d in rows:
        print(f"| {name} | {tt:.2f} s | {to:.2f} s | {tt / to:.2f}x | {d:.1e} |")


def any_camera(size: str, stack: np.ndarray, focus: np.ndarray) -> list[tuple]:
    """The any-camera net, torch vs the runtime (maps included), whole frames; then as shipped: the runtime in tiles
    of aat.tile_px (the largest single scenes configs/anycam/dfv_aat.json trains on, training.train.export),
    against torch on the whole frame (the difference column then is tiled vs whole, not a parity check)."""
    from aat_deploy.anycam.model import FocusMapModel
    from aat_deploy.anycam.optics import CameraOptics
    from training.nets.dfvaat import build, predict
    from training.nets.export import export_focus_map_onnx, focus_map_metadata
    from training.train.config import load_config
    from training.train.export import largest_training_image_px

    torch.manual_seed(0)
    model = build(size).eval()
    h, w = stack.shape[2:]
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.onnx"
        export_focus_map_onnx(model, path, focus_map_metadata(model, effects=[], stack_range=(3, 16),
                                                              config_hash="benchmark", k_range=(0.3, 64)))
        rt = FocusMapModel(path, threads=2).bound(CameraOptics(50.0, 1.8, 37.5, w, "benchmark"), focus)
        maps = torch.from_numpy(rt.maps(focus, h, w))[None]
        with torch.no_grad():
            ref, t_torch = best_of(lambda: predict(model, torch.from_numpy(stack)[None], maps[:, :-1], maps[:, -1:]),
                                   repeat=3)
        out, t_ort = best_of(lambda: rt.infer(stack, focus, tile=0), repeat=3)
        tile = largest_training_image_px(load_config(ROOT / "configs/anycam/dfv_aat.json").data)
        tiled, t_tiled = best_of(lambda: rt.infer(stack, focus, tile=tile, overlap=tile // 4), repeat=3)
    print(f"done dfvaat {size}", flush=True)
    ref_d = ref["depth_m"][0].numpy()
    return [(f"dfvaat {size} (any camera, whole frame)", t_torch, t_ort, float(np.abs(out.depth_m - ref_d).max())),
            (f"dfvaat {size} (any camera as shipped: tiles of {tile} px, {tile // 4} overlapping)", t_torch, t_tiled,
             float(np.abs(tiled.depth_m - ref_d).max()))]


if __name__ == "__main__":
    main()
