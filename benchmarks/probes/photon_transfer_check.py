"""Does photon transfer on a capture's RAW mosaics (`aat_deploy/diagnose/photon.py`) find the full well the captures
were rendered with, and is the expected floor right at that full well? (issue 32, 2026-11-28; development scenes
only; docs/diagnosis.md, Limits, "The full well by photon transfer".)

- `--captures FOLDER...`: per capture, the photon-transfer full well and read noise from all its frames pooled and
  frame by frame (`fitters.full_well_by_photon_transfer` without the development's gain: it is 1.000 for the virtual
  camera), against `--rendered-e` (`aat-render --effects noise`'s default, 8000 e-, read noise 3 e-).
- `--floor QUIET NOISY`: the same scene rendered without and with noise (same optics, `make_sample_capture --effects
  vignetting` and the default): the developed noise (NOISY - QUIET, both developed as the runtime develops them),
  binned 4 x 4 as the focus fit bins, its Laplacian energy per region, frame and channel over the expected floor
  (`noisefloor.floor` at the rendered full well with `developed_factor`). 1 = the floor model is right at the truth.

    python -m benchmarks.probes.photon_transfer_check --captures cache/bench_diagnose_focus/captures/scene3303 \\
        --floor cache/p32/noise/scene3303quiet cache/p32/noise/scene3303n1001 --out results/photon_transfer_check.md
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic


def frames_of(folder: Path) -> list[Path]:
    return sorted(folder.glob("frame_*.dng"))


def capture_rows(folder: Path) -> list[str]:
    from aat_deploy.capture.raw import load_mosaic
    from aat_deploy.diagnose import photon

    per, pooled = [], []
    for f in frames_of(folder):
        planes = photon.cfa_planes(load_mosaic(f)[0])
        pooled += planes
        got = photon.photon_transfer(planes)
        per.append("-" if got is None else f"{got['full_well_e']:.0f}")
    got = photon.photon_transfer(pooled)
    if got is None:
        return [f"| {folder.name} | no estimate | | | |"]
    return [f"| {folder.name} | {got['full_well_e']:.0f} | {got['read_noise_e']:.1f} | {got['n_blocks']} | {', '.join(per)} |"]


def floor_ratio(quiet: Path, noisy: Path, full_well_e: float, b: int = 4) -> dict:
    import cv2

    from aat_deploy.capture.raw import load_raw
    from aat_deploy.diagnose import noisefloor
    from aat_deploy.diagnose.binned import bin_frames
    from aat_deploy.diagnose.compare import region_index
    from aat_deploy.diagnose.focusfit import FIT_GRID
    from aat_deploy.render.effects.noise import Noise
    from aat_deploy.render.effects.raw_pipeline import RawPipeline

    def dev(folder):
        return np.stack([load_raw(p)[0].transpose(2, 0, 1) for p in frames_of(folder)])

    q, n = dev(quiet), dev(noisy)
    qb = np.stack([bin_frames(f, b) for f in q])
    zb = np.stack([bin_frames(f, b) for f in n - q])
    noise = Noise(full_well_e=full_well_e)
    fac = noisefloor.developed_factor([noise, RawPipeline()], b)
    fl = noisefloor.floor(qb, 1.0, noise.binned(b), fac, FIT_GRID)
    s, c, h, w = zb.shape
    reg = region_index(h, w, FIT_GRID).ravel()
    cnt = np.bincount(reg, minlength=fl.shape[0])
    meas = np.empty_like(fl)
    for i in range(s):
        for j in range(c):
            lap = cv2.Laplacian(np.ascontiguousarray(zb[i, j], np.float32), cv2.CV_32F, ksize=3).astype(np.float64)
            meas[:, i, j] = np.bincount(reg, weights=(lap ** 2).ravel(), minlength=fl.shape[0]) / cnt
    r = meas / fl
    return {"median": float(np.median(r)), "per_channel": np.median(r, axis=(0, 1)).round(3).tolist(),
            "per_frame": np.median(r, axis=(0, 2)).round(3).tolist(), "p10_p90": np.percentile(r, [10, 90]).round(3).tolist()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--captures", type=Path, nargs="*", default=[], help="capture folders of DNG frames")
    ap.add_argument("--floor", type=Path, nargs=2, metavar=("QUIET", "NOISY"), help="the floor model's check")
    ap.add_argument("--rendered-e", type=float, default=8000.0, help="the full well the captures were rendered with")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    for f in [*a.captures, *(a.floor or [])]:
        if not frames_of(f):
            ap.error(f"{f}: no frame_*.dng")
    lines = [f"rendered: {a.rendered_e:.0f} e-, read noise 3 e-", "",
             "| capture | full well (e-), all frames | read noise (e-) | flat blocks | full well per frame |",
             "|---|---|---|---|---|"]
    for f in a.captures:
        lines += capture_rows(f)
    if a.floor:
        r = floor_ratio(*a.floor, a.rendered_e)
        lines += ["", f"developed binned noise energy over the expected floor at {a.rendered_e:.0f} e- "
                      f"({a.floor[0].name} vs {a.floor[1].name}): median {r['median']:.3f}, per channel "
                      f"{r['per_channel']}, per frame {r['per_frame']}, 10-90 % {r['p10_p90']}"]
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        write_text_atomic(a.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
