"""The routed any-camera file (`training.train.route`) vs the net it routes to, on the same input.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_route [--model models/reproduce/dfv_aat_route_v12_v10.onnx]
        [--hw 640x960] [--stacks 5,8] [--threads 1] [--rounds 5] [--json results/bench_route.json]

The routed file holds two nets and an ONNX `If` on the frame count. For each stack size, one random normalised stack
with thin-lens focus maps is run by onnxruntime through the routed file and through the file of the net its
`aat.route` names for that size, in turn, --rounds times; the table gives the median and range over the rounds of
routed / direct seconds, and the largest |difference| of the depths (the routing must change nothing).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _session(path: Path, threads: int):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def feeds(s: int, h: int, w: int, seed: int = 0) -> dict:
    """One (1, S, 3, H, W) stack in [0, 1] and its maps: frames even in diopters over 2-0.1 D, defocus 20 px/D."""
    rng = np.random.default_rng(seed)
    focus = np.linspace(2.0, 0.1, s, dtype=np.float32)
    return {"stack": rng.random((1, s, 3, h, w), dtype=np.float32),
            "focus_diopters": np.broadcast_to(focus[None, :, None, None], (1, s, h, w)).copy(),
            "defocus_px_per_d": np.full((1, 1, h, w), 20.0, np.float32)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=ROOT / "models" / "reproduce" / "dfv_aat_route_v12_v10.onnx")
    ap.add_argument("--hw", default="640x960", help="H x W (px)")
    ap.add_argument("--stacks", default="5,8", help="frame counts")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    if not a.model.is_file():
        print(f"error: {a.model}: no such model file", file=sys.stderr)
        return 2
    routed = _session(a.model, a.threads)
    meta = routed.get_modelmeta().custom_metadata_map
    if "aat.route" not in meta:
        print(f"error: {a.model}: not a routed model (no aat.route metadata)", file=sys.stderr)
        return 2
    route = json.loads(meta["aat.route"])
    h, w = (int(v) for v in a.hw.lower().split("x"))
    rows = []
    for s in (int(v) for v in a.stacks.split(",")):
        branch = route["small"] if s <= route["max_small_frames"] else route["large"]
        direct_path = a.model.parent / branch["file"]
        if not direct_path.is_file():
            print(f"error: {direct_path}: the routed net's own file is missing", file=sys.stderr)
            return 2
        direct = _session(direct_path, a.threads)
        f = feeds(s, h, w)
        diff = float(np.abs(routed.run(["depth_m"], f)[0] - direct.run(["depth_m"], f)[0]).max())  # also warms up
        ratios, t_routed, t_direct = [], [], []
        for _ in range(a.rounds):
            t0 = time.perf_counter()
            routed.run(None, f)
            t1 = time.perf_counter()
            direct.run(None, f)
            t2 = time.perf_counter()
            t_routed.append(t1 - t0)
            t_direct.append(t2 - t1)
            ratios.append((t1 - t0) / (t2 - t1))
        rows.append({"frames": s, "net": branch["file"], "routed_s": float(np.median(t_routed)),
                     "direct_s": float(np.median(t_direct)), "ratio_median": float(np.median(ratios)),
                     "ratio_min": float(min(ratios)), "ratio_max": float(max(ratios)), "max_depth_diff_m": diff})
    print(f"| frames | runs | routed (s) | direct (s) | routed / direct, median [range] over {a.rounds} rounds "
          "| max depth diff (m) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['frames']} | {r['net']} | {r['routed_s']:.2f} | {r['direct_s']:.2f} | {r['ratio_median']:.2f} "
              f"[{r['ratio_min']:.2f}, {r['ratio_max']:.2f}] | {r['max_depth_diff_m']:.1e} |")
    if a.json:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(a.json, json.dumps({"model": str(a.model), "hw": [h, w], "threads": a.threads,
                                              "rounds": a.rounds, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
