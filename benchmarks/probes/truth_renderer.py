"""The phone's tile bias: the renderer the chart sweeps use against the one the truth was calibrated with
(issue 33, part a; `truth_texture` holds the texture part).

    OMP_NUM_THREADS=1 python -m benchmarks.probes.truth_renderer [--distances-m 0.07,0.1,0.18] \
        [--renderers sim32,shoot64,shoot32] [--out results/truth_renderer.json]

A flat plane square to the camera, covered in the chart's softened dead leaves (`truth_texture._leaves`), at Z,
through the nominal phone lens with no noise, in a sweep of frames 1/Z - 2.75 .. 1/Z + 6.05 D in 0.55 D steps;
each of the fit's 27 px tiles (`peaks.tile_peaks`, the runtime's measure and `gauss` estimator) peaks at F_peak, and
its bias is 1/Z minus the truth's in-focus object at its field radius for the frame F_peak (the nominal lens: the
best-focus map, lenses/best_focus/cellphone_asphere.json), as the tiles' bias is defined. Renderers:
`sim32` the truth's (`training.render.simulator.Simulator`, 32 px PSF cells, as
`training.render.focus_calibration` renders the truth's photographs); `shoot64` the chart sweeps' (the virtual
camera, `aat_deploy.capture.virtual.shoot`, 64 px cells, bench_calibrate's `cell_px`); `shoot32` the same at 32 px.
No scene, held-out or not, is rendered.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic
from benchmarks import RESULTS

EDGES = (0.0, 0.33, 0.5, 0.66, 0.75, 0.84, 0.93)


def render(name: str, lens, rgb: np.ndarray, z: float, focus_m: np.ndarray, psf: Path | None) -> np.ndarray:
    """(S, 3, H, W) float32 linear frames of the plane at z (m) by renderer `name`; psf None (`shoot` only): the
    thin-lens Gaussian, focusing paraxially (an ideal lens, for tests)."""
    h, w = rgb.shape[1:]
    if name.startswith("shoot"):
        from aat_deploy.capture.virtual import shoot
        from aat_deploy.render.sources import OnnxSource

        src = OnnxSource(psf, lens, threads=1) if psf is not None else None
        fr, _ = shoot(lens, rgb, np.full((h, w), z, np.float32), focus_m, [], src, seed=0, workers=1,
                      cell_px=int(name[5:]))
        return fr
    if name.startswith("sim"):
        import torch

        from aat_deploy.render import effects as fx
        from training.render.layered import LayeredConfig
        from training.render.simulator import Simulator
        from training.render.sources import OnnxPSF

        sim = Simulator(lens, OnnxPSF(str(psf), lens, threads=1), fx.parse(["aberrations"]),
                        LayeredConfig(cell_px=int(name[3:])))
        st = sim.render_stack(torch.from_numpy(rgb), torch.full((h, w), z), focus_m, origin=(0, 0))
        return st.frames.numpy()
    raise SystemExit(f"unknown renderer {name!r}: sim32, shoot64, shoot32")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--distances-m", default="0.07,0.1,0.18")
    ap.add_argument("--renderers", default="sim32,shoot64,shoot32")
    ap.add_argument("--textures", default="leaves,photos", help="leaves: the chart's; photos: the truth's (a mosaic)")
    ap.add_argument("--seeds", default="7,8", help="texture draws")
    ap.add_argument("--out", default=str(RESULTS / "truth_renderer.json"))
    a = ap.parse_args(argv)
    if Path(a.out).exists():  # a committed result is never overwritten
        ap.error(f"{a.out}: exists (choose another --out)")
    from aat_deploy.calibrate.format import field_radius_of
    from aat_deploy.calibrate.peaks import TileGrid, tile_peaks
    from aat_deploy.focus.bestfocus import load_json
    from aat_deploy.lens.io import load_lens
    from benchmarks.probes.truth_texture import _leaves

    root = Path(__file__).resolve().parents[2]
    lens = load_lens(root / "lenses" / "cellphone_asphere.json")
    fmap = load_json(root / "lenses" / "best_focus" / "cellphone_asphere.json")
    psf = root / fmap.notes["calibration"]["psf"]
    h, w = lens.sensor.height_px, lens.sensor.width_px
    grid = TileGrid(h, w, max(1, w // 24))
    fx, fy = grid.field()
    rad = field_radius_of(fx, fy, w / h)
    out = {"what": __doc__.split("\n")[0], "rows": {}}
    from benchmarks.probes.chart_texture import photo_mosaic

    for z, name, tname in ((float(v), n, t) for v in a.distances_m.split(",") for n in a.renderers.split(",")
                           for t in a.textures.split(",")):
        fd = 1.0 / z + np.arange(-2.75, 6.05 + 1e-9, 0.55)
        biases = []
        for seed in (int(v) for v in a.seeds.split(",")):
            rng = np.random.default_rng(seed)
            tex = (_leaves(max(h, w), rng, False)[:h, :w] if tname == "leaves" else photo_mosaic(h, w, rng))
            rgb = np.ascontiguousarray(np.repeat(tex[None], 3, 0) * 0.6, np.float32)
            fr = render(name, lens, rgb, z, 1.0 / fd, psf)
            pk = tile_peaks(fr, fd, grid, np.ones(grid.shape, bool))
            ok = pk.counted
            truth = np.full(grid.shape, np.nan)
            truth[ok] = [float(fmap.frame_diopters([1.0 / p], [r], calibrated=True)[0, 0])
                         for p, r in zip(pk.peak_d[ok], rad[ok])]
            biases.append(1.0 / z - truth)
        bias = np.stack(biases)
        ok = np.isfinite(bias)
        row = {}
        for lo, hi in zip(EDGES[:-1], EDGES[1:]):
            m = ok & ((rad >= lo) & (rad < hi))[None]
            if m.sum() > 3:
                row[f"{lo:g}-{hi:g}"] = {"n": int(m.sum()), "mean_d": float(np.mean(bias[m])),
                                         "sd_d": float(np.std(bias[m]))}
        out["rows"][f"{name} {tname} z={z:g}"] = row
        print(f"{name:8s} {tname:6s} z {z:g} m: " + " ".join(f"{k} {v['mean_d']:+.3f}" for k, v in row.items()),
              flush=True)
    write_text_atomic(a.out, json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
