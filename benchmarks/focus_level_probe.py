"""Why a frame that shows nothing in focus is not determined (issue 32, scene 2027's nearest frame): per frame of a
benchmark set of `bench_diagnose_focus`, the first round's robust focus sweep (binned, re-anchored, floors and
weights as the diagnosis fits them), and

- `err`: the per-frame estimate's error against the truth (diopters);
- `k`: its level sensitivity (`focusfit.level_sensitivity`, diopters per log unit, signed: how far a misfit of the
  twin's level in that frame, alike in all its regions, moves the estimate);
- `level`: that misfit at the truth (the weighted mean over regions of the capture's curve less the twin's at the
  true focus, each region's level over the frames removed; log units);
- `k x level`: the error the level misfit alone would cause (to first order);
- `sys`: the frame's systematic error (`focusfit.frame_systematic`).

    python -m benchmarks.focus_level_probe scene2027:offset_+0.05 scene2029:offset_+0.05 [--threads 1]

Captures as `bench_diagnose_focus` makes them (its --cache); the tuning capture scene2029 by name too.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from benchmarks import bench_diagnose_focus as bench


def prepared_sweep(folder, kind: str, index: int, model, lens, src, threads: int, chain: list = (),
                   noise_floor: bool | None = None):
    """The set's capture (`CaptureData`), the first round's sweep (re-anchored, as `fitters.fit_focus_metadata`
    fits it) before and after `focusrobust.prepare`, and the frames' true and reported focus (diopters, near to
    far). chain: effects in the twin (the first round's twin has none; a later round's, those named before).
    noise_floor: the twin's noise by its expectation (`noisefloor`; None: as the fit, `fitters.NOISE_FLOOR`)."""
    from aat_deploy.diagnose import anchors, fitters, focusrobust
    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.search import DiagnoseConfig
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.render import effects as fx

    true_m = np.asarray(json.loads((folder / "virtual_camera.json").read_text())["focus_m"], np.float64)
    true_d = 1.0 / np.sort(true_m)
    rep = bench.reported_d(kind, true_d, index)
    root = bench.make_copy(folder, bench.CACHE / "sets" / folder.name / kind, 1.0 / rep)
    twins = make_renderer(model, lens, src, torch_free=True, threads=threads)
    data = [load_capture_data(root / folder.name, model)]
    cfg = DiagnoseConfig()
    factor = max(1, min(8, data[0].frames.shape[-1] // cfg.search_px))
    full = [fitters.fit_curves(twins.render(c, c.aif_linear, list(chain), seed=cfg.seed + i), factor)
            for i, c in enumerate(data)]
    state = fitters.FitState(twins, data, [c.aif_linear for c in data], list(chain), fx.make, factor, cfg.fit_boot,
                             cfg.seed, {}, full)
    # the sweep `fitters.fit_focus_metadata` fits (re-anchored at the estimates), made robust as it is
    sweep, _ = anchors.reanchored_sweep(state, fitters.focus_sweep(
        state, correct=False, noise_floor=fitters.NOISE_FLOOR if noise_floor is None else noise_floor),
                                        lambda d: np.asarray(focusrobust.prepare(d)[1]["frame_focus_d"][-1]))
    prepared, _ = focusrobust.prepare(sweep)
    return data[0], sweep, prepared, true_d, rep


def probe(folder, kind: str, index: int, model, lens, src, threads: int) -> None:
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose import focusrobust

    _, _, prepared, true_d, _ = prepared_sweep(folder, kind, index, model, lens, src, threads)
    est = ff.frame_focus(prepared)
    k = ff.level_sensitivity(prepared, est)[0]
    res = prepared.capture - focusrobust.twin_at(prepared, true_d[None])
    res = res - res.mean(-1, keepdims=True)
    w = prepared.weight[..., None]
    level = ((w * res).sum(1) / w.sum(1))[0]
    sys_d = ff.frame_systematic(prepared, est)[0]
    peaks = prepared.grid_d[prepared.twin[0].argmax(-1)]
    print(f"\n{folder.name} {kind}: regions' twin curves peak at {np.quantile(peaks, 0.1):.2f}-"
          f"{np.quantile(peaks, 0.9):.2f} D (10-90 %), frames at {true_d.min():.2f}-{true_d.max():.2f} D\n")
    print("| frame | true focus (D) | err (D) | k (D per log unit) | level at the truth (log) | k x level (D) | "
          "sys (D) |")
    print("|---|---|---|---|---|---|---|")
    for f in range(len(true_d)):
        print(f"| {f} | {true_d[f]:.3f} | {est[0, f] - true_d[f]:+.3f} | {k[f]:+.2f} | {level[f]:+.3f} | "
              f"{k[f] * level[f]:+.3f} | {sys_d[f]:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sets", nargs="+", help="capture:kind, e.g. scene2027:offset_+0.05 (captures: sample_rf50, "
                    "scene2027, scene2028, scene2029)")
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.infer.model import DfFModel

    model = DfFModel(str(bench.ROOT / "models" / "rf50_dfvnet_aat_field.onnx"), threads=a.threads)
    lens, _ = find_lens(model, None)
    src = find_surrogate(lens, None, a.threads)
    for spec in a.sets:
        index, folder, kind = set_spec(spec)
        probe(folder, kind, index, model, lens, src, a.threads)


def set_spec(spec: str):
    """capture:kind -> (the capture's index as the benchmark numbers it, its folder, kind): the benchmark's
    captures, the tuning capture scene2029 (run alone: index 0) and the fresh test captures (index in --fresh)."""
    folders = {f"scene{s}": (0, bench.CACHE / "captures" / f"scene{s}") for s in (2029,)}
    folders.update({f"scene{s}": (k, bench.CACHE / "captures" / f"scene{s}")
                    for k, (s, _) in enumerate(bench.FRESH_SCENES)})
    folders.update({f.name: (k, f) for k, f in enumerate(bench.capture_folders(3, bench.CACHE))})
    name, _, kind = spec.partition(":")
    if name not in folders or kind not in bench.kinds() or not folders[name][1].exists():
        raise SystemExit(f"{spec}: unknown or unrendered capture, or unknown kind (captures "
                         f"{', '.join(folders)}; kinds {', '.join(bench.kinds())})")
    return folders[name][0], folders[name][1], kind


if __name__ == "__main__":
    main()
