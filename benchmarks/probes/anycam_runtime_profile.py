"""Where the any-camera net's runtime time goes, per op type, against the lens-specific DFVNet (issue 35's speed).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_runtime_profile [--dfvaat A.onnx ...]
        [--checkpoint RUN/last.pt ...] [--hw 640x960] [--stack 8] [--threads 1,2] [--runs 5] [--out results/anycam_runtime_profile.md]

Graphs: the small DFVNet and the small any-camera net, both freshly built and exported by the current code exactly
as bench_runtime exports them (weights do not change the speed), and any --dfvaat ONNX files given (e.g. an export
made by older code: `models/reproduce/dfv_aat_v1.onnx`), and any --checkpoint exported now by the current code
(`training.train.export.export_checkpoint`, into a temporary folder). One input for all: a (1, S, 3, H, W) random stack, S focus
distances even in diopters over 0.5-10 m; the any-camera graphs also get the thin-lens maps (every pixel of frame s
at 1/F_s diopters, 20 px per diopter). Each graph runs on onnxruntime's CPU provider with its profiler on, at each
thread count: one warm-up run each, then --runs runs taking turns; prints per op type the least kernel milliseconds
over the runs of each graph (the least disturbed by the shared machine's load) and the any-camera graphs' excess
over the DFVNet, then the wall times (best of the runs). onnxruntime's own
fused kernels (FusedConv ...) are op types of their own. Writes the same tables to --out (markdown).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def profile(graphs: dict[str, Path], feeds: dict[str, dict], threads: int, runs: int, tmp: Path
            ) -> dict[str, tuple[dict[str, float], float]]:
    """{graph: ({op type: least kernel ms over the runs}, best wall seconds)}. The graphs take turns run by run (a
    load change on the shared machine hits all of them), each after one unprofiled-in-the-result warm-up run; the
    least time of each op type over the runs, as the best of the wall times, is the one least disturbed."""
    import onnxruntime as ort

    sessions = {}
    for n, path in graphs.items():
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.enable_profiling = True
        opts.profile_file_prefix = str(tmp / f"{path.stem}_{threads}")
        sessions[n] = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        sessions[n].run(None, feeds[n])  # warm-up: left out below
    walls: dict[str, list[float]] = {n: [] for n in graphs}
    for _ in range(runs):
        for n, sess in sessions.items():
            t0 = time.perf_counter()
            sess.run(None, feeds[n])
            walls[n].append(time.perf_counter() - t0)
    out = {}
    for n, sess in sessions.items():
        events = json.loads(Path(sess.end_profiling()).read_text())
        starts = sorted(e["ts"] for e in events if e.get("cat") == "Session" and e.get("name") == "model_run")
        if len(starts) != runs + 1:
            raise RuntimeError(f"{graphs[n]}: the profile holds {len(starts)} runs, expected {runs + 1}")
        per_run = [collections.Counter() for _ in range(runs)]
        for e in events:
            if e.get("cat") == "Node" and e["name"].endswith("_kernel_time") and e["ts"] >= starts[1]:
                r = max(i for i in range(runs) if starts[i + 1] <= e["ts"])
                per_run[r][e["args"]["op_name"]] += e["dur"] / 1000.0
        ops = set().union(*per_run)
        out[n] = ({op: min(c.get(op, 0.0) for c in per_run) for op in ops}, min(walls[n]))
    return out


def feeds_for(path: Path, stack: np.ndarray, focus_m: np.ndarray) -> dict:
    """Inputs by the graph's input names: DFVNet (stack, focus_m) or the any-camera net (+ thin-lens maps)."""
    import onnxruntime as ort

    names = {i.name for i in ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).get_inputs()}
    s, _, h, w = stack.shape
    feeds = {"stack": stack[None]}
    if "focus_m" in names:
        feeds["focus_m"] = focus_m[None]
    if "focus_diopters" in names:
        feeds["focus_diopters"] = np.ascontiguousarray(
            np.broadcast_to((1.0 / focus_m)[None, :, None, None], (1, s, h, w)), np.float32)
        feeds["defocus_px_per_d"] = np.full((1, 1, h, w), 20.0, np.float32)
    return feeds


def fresh_exports(d: Path) -> dict[str, Path]:
    """The small DFVNet and the small any-camera net, built with seed 0 and exported as bench_runtime does."""
    import torch

    from aat_deploy.lens.io import load_lens
    from training.nets.dfvaat import build
    from training.nets.export import dff_metadata, export_dff_onnx, export_focus_map_onnx, focus_map_metadata
    from training.nets.model import build_model

    torch.manual_seed(0)
    dfv = build_model("dfvnet", "small").eval()
    lens = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
    export_dff_onnx(dfv, d / "dfvnet.onnx", dff_metadata(dfv, lens, simulator="aat", effects=[],
                                                         focus_range_m=(0.5, 10.0), stack_range=(2, 16),
                                                         config_hash="benchmark"))
    torch.manual_seed(0)
    aat = build("small").eval()
    export_focus_map_onnx(aat, d / "dfvaat.onnx", focus_map_metadata(aat, effects=[], stack_range=(3, 16),
                                                                     config_hash="benchmark", k_range=(0.3, 64)))
    return {"DFVNet (fresh export)": d / "dfvnet.onnx", "dfv_aat (fresh export)": d / "dfvaat.onnx"}


def tables(results: dict, threads: list[int], hw: tuple[int, int], s: int) -> str:
    """Markdown: per thread count, per op type the kernel ms of each graph and the any-camera graphs' excess."""
    names = list(next(iter(results.values())))
    ref = names[0]
    out = []
    for t in threads:
        per = results[t]
        ops = set().union(*(per[n][0] for n in names))
        excess = {op: max(per[n][0].get(op, 0.0) - per[ref][0].get(op, 0.0) for n in names[1:]) for op in ops}
        out.append(f"\n#### {t} thread(s), one stack of {s} x 3 x {hw[0]} x {hw[1]}: least kernel ms per run by op type\n")
        out.append("| op type | " + " | ".join(names) + " | " + " | ".join(f"{n} - DFVNet" for n in names[1:]) + " |")
        out.append("|---" * (2 * len(names)) + "|")
        for op in sorted(ops, key=lambda o: (-abs(excess[o]), o)):
            vals = [per[n][0].get(op, 0.0) for n in names]
            if max(vals) < 0.05:
                continue
            out.append(f"| {op} | " + " | ".join(f"{v:.1f}" for v in vals) + " | "
                       + " | ".join(f"{v - vals[0]:+.1f}" for v in vals[1:]) + " |")
        totals = [sum(per[n][0].values()) for n in names]
        out.append("| **all kernels** (sum of the rows) | " + " | ".join(f"**{v:.1f}**" for v in totals) + " | "
                   + " | ".join(f"**{v - totals[0]:+.1f}**" for v in totals[1:]) + " |")
        walls = [per[n][1] for n in names]
        out.append("| wall s (best run) | " + " | ".join(f"{v:.3f}" for v in walls) + " | "
                   + " | ".join(f"{v / walls[0]:.2f}x" for v in walls[1:]) + " |")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dfvaat", type=Path, nargs="*", default=[], help="more any-camera ONNX files to profile")
    ap.add_argument("--checkpoint", type=Path, nargs="*", default=[],
                    help="any-camera checkpoints (last.pt, model.pt) to export with the current code and profile")
    ap.add_argument("--hw", default="640x960")
    ap.add_argument("--stack", type=int, default=8)
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None, help="also write the tables here (markdown)")
    a = ap.parse_args(argv)
    h, w = (int(v) for v in a.hw.split("x"))
    threads = [int(t) for t in a.threads.split(",")]
    rng = np.random.default_rng(0)
    stack = rng.random((a.stack, 3, h, w), dtype=np.float32)
    focus = np.sort(1.0 / np.linspace(2.0, 0.1, a.stack)).astype(np.float32)  # 0.5-10 m, even in diopters
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        graphs = fresh_exports(d)
        graphs.update({f"`{p.name}`": p for p in a.dfvaat})
        for i, ck in enumerate(a.checkpoint):
            from training.train.export import export_checkpoint

            export_checkpoint(ck, d / f"checkpoint{i}.onnx")
            graphs[f"`{ck.parent.name}/{ck.name}` exported now"] = d / f"checkpoint{i}.onnx"
        feeds = {n: feeds_for(p, stack, focus) for n, p in graphs.items()}
        results, load = {}, os.getloadavg()[0]
        for t in threads:
            results[t] = profile(graphs, feeds, t, a.runs, d)
            print(f"done {t} thread(s)", file=sys.stderr, flush=True)
        load = (load, os.getloadavg()[0])
    text = (f"### onnxruntime profile, DFVNet vs the any-camera net (`python -m benchmarks.probes.anycam_runtime_profile"
            f" {' '.join(argv if argv is not None else sys.argv[1:])}`; 1-minute load average {load[0]:.1f} at the start,"
            f" {load[1]:.1f} at the end, on {os.cpu_count()} cores)\n" + tables(results, threads, (h, w), a.stack))
    print(text)
    if a.out is not None:
        from aat_deploy.io.atomic import write_text_atomic

        a.out.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(a.out, text)
        print(f"wrote {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
