"""An any-camera run's error on whole RF50 validation frames, checkpoint by checkpoint (exploratory).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_stack_curve CHECKPOINT [CHECKPOINT ...]
        [--n 12] [--first 0] [--cache cache/heldout] [--threads 1] --out results/anycam_stack_curve_v9.json [--png FIG.png]

The run's own validation curve scores 128 px renders of its own generator. What the run is judged on is different:
the RF50's fixed-protocol stacks, rendered by the test-set renderer at 960 x 640 and run as whole frames (`anycam_tiles
--split validation`; training photographs, their own seed, so they may choose a setting; no held-out lens or test
scene). --first K scores stacks K to K+N-1 instead: a second dozen to choose with, apart from the dozen that judges.
This probe exports each checkpoint (model.pt, last.pt, or a kept step_NNNNN.pt) as it is and scores it on
the first N of those stacks, given the RF50's best-focus map, beside the classical method with the same map. Per
stack: MAE in metres (the judgement's unit), MAE of inverse depth in diopters (the unit the loss and the optics
work in) and the median absolute error (m). A checkpoint whose export onnxruntime disagrees with (the export's
parity check) is no file the runtime could run: it is listed as "unexportable" and not scored. Whether the curve drifts with the learning rate or swings from one
checkpoint to the next is what tells a domain gap from an unstable run. --png draws the means over the steps;
--paired compares each checkpoint with the first one given (e.g. an average of weights with a single checkpoint).
--processed also scores each stack given the training's camera processing (`training.data.anycam.camera_processing`,
seeded per stack: exposure, misalignment, noise, RAW development...), keys `processed_*`: whether a net does worse on
the clean renders the test sets are than on what it was trained on.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.probes.anycam_precise_bn import refuse_missing_or_existing
from benchmarks.probes.anycam_tiles import ROOT, fixed_stacks


def stack_errors(depth_m: np.ndarray, truth_m: np.ndarray) -> dict:
    """depth_m, truth_m (H, W) metres from the sensor; pixels with no truth (<= 0) are left out. Returns the MAE
    (m), the MAE of inverse depth (diopters) and the median absolute error (m)."""
    ok = truth_m > 0
    d, t = depth_m[ok].astype(np.float64), truth_m[ok].astype(np.float64)
    e = np.abs(d - t)
    return {"mae_m": float(e.mean()), "mae_d": float(np.abs(1.0 / d - 1.0 / t).mean()),
            "median_m": float(np.median(e))}


def processed_stack(stack: np.ndarray, index: int) -> np.ndarray:
    """stack (S, 3, H, W) normalised linear frames -> the same after a random camera's processing (seeded by the
    stack's index), normalised again as the runtime does."""
    from aat_deploy.infer.normalise import normalise_scale, scaled
    from training.data.anycam import camera_processing

    f = camera_processing(stack.astype(np.float32), np.random.default_rng([4242, index]))
    return scaled(f, normalise_scale(f))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoints", type=Path, nargs="+", help="runs' model.pt, last.pt or kept step_NNNNN.pt")
    ap.add_argument("--n", type=int, default=12, help="RF50 validation stacks (the first N)")
    ap.add_argument("--first", type=int, default=0, help="the first stack's index (stacks FIRST..FIRST+N-1)")
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"), help="where the stacks are cached")
    ap.add_argument("--threads", type=int, default=1, help="onnxruntime threads (1 in a heavy-job lane)")
    ap.add_argument("--out", type=Path, required=True, help="JSON of every stack's errors per checkpoint")
    ap.add_argument("--png", type=Path, help="also draw the means over the steps")
    ap.add_argument("--paired", action="store_true",
                    help="also each checkpoint's MAE over the first one's, paired over the stacks (95 %% bootstrap)")
    ap.add_argument("--processed", action="store_true", help="also score the stacks given a camera's processing")
    ap.add_argument("--stack-size", type=int, help="frames per stack, even in diopters over the fixed protocol's "
                    "range (default the RF50's 8): the same scenes swept with fewer or more frames")
    a = ap.parse_args(argv)
    if a.n < 1 or a.first < 0:
        ap.error(f"--n: at least 1 stack, --first: 0 or more, got {a.n}, {a.first}")
    if a.stack_size is not None and not 2 <= a.stack_size <= 32:
        ap.error(f"--stack-size: 2 to 32 frames, got {a.stack_size}")
    refuse_missing_or_existing(ap, a.checkpoints, a.out)
    if a.png and a.png.exists():
        ap.error(f"{a.png}: exists (choose another --png)")

    from tqdm import tqdm

    from aat_deploy.anycam.model import FocusMapModel, mapping_from_args
    from aat_deploy.focus import classical_depth
    from aat_deploy.focus.bestfocus import for_lens
    from aat_deploy.io.atomic import write_text_atomic
    from benchmarks.bench_anycam import LENSES
    from training.train.checkpoint import load
    from training.train.export import export_checkpoint

    lens = ROOT / LENSES["rf50"]["lens"]
    items = fixed_stacks("rf50", "validation", a.first + a.n, a.cache, a.stack_size)[a.first:]
    fmap, _ = for_lens(lens, compute=False)
    processed = [processed_stack(it.stack, a.first + k) for k, it in enumerate(items)] if a.processed else []
    classical = [stack_errors(classical_depth(it.stack, it.focus_m, fmap).depth_m, it.depth_m) for it in items]
    rows, unexportable = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for ck in tqdm(a.checkpoints, desc="checkpoints", file=sys.stderr):
            onnx = Path(tmp) / "net.onnx"
            try:
                export_checkpoint(ck, onnx, force=True)  # a scratch file of our own, replaced per checkpoint
            except RuntimeError as e:  # onnxruntime disagrees with torch: no file the runtime could ship
                if "differs from torch" not in str(e):  # any other failure is a failure
                    raise
                unexportable.append({"checkpoint": str(ck), "reason": str(e).split(": ", 1)[-1]})
                tqdm.write(f"{ck}: left out, not exportable ({unexportable[-1]['reason']})", file=sys.stderr)
                continue
            model = FocusMapModel(onnx, threads=a.threads, mapping=mapping_from_args(lens=lens))
            errs = []
            for it in items:
                bound = model.bound(model.mapping_optics(it.stack.shape[-1]), it.focus_m)
                errs.append(stack_errors(bound.infer(it.stack, it.focus_m, tile=0).depth_m, it.depth_m))
            perr = [stack_errors(model.bound(model.mapping_optics(it.stack.shape[-1]), it.focus_m)
                                 .infer(st, it.focus_m, tile=0).depth_m, it.depth_m) for it, st in zip(items, processed)]
            rows.append({"checkpoint": str(ck), "step": int(load(ck).get("step", -1)),
                         **{k: [e[k] for e in errs] for k in errs[0]},
                         **({f"processed_{k}": [e[k] for e in perr] for k in perr[0]} if perr else {})})
            r = rows[-1]
            tqdm.write(f"step {r['step']:6d}: MAE {np.mean(r['mae_m']):.3f} m, {np.mean(r['mae_d']):.3f} D, "
                       f"median stack {np.median(r['mae_m']):.3f} m"
                       + (f"; processed {np.mean(r['processed_mae_m']):.3f} m" if perr else ""), file=sys.stderr)
    cl = {k: [e[k] for e in classical] for k in classical[0]}
    write_text_atomic(a.out, json.dumps({"lens": "rf50", "split": "validation", "first": a.first, "n": len(items),
                                         "stack_size": len(items[0].focus_m),
                                         "classical_lens_map": cl, "rows": rows,
                                         **({"unexportable": unexportable} if unexportable else {})}, indent=1))
    print(f"classical, lens map: MAE {np.mean(cl['mae_m']):.3f} m, {np.mean(cl['mae_d']):.3f} D")
    print("| step | MAE (m) | MAE (D) | median stack MAE (m) |\n|---|---|---|---|")
    for r in sorted(rows, key=lambda r: r["step"]):
        print(f"| {r['step']} | {np.mean(r['mae_m']):.3f} | {np.mean(r['mae_d']):.3f} | {np.median(r['mae_m']):.3f} |")
    if a.paired and len(rows) > 1:
        from aat_deploy.eval.stats import fmt_interval, paired_ratio

        per = lambda v: [{"mae": x} for x in v]  # noqa: E731
        for r in rows[1:]:
            print(f"{r['checkpoint']} / {rows[0]['checkpoint']}, paired over the stacks: "
                  f"{fmt_interval(paired_ratio(per(r['mae_m']), per(rows[0]['mae_m'])))} (m), "
                  f"{fmt_interval(paired_ratio(per(r['mae_d']), per(rows[0]['mae_d'])))} (D)")
    if a.png:
        draw(rows, cl, a.png)
    return 0


def draw(rows: list[dict], classical: dict, png: Path, mark: int | None = None) -> None:
    """Mean MAE in m and in D over the steps, the classical method's as a line; `mark`: a step drawn as a vertical
    line (the chosen checkpoint)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aat_deploy.io.atomic import write_bytes_atomic

    rows = sorted(rows, key=lambda r: r["step"])
    steps = [r["step"] for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, key, unit in zip(axes, ("mae_m", "mae_d"), ("m", "D")):
        ax.plot(steps, [np.mean(r[key]) for r in rows], "o-", ms=3, label="net, whole frames")
        ax.axhline(np.mean(classical[key]), color="k", ls="--", lw=1, label="classical, lens map")
        if mark is not None:
            ax.axvline(mark, color="tab:red", lw=1, label=f"chosen: step {mark}")
        ax.set_xlabel("training step")
        ax.set_ylabel(f"MAE ({unit}), {len(rows[0][key])} RF50 validation stacks")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    write_bytes_atomic(png, buf.getvalue())


if __name__ == "__main__":
    sys.exit(main())
