"""Does the binned focus sweep carry the capture's developed noise? (issue 32, scene 2038; `noisefloor`).
Understanding only: it chooses nothing.

Per `bench_diagnose_focus` set and twin chain (e.g. noise,vignetting,raw_pipeline), at the twin's own frames
(the set's reported focus: for the untouched copy the truth), per frame, the median over the textured regions of
each curve less the capture's (log units; every region's level over the frames removed first, as the fit does):
- `full drawn`: the full-resolution twin with a noise draw and the development, binned (what the binning
  correction anchors on);
- `sweep, expected floor`: the binned sweep with the noise by its expectation (`noisefloor`), corrected at the
  anchors (`anchors.reanchored_sweep`'s first anchors), at the frames;
- `sweep, binned draw`: the binned sweep with the binned sensor's noise draw (`Noise.binned`), corrected alike;
and the share of each frame's expected measure that is floor (median region).

    python -m benchmarks.probes.focus_noise_floor scene2038:none --chain noise,vignetting,raw_pipeline
"""

from __future__ import annotations

import argparse
import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

from benchmarks import bench_diagnose_focus as bench
from benchmarks.probes.focus_scene_coverage import set_spec


def report(spec: str, chain: str, threads: int) -> str:
    from aat_deploy.diagnose import anchors, fitters
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose import focusrobust as fr
    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.diagnose.search import DiagnoseConfig
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.render import effects as fx

    index, folder, kind = set_spec(spec)
    model = DfFModel(str(bench.ROOT / "models" / "rf50_dfvnet_aat_field.onnx"), threads=threads)
    lens, _ = find_lens(model, None)
    src = find_surrogate(lens, None, threads)
    true_m = np.asarray(json.loads((folder / "virtual_camera.json").read_text())["focus_m"], np.float64)
    rep = bench.reported_d(kind, 1.0 / np.sort(true_m), index)
    root = bench.make_copy(folder, bench.CACHE / "sets" / folder.name / kind, 1.0 / rep)
    twins = make_renderer(model, lens, src, torch_free=True, threads=threads)
    data = [load_capture_data(root / folder.name, model)]
    cfg = DiagnoseConfig()
    factor = max(1, min(8, data[0].frames.shape[-1] // cfg.search_px))
    effects = fx.parse(chain.split(","))
    full = [fitters.fit_curves(twins.render(c, c.aif_linear, effects, seed=cfg.seed + i), factor)
            for i, c in enumerate(data)]
    state = fitters.FitState(twins, data, [c.aif_linear for c in data], effects, fx.make, factor, cfg.fit_boot,
                             cfg.seed, {}, full)
    own = np.asarray(1.0 / state.twins.true_focus(data[0], effects, cfg.seed), np.float64)[None]

    def at_frames(sweep):
        chain_ = [e for e in state.chain if not state.tb.has_stack_hook(e)]
        if sweep.floor_c is not None:
            from aat_deploy.diagnose import noisefloor

            chain_ = noisefloor.quiet(chain_)
        a = [[x] for x in anchors.anchor_deltas(state, chain_, [1.0 / own[0]])]
        s = sweep.with_correction(anchors.correction(sweep.grid_d, a))
        return fr.twin_at(s, own), s

    expected, s_exp = at_frames(fitters.focus_sweep(state, correct=False, noise_floor=True))
    drawn, _ = at_frames(fitters.focus_sweep(state, correct=False, noise_floor=False))
    cap = s_exp.capture
    used = s_exp.weight[0] > 0

    def rel(x):
        d = (x - cap)[0]
        d = d - d.mean(-1, keepdims=True)
        return np.median(d[used], 0)

    share = None
    if s_exp.floor_c is not None:
        fl = ff.SweepData(s_exp.grid_d, np.log(s_exp.floor_c.mean(-1)), s_exp.capture, s_exp.reported_d,
                          s_exp.base_d, s_exp.field_xy)
        share = np.median(np.exp(fr.twin_at(fl, own) - expected)[0][used], 0)
    out = io.StringIO()
    with redirect_stdout(out):
        print(f"\n### {spec}, the twin with {chain}\n")
        print("| frame | focus (D) | full drawn - capture | sweep, expected floor - capture | sweep, binned draw - capture "
              "| floor share (median region) |")
        print("|---|---|---|---|---|---|")
        for f, (a, b, c) in enumerate(zip(rel(full[0][None]), rel(expected), rel(drawn))):
            sh = f"{100 * share[f]:.0f} %" if share is not None else "-"
            print(f"| {f} | {own[0, f]:.3f} | {a:+.3f} | {b:+.3f} | {c:+.3f} | {sh} |")
    return out.getvalue()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sets", nargs="+", help="capture:kind, e.g. scene2038:none")
    ap.add_argument("--chain", default="noise,vignetting,raw_pipeline")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", help="also write the output here (markdown)")
    a = ap.parse_args()
    text = "".join(report(s, a.chain, a.threads) for s in a.sets)
    print(text, end="")
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(Path(a.out), "# Does the binned focus sweep carry the capture's developed noise? (issue 32)\n\n"
                          f"`python -m benchmarks.probes.focus_noise_floor {' '.join(a.sets)} --chain {a.chain}`\n"
                          + text)


if __name__ == "__main__":
    main()
