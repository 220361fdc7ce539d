"""How many validation pixels an any-camera checkpoint places at or past infinity (exploratory; chooses nothing).

    python -m benchmarks.probes.anycam_past_infinity CONFIG.json CHECKPOINT [CHECKPOINT ...] [--items 64]

Over the config's validation items (training photographs, its own seed), the share of pixels whose interpolated
diopters sit at the head's 1 km clamp (`training.nets.dfvaat.MIN_DIOPTERS`), and of those placed farther than 1.5x
their farthest frame's in-focus distance. An interpolating head can do neither; an extrapolating one
(`EndExtrapolation`) can, and each such pixel costs up to a kilometre in a metric MAE.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def counts(diopters, depth_m, focus_diopters, min_diopters: float) -> tuple[int, int, int]:
    """(pixels at or past the clamp, pixels beyond 1.5x the farthest frame's distance, pixels) of one item:
    diopters, depth_m (H, W), focus_diopters (S, H, W) tensors."""
    far_m = 1.0 / focus_diopters.min(0).values.clamp_min(min_diopters)
    return (int((diopters <= min_diopters * 1.01).sum()), int((depth_m > 1.5 * far_m).sum()), diopters.numel())


def main(argv: list[str] | None = None) -> int:
    import torch

    from training.nets.dfvaat import MIN_DIOPTERS, predict
    from training.train.data import make_dataset
    from training.train.loop import load_trained

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("config", type=Path)
    ap.add_argument("checkpoints", type=Path, nargs="+")
    ap.add_argument("--items", type=int, default=64)
    a = ap.parse_args(argv)
    cfg = json.loads(a.config.read_text())
    val = make_dataset(cfg["val_data"], cfg["simulator"], cfg["lens"])
    print("| checkpoint | at or past infinity | beyond 1.5x the far frame | pixels |\n|---|---|---|---|")
    for ck in a.checkpoints:
        model, _ = load_trained(ck)
        model.eval()
        tot = [0, 0, 0]
        with torch.no_grad():
            for i in range(min(a.items, len(val))):
                it = val[i]
                out = predict(model, it["stack"][None].float(), it["focus_diopters"][None].float(),
                              it["defocus_px_per_d"][None].float())
                c = counts(out["diopters"][0], out["depth_m"][0], it["focus_diopters"].float(), MIN_DIOPTERS)
                tot = [t + x for t, x in zip(tot, c)]
        print(f"| {ck} | {tot[0]} ({tot[0] / tot[2]:.2%}) | {tot[1]} ({tot[1] / tot[2]:.2%}) | {tot[2]} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
