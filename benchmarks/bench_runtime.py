"""Runtime inference: onnxruntime (what `aat-infer` runs) vs torch eager on the same net and input.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_runtime [--sizes small] [--hw 640x960] [--stack 8] [--anycam-size S]
        [--nets dfvnet,aifnet,dfvaat] [--threads 2] [--tile N] [--rounds 5] [--json results/runtime.json]

For each net, a freshly built model (weights do not change the speed) is exported exactly as the shipped
models are (training.nets.export), then one normalised (S, 3, H, W) stack is run by torch (`predict`, eager,
no grad) and by the runtime (`aat_deploy.infer.model.DfFModel.infer`), both on --threads threads (2; 1 in a
heavy-job lane); best of 3, one run.
Prints a table: seconds per stack each way, the ratio, and the max |difference| of the depths. The any-camera net
(`dfvaat`, the small DFVNet told per-pixel focus maps) runs as `aat-infer --model dfv_aat` runs it: its runtime time
includes making the maps (thin lens, a 50 mm f/1.8 camera); two rows: whole frames, and as shipped, in overlapping
tiles of the largest scenes it trained on (aat.tile_px, --tile to set it as a model's metadata says), overlapping as
the runtime overlaps them (`aat_deploy.anycam.model.own_tiles`; the depth difference of that row is tiled vs whole).
With both `dfvnet` and `dfvaat`, a second table gives the any-camera net's runtime time over the DFVNet's of the
same size and input (issue 35: no slower than today's DFVNet), and a third the same ratios from --rounds rounds in which the DFVNet and the any-camera net's ways (whole frame, its own
tiles batched and one per run, tiles a quarter overlapping one per run as before 2026-11-26) run in turn (`in_turns`): median and range over the
rounds, steadier on a shared machine than the separate best-of runs; --json also writes the rows.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import torch

from benchmarks.timing import best_of

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="small")
    ap.add_argument("--hw", default="640x960")
    ap.add_argument("--stack", type=int, default=8)
    ap.add_argument("--nets", default="dfvnet,aifnet,dfvaat")
    ap.add_argument("--threads", type=int, default=2, help="threads of torch and the runtime (1 in a heavy-job lane)")
    ap.add_argument("--tile", type=int, default=None,
                    help="the any-camera net's tile (px; default: the largest image configs/anycam/dfv_aat.json "
                         "trains on, what its export writes as aat.tile_px)")
    ap.add_argument("--anycam-size", default=None,
                    help="the any-camera net's size (training.nets.dfvaat.CONFIGS, e.g. small_replicate: edge-value "
                         "padding, which adds Pad nodes; default: each --sizes value)")
    ap.add_argument("--rounds", type=int, default=5,
                    help="with dfvnet and dfvaat: rounds in which the DFVNet and the any-camera net's ways run in turn "
                         "(0: none)")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows here (JSON)")
    args = ap.parse_args(argv)
    h, w = (int(v) for v in args.hw.split("x"))
    threads = args.threads
    torch.set_num_threads(threads)
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.focus_table import diopter_grid
    from training.nets.export import dff_metadata, export_dff_onnx
    from training.nets.model import build_model, predict

    lens = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
    rng = np.random.default_rng(0)
    stack = rng.random((args.stack, 3, h, w), dtype=np.float32)
    focus = np.sort(diopter_grid(0.5, 10.0, args.stack)).astype(np.float32)
    rows, runtimes = [], {}
    for size in args.sizes.split(","):
        for net in args.nets.split(","):
            if net == "dfvaat":
                more, runtimes[("dfvaat", size)] = any_camera(args.anycam_size or size, stack, focus, threads,
                                                              args.tile)
                rows.extend(more)
                continue
            torch.manual_seed(0)
            model = build_model(net, size).eval()
            with tempfile.TemporaryDirectory() as d:
                path = Path(d) / "m.onnx"
                md = dff_metadata(model, lens, simulator="aat", effects=[], focus_range_m=(0.5, 10.0),
                                  stack_range=(2, 16), config_hash="benchmark")
                export_dff_onnx(model, path, md)
                rt = DfFModel(path, threads=threads)
                with torch.no_grad():
                    ref, t_torch = best_of(lambda m=model: predict(m, torch.from_numpy(stack)[None],
                                                                  torch.from_numpy(focus)[None]), repeat=3)
                out, t_ort = best_of(lambda rt=rt: rt.infer(stack, focus), repeat=3)
                runtimes[(net, size)] = rt
            diff = float(np.abs(out.depth_m - ref["depth_m"][0].numpy()).max())
            rows.append((f"{net} {size}", t_torch, t_ort, diff))
            print(f"done {net} {size}", flush=True)
    print(f"\n### DfF inference, one stack of {args.stack} x 3 x {h} x {w}, {threads} thread(s)\n")
    print("| net | torch eager | onnxruntime (aat-infer) | torch / ORT | max abs depth diff (m) |")
    print("|---|---|---|---|---|")
    for name, tt, to, d in rows:
        print(f"| {name} | {tt:.2f} s | {to:.2f} s | {tt / to:.2f}x | {d:.1e} |")
    ratios = anycam_ratios(rows)
    if ratios:
        print("\n| any-camera net, runtime | its time / the DFVNet's (same size, input, run) |\n|---|---|")
        for name, r in ratios.items():
            print(f"| {name} | {r:.2f}x |")
    turns = {}
    for size in args.sizes.split(","):
        if args.rounds > 0 and ("dfvnet", size) in runtimes and ("dfvaat", size) in runtimes:
            rt, tile = runtimes[("dfvaat", size)]
            turns[size] = in_turns(runtimes[("dfvnet", size)], rt, tile, stack, focus, args.rounds)
            print(f"\n| {size} nets, {args.rounds} rounds in turn | seconds (best) | its time / the DFVNet's in the "
                  "same round: median [least, most] |\n|---|---|---|")
            for name, secs in turns[size].items():
                r = np.array(secs) / np.array(turns[size]["DFVNet"])
                print(f"| {name} | {min(secs):.2f} s | {np.median(r):.2f}x [{r.min():.2f}, {r.max():.2f}] |")
    if args.json is not None:
        from aat_deploy.io.atomic import write_text_atomic

        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(args.json, json.dumps({
            "stack": [args.stack, 3, h, w], "threads": threads, "repeat": 3,
            "rows": [{"net": n, "torch_s": tt, "runtime_s": to, "max_abs_depth_diff_m": d} for n, tt, to, d in rows],
            "anycam_over_dfvnet": ratios, "rounds_in_turn_s": turns}, indent=1))
        print(f"wrote {args.json}")


def anycam_ratios(rows: list[tuple]) -> dict[str, float]:
    """{any-camera row: its runtime seconds / those of the DFVNet of the same size}, rows (name, torch s, runtime
    s, diff) as main prints them ("dfvnet small", "dfvaat small (...)")."""
    dfv = {name.split()[1]: to for name, _, to, _ in rows if name.split()[0] == "dfvnet"}
    return {name: to / dfv[name.split()[1]] for name, _, to, _ in rows
            if name.split()[0] == "dfvaat" and name.split()[1] in dfv}


def any_camera(size: str, stack: np.ndarray, focus: np.ndarray, threads: int = 2, tile: int | None = None
               ) -> tuple[list[tuple], tuple]:
    """The any-camera net, torch vs the runtime (maps included), whole frames; then as shipped: the runtime in tiles
    of aat.tile_px (the largest single scenes configs/anycam/dfv_aat.json trains on, training.train.export),
    against torch on the whole frame (the difference column then is tiled vs whole, not a parity check). Returns
    those rows and (the runtime model bound to a camera, the tile side) for `in_turns`."""
    from aat_deploy.anycam.model import FocusMapModel, own_tiles
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
        rt = FocusMapModel(path, threads=threads).bound(CameraOptics(50.0, 1.8, 37.5, w, "benchmark"), focus)
        maps = torch.from_numpy(rt.maps(focus, h, w))[None]
        with torch.no_grad():
            ref, t_torch = best_of(lambda: predict(model, torch.from_numpy(stack)[None], maps[:, :-1], maps[:, -1:]),
                                   repeat=3)
        out, t_ort = best_of(lambda: rt.infer(stack, focus, tile=0), repeat=3)
        if tile is None:
            tile = largest_training_image_px(load_config(ROOT / "configs/anycam/dfv_aat.json").data)
        tile, overlap = own_tiles(tile)
        tiled, t_tiled = best_of(lambda: rt.infer(stack, focus, tile=tile, overlap=overlap), repeat=3)
    print(f"done dfvaat {size}", flush=True)
    ref_d = ref["depth_m"][0].numpy()
    return [(f"dfvaat {size} (any camera, whole frame)", t_torch, t_ort, float(np.abs(out.depth_m - ref_d).max())),
            (f"dfvaat {size} (any camera as shipped: tiles of {tile} px, {overlap} overlapping)", t_torch, t_tiled,
             float(np.abs(tiled.depth_m - ref_d).max()))], (rt, tile)


def in_turns(dfv, anycam, tile: int, stack: np.ndarray, focus: np.ndarray, rounds: int) -> dict[str, list[float]]:
    """{way: seconds in each round}: the DFVNet's runtime, then the any-camera net's on whole frames, in its own tiles
    (`own_tiles`) batched as the runtime runs them (`TILE_BATCH_PX`) and one per run, and in tiles a quarter
    overlapping one per run (the runtime before 2026-11-26), one after the other in every
    round on the same input, after one warm-up each: a load change on the shared machine hits the ways of a round
    alike, so the ratio within rounds is steadier than that of separate best-of runs."""
    import aat_deploy.infer.model as infer_model
    from aat_deploy.anycam.model import own_tiles

    _, overlap = own_tiles(tile)

    def one_per_run(fn):  # tiles one per onnxruntime run, as before TILE_BATCH_PX
        def run():
            keep, infer_model.TILE_BATCH_PX = infer_model.TILE_BATCH_PX, 1
            try:
                return fn()
            finally:
                infer_model.TILE_BATCH_PX = keep
        return run

    ways = {"DFVNet": lambda: dfv.infer(stack, focus),
            "any-camera net, whole frame (maps included)": lambda: anycam.infer(stack, focus, tile=0),
            f"any-camera net as shipped: {tile} px tiles, {overlap} px overlap, batched":
                lambda: anycam.infer(stack, focus, tile=tile, overlap=overlap),
            f"any-camera net, {tile} px tiles, {overlap} px overlap, one per run":
                one_per_run(lambda: anycam.infer(stack, focus, tile=tile, overlap=overlap)),
            f"any-camera net, {tile} px tiles, {tile // 4} px overlap, one per run (the runtime before 2026-11-26)":
                one_per_run(lambda: anycam.infer(stack, focus, tile=tile, overlap=tile // 4))}
    for fn in ways.values():
        fn()
    secs: dict[str, list[float]] = {k: [] for k in ways}
    for _ in range(rounds):
        for k, fn in ways.items():
            secs[k].append(best_of(fn)[1])
    return secs


if __name__ == "__main__":
    main()
