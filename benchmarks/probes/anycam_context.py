"""Does the any-camera net fail on whole frames because of its image-wide context? (exploratory, validation only)

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.probes.anycam_context CHECKPOINT --windows 0,7,15 --out DIR
        [--tiles 0,128] [--n 12] [--threads 1] [--cache cache/heldout]

The nets so far are worse the larger the image they run on (docs/training.md): 128 px tiles beat whole frames by
3x. Their only image-wide operation is the context module's global mean at /32 (training.nets.dfvnet.PyramidPool2d):
on a 128-256 px training image it averages 4-8 feature pixels per side, on a 960 x 640 frame 30 x 20, a mix of
far-apart content the net never saw. This probe exports the checkpoint once per --windows value (0 = the global
mean as trained; K = a K x K window at /32, which equals the global mean on images up to (K + 1) / 2 feature pixels:
K = 7 on 128 px, 15 on 256 px) to DIR/<checkpoint>_ctx<K>.onnx (the export's ORT-vs-torch parity check included)
and runs each through `benchmarks.probes.anycam_tiles` on the RF50's validation stacks (training photographs, their
own seed): whole frames and the given tiles. It may choose the window; the held-out lenses and test scenes do not.
"""

from __future__ import annotations

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def export_with_window(checkpoint: Path, out: Path, window: int, force: bool = False) -> Path:
    """checkpoint -> out/<stem>_ctx<window>.onnx, the encoder's context mean over `window` /32 pixels (0: global)."""
    from training.nets.dfvnet import PyramidPool2d
    from training.train.export import export_checkpoint

    dst = out / f"{checkpoint.stem}_ctx{window}.onnx"
    if dst.exists() and not force:
        return dst
    # export_checkpoint builds the net from the checkpoint itself: set the window on the class for its duration
    before = PyramidPool2d.global_window
    PyramidPool2d.global_window = window or None
    try:
        md, err = export_checkpoint(checkpoint, dst, force=force, extra={"context_window": str(window)})
    finally:
        PyramidPool2d.global_window = before
    print(f"{dst}: ORT vs torch {err:.2e} relative", flush=True)
    return dst


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoint", type=Path, help="a run's model.pt or last.pt")
    ap.add_argument("--windows", default="0,7,15", help="context windows at /32 (feature px, odd; 0 = global)")
    ap.add_argument("--out", type=Path, required=True, help="folder for the exported .onnx files")
    ap.add_argument("--tiles", default="0,128", help="as anycam_tiles --tiles")
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--cache", default=str(ROOT / "cache" / "heldout"))
    ap.add_argument("--force", action="store_true", help="export again over existing files")
    a = ap.parse_args(argv)
    windows = [int(w) for w in a.windows.split(",")]
    bad = [w for w in windows if w < 0 or (w and w % 2 == 0)]
    if bad:
        ap.error(f"--windows: odd positive sizes or 0, got {bad}")
    if not a.checkpoint.is_file():
        ap.error(f"{a.checkpoint}: no such checkpoint")
    a.out.mkdir(parents=True, exist_ok=True)
    from benchmarks.probes import anycam_tiles

    for w in windows:
        model = export_with_window(a.checkpoint, a.out, w, a.force)
        anycam_tiles.main(["--model", str(model), "--lens", "rf50", "--split", "validation", "--n", str(a.n),
                           "--tiles", a.tiles, "--threads", str(a.threads), "--cache", a.cache,
                           "--json", str(model.with_suffix(".json"))])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
