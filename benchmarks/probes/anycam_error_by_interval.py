"""Where an any-camera net's error in metres comes from on few-frame stacks: by the frame interval the truth lies in
(exploratory; RF50 validation stacks only).

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_error_by_interval CHECKPOINT [CHECKPOINT ...]
        --stack-size 3 [--first 12] [--n 12] [--threads 1] --out OUT.json

With 3 frames over 0.5-10 m (2, 1.05 and 0.1 D) the far interval, 0.95-10 m, holds depths where a small error in
diopters is metres. Per checkpoint (and for the classical method with the same lens map) this splits the summed
absolute error (m) over the pixels with truth by the interval of the sweep's nominal focus diopters the truth lies in
(nearer than the first frame, between frames k and k+1, farther than the last), and gives each interval's MAE in metres
and in diopters and its share of pixels. Validation stacks only (training photographs): no held-out lens or test scene.
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


def by_interval(depth_m: np.ndarray, truth_m: np.ndarray, focus_m: np.ndarray) -> list[dict]:
    """depth_m, truth_m (H, W) metres; focus_m (S,) the frames' nominal focus distances (m). Pixels with truth (> 0)
    split by where 1/truth lies among the frames' diopters: interval 0 nearer than the nearest frame, k between the
    k-th and (k+1)-th frames from the near end, S farther than the farthest. Per interval: pixels, summed |error| (m),
    summed |error| (D)."""
    ok = truth_m > 0
    d, t = depth_m[ok].astype(np.float64), truth_m[ok].astype(np.float64)
    fd = np.sort(1.0 / np.asarray(focus_m, np.float64))[::-1]  # near -> far: diopters descending
    k = np.searchsorted(-fd, -1.0 / t, side="left")  # how many frames are nearer than the truth
    e_m, e_d = np.abs(d - t), np.abs(1.0 / d - 1.0 / t)
    return [{"pixels": int((k == i).sum()), "abs_m": float(e_m[k == i].sum()), "abs_d": float(e_d[k == i].sum())}
            for i in range(len(fd) + 1)]


def summarise(per_stack: list[list[dict]]) -> list[dict]:
    """Per interval over the stacks: share of pixels, share of the summed |error| (m), MAE (m), MAE (D)."""
    n = len(per_stack[0])
    px = np.array([[s[i]["pixels"] for i in range(n)] for s in per_stack], float).sum(0)
    am = np.array([[s[i]["abs_m"] for i in range(n)] for s in per_stack]).sum(0)
    ad = np.array([[s[i]["abs_d"] for i in range(n)] for s in per_stack]).sum(0)
    safe = np.maximum(px, 1)
    return [{"pixel_share": float(px[i] / px.sum()), "error_share_m": float(am[i] / am.sum()),
             "mae_m": float(am[i] / safe[i]), "mae_d": float(ad[i] / safe[i])} for i in range(n)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoints", type=Path, nargs="+", help="runs' model.pt, last.pt or kept step_NNNNN.pt")
    ap.add_argument("--stack-size", type=int, required=True, help="frames per stack (2 to 32)")
    ap.add_argument("--first", type=int, default=12, help="the first RF50 validation stack (default the choosing 12)")
    ap.add_argument("--n", type=int, default=12, help="stacks")
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"), help="where the stacks are cached")
    ap.add_argument("--threads", type=int, default=1, help="onnxruntime threads")
    ap.add_argument("--out", type=Path, required=True, help="JSON of the split per checkpoint and the classical one")
    a = ap.parse_args(argv)
    if not 2 <= a.stack_size <= 32 or a.n < 1 or a.first < 0:
        ap.error(f"--stack-size 2 to 32, --n at least 1, --first 0 or more; got {a.stack_size}, {a.n}, {a.first}")
    refuse_missing_or_existing(ap, a.checkpoints, a.out)

    from aat_deploy.anycam.model import FocusMapModel, mapping_from_args
    from aat_deploy.focus import classical_depth
    from aat_deploy.focus.bestfocus import for_lens
    from aat_deploy.io.atomic import write_text_atomic
    from benchmarks.bench_anycam import LENSES
    from training.train.export import export_checkpoint

    lens = ROOT / LENSES["rf50"]["lens"]
    items = fixed_stacks("rf50", "validation", a.first + a.n, a.cache, a.stack_size)[a.first:]
    fmap, _ = for_lens(lens, compute=False)
    out = {"lens": "rf50", "split": "validation", "first": a.first, "n": len(items), "stack_size": a.stack_size,
           "frames_m": [float(f) for f in np.sort(items[0].focus_m)],
           "classical_lens_map": summarise([by_interval(classical_depth(it.stack, it.focus_m, fmap).depth_m,
                                                        it.depth_m, it.focus_m) for it in items]), "rows": []}
    with tempfile.TemporaryDirectory() as tmp:
        for ck in a.checkpoints:
            onnx = Path(tmp) / "net.onnx"
            export_checkpoint(ck, onnx, force=True)  # a scratch file of our own, replaced per checkpoint
            model = FocusMapModel(onnx, threads=a.threads, mapping=mapping_from_args(lens=lens))
            per = [by_interval(model.bound(model.mapping_optics(it.stack.shape[-1]), it.focus_m)
                               .infer(it.stack, it.focus_m, tile=0).depth_m, it.depth_m, it.focus_m) for it in items]
            out["rows"].append({"checkpoint": str(ck), "intervals": summarise(per)})
    write_text_atomic(a.out, json.dumps(out, indent=1))
    near = [f"{f:.2f}" for f in out["frames_m"]]
    print(f"frames at {', '.join(near)} m; intervals from the near end: pixel share / error share (m) / MAE m / MAE D")
    for name, s in [("classical, lens map", out["classical_lens_map"])] + [(r["checkpoint"], r["intervals"])
                                                                         for r in out["rows"]]:
        print(f"{name}: " + "; ".join(f"{v['pixel_share']:.2f} / {v['error_share_m']:.2f} / {v['mae_m']:.2f} / "
                                      f"{v['mae_d']:.3f}" for v in s))
    return 0


if __name__ == "__main__":
    sys.exit(main())
