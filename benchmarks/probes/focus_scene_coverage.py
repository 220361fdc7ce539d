"""Why a scene's per-frame focus estimates are compressed towards the middle of the stack (issue 32, scene 2038:
every set's estimates share -0.071 D at the nearest frame ... +0.034 D at the farthest). Understanding only: it
chooses nothing.

Per `bench_diagnose_focus` set, on the first round's sweep as the focus fit reads it (re-anchored; exposure, floors
and weights as `focusrobust.prepare` makes them: `focus_level_probe.prepared_sweep`):
- the scene's depth against the stack: the ground truth's inverse depth (5-95 %), where the regions' twin curves
  peak, and per frame how far (diopters) the frame's focus is from the nearest content and the share of regions it
  sees from one side of focus;
- the per-frame estimates: as the fit makes them (floors <-> focus alternated from the reported focus), the same
  with the floors on a 5 times finer grid, with the floors fitted at the truth and held (the fit never knows it),
  and with no floors; the error over the frame's level sensitivity (the level misfit it reads, log units);
- the frames' level misfit at the truth with the floors fitted there (capture less floored twin, each region's
  level over the frames removed, weighted mean over regions; log units) and the error it alone explains (times the
  frame's level sensitivity, `focusfit.level_sensitivity`);
- the capture's excess over the unfloored twin at the truth against the frame's defocus from each region's
  content: a noise floor is a constant in linear units (the excess grows as the twin falls, as log(1 + e^(b - t)));
  a tail the twin's blur gets wrong is not.

The sweeps are cached (npz, --cache) so the analysis reruns without rendering.

    python -m benchmarks.probes.focus_scene_coverage scene2038:none scene2039:none [--out results/...md]
    python -m benchmarks.probes.focus_scene_coverage scene2038_nonoise:none --chain none vignetting raw_pipeline \
        vignetting,raw_pipeline          # after `make_sample_capture.py --effects vignetting` into scene2038_nonoise
    python -m benchmarks.probes.focus_scene_coverage ... --nuisance RESULTS.jsonl ...   # a fix tried on stored fits
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np

from benchmarks import bench_diagnose_focus as bench
from benchmarks import focus_level_probe as flp

SWEEP_CACHE = bench.CACHE / "probe_sweeps"
FIELDS = ("grid_d", "twin", "capture", "reported_d", "base_d", "field_xy", "weight", "capture_lum", "twin_lum")


def set_spec(spec: str):
    """capture:kind -> (the capture's index as the benchmark numbers it, its folder, kind) for the rendered
    captures of the cache (the tuning capture 2029 and the fresh sets; nothing is rendered here)."""
    idx = {2029: 0}
    for group in (bench.FRESH_SCENES, bench.FRESH_SCENES_2, bench.FRESH_SCENES_3,
                  getattr(bench, "FRESH_SCENES_4", ())):
        idx.update({s: k for k, (s, _) in enumerate(group)})
    name, _, kind = spec.partition(":")
    # a variant of a capture (e.g. scene2038_nonoise: `make_sample_capture.py --effects vignetting`) keeps its index
    stem = name.split("_")[0]
    scene = int(stem[5:]) if stem.startswith("scene") and stem[5:].isdigit() else None
    folder = bench.CACHE / "captures" / name
    if scene not in idx or kind not in bench.kinds() or not (folder / "virtual_camera.json").exists():
        raise SystemExit(f"{spec}: unknown or unrendered capture, or unknown kind")
    return idx[scene], folder, kind


def sweep_of(spec: str, cache: Path, threads: int, chain: str = "", noise_floor: bool = False):
    """(the reanchored sweep before `prepare`, true_d, reported_d, gt inverse depth per region (R, 3)), cached.
    chain: effects in the twin (comma-separated; the first round's twin has none). noise_floor: its noise by its
    expectation (`noisefloor`), cached apart."""
    from aat_deploy.diagnose import focusfit as ff

    index, folder, kind = set_spec(spec)
    floor = "__floor" if noise_floor and "noise" in [c.split(":")[0] for c in chain.split(",")] else ""
    path = cache / f"{spec.replace(':', '_')}{'__' + chain.replace(',', '_').replace(':', '_') if chain else ''}{floor}.npz"
    if not path.exists():
        from aat_deploy.diagnose.compare import region_index
        from aat_deploy.diagnose.lookup import find_lens, find_surrogate
        from aat_deploy.infer.model import DfFModel

        model = DfFModel(str(bench.ROOT / "models" / "rf50_dfvnet_aat_field.onnx"), threads=threads)
        lens, _ = find_lens(model, None)
        src = find_surrogate(lens, None, threads)
        from aat_deploy.render import effects as fx

        effects = fx.parse(chain.split(",")) if chain else []
        cap, sweep, _, true_d, rep = flp.prepared_sweep(folder, kind, index, model, lens, src, threads, effects,
                                                        noise_floor)
        h, w = cap.gt_m.shape
        reg = region_index(h, w, ff.FIT_GRID)
        inv = 1.0 / cap.gt_m
        q = np.array([np.nanquantile(inv[reg == r], (0.1, 0.5, 0.9)) for r in range(ff.FIT_GRID[0] * ff.FIT_GRID[1])])
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(path, true_d=true_d, rep=rep, gt_q=q, gt_all=np.quantile(inv, (0.05, 0.5, 0.95)),
                 **{k: getattr(sweep, k) for k in FIELDS if getattr(sweep, k) is not None})
    z = np.load(path)
    sweep = ff.SweepData(**{k: z[k] for k in FIELDS if k in z.files})
    return sweep, z["true_d"], z["rep"], z["gt_q"], z["gt_all"]


def estimates(sweep, true_d: np.ndarray) -> dict:
    """Per-frame estimates (1, S): as the fit makes them, with floors fitted at the truth and held, without floors."""
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose import focusrobust as fr

    prepared, rep = fr.prepare(sweep)
    g = fr.frame_gains_log(sweep)
    base = dataclasses.replace(sweep, capture=sweep.capture - 2.0 * g[:, None, :])
    t = true_d[None]
    at_truth = fr.floored(base, fr.fit_floors(base, t))
    # the same alternation with the floors on a 5 times finer grid (0.1 log, to 12 below the top): is the 0.5-log grid's
    # rounding what the frames read?
    fine = np.arange(0.1, 12.01, 0.1)
    old = fr.fit_floors.__defaults__
    fr.fit_floors.__defaults__ = (fine,)
    try:
        _, rep_fine = fr.prepare(sweep)
    finally:
        fr.fit_floors.__defaults__ = old
    return {"fit": np.asarray(rep["frame_focus_d"][-1]), "fine floors": np.asarray(rep_fine["frame_focus_d"][-1]),
            "floors at the truth, held": ff.frame_focus(at_truth, start=t),
            "no floors": ff.frame_focus(base, start=t), "_prepared": prepared, "_at_truth": at_truth, "_base": base}


def report(spec: str, cache: Path, threads: int, chain: str = "", noise_floor: bool = False) -> str:
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose import focusrobust as fr

    sweep, true_d, rep, gt_q, gt_all = sweep_of(spec, cache, threads, chain, noise_floor)
    est = estimates(sweep, true_d)
    base, at_truth = est["_base"], est["_at_truth"]
    used = sweep.weight[0] > 0
    peaks = sweep.grid_d[sweep.twin[0].argmax(-1)]
    out = io.StringIO()
    with redirect_stdout(out):
        floor = (", its noise by its expectation (`noisefloor`)"
                 if noise_floor and "noise" in [c.split(":")[0] for c in chain.split(",")] else "")
        print(f"\n### {spec}{f' (the twin with {chain}{floor})' if chain else ''}\n")
        print(f"- ground truth inverse depth 5/50/95 %: {gt_all[0]:.3f} / {gt_all[1]:.3f} / {gt_all[2]:.3f} D; "
              f"regions' twin curves peak at {np.quantile(peaks[used], 0.1):.2f}-{np.quantile(peaks[used], 0.9):.2f} "
              f"D (10-90 %, {int(used.sum())} regions used); frames at {true_d.min():.3f}-{true_d.max():.3f} D")
        _, folder, _ = set_spec(spec)
        tex = aif_texture(folder)
        print(f"- the all-in-focus image's texture (gt_aif.png, grey, 8-bit DN): standard deviation {tex[0]:.1f}, "
              f"Laplacian rms {tex[1]:.2f}; the twin's highest focus measure, median region: "
              f"{np.median(sweep.twin[0].max(-1)[used]):.2f} log; its range over the sweep {np.median(np.ptp(sweep.twin[0], -1)[used]):.2f}, "
              f"the capture's over the frames {np.median(np.ptp(sweep.capture[0], -1)[used]):.2f} log (median region)")
        beta = fr.fit_floors(base, true_d[None])[0]
        top = sweep.twin[0].max(-1)
        print(f"- floors fitted at the truth in {int(np.isfinite(beta[used]).sum())}/{int(used.sum())} regions, "
              f"below the twin's top (10/50/90 %): "
              + " / ".join(f"{v:.1f}" for v in np.quantile(np.where(np.isfinite(beta), top - beta, np.inf)[used],
                                                             (0.1, 0.5, 0.9))) + " log")
        n, r, s = sweep.capture.shape
        at = np.broadcast_to(true_d[None, None, :], (n, r, s))
        slope = (ff.curves_at(at_truth, at + 0.01) - ff.curves_at(at_truth, at - 0.01))[0] / 0.02  # (R, S)
        k = ff.level_sensitivity(at_truth, true_d[None])[0]
        res = (at_truth.capture - fr.twin_at(at_truth, true_d[None]))[0]
        res = res - res.mean(-1, keepdims=True)
        w = sweep.weight[0]
        level = (w[:, None] * res).sum(0) / w.sum()
        # the capture's excess over the unfloored twin (levels matched on each region's two frames nearest its peak)
        tw0 = fr.twin_at(base, true_d[None])[0]
        cap0 = base.capture[0]
        print("\n| frame | true (D) | nearest content (D away) | regions seen from one side | fit err (D) | "
              "floors at truth err (D) | no floors err (D) | k (D/log) | level misfit at truth (log) | k x level (D) "
              "| floor share of twin at truth (median) | fit err / k (log) | fit err, floors on a 0.1-log grid (D) |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        floor_share = np.exp(np.where(np.isfinite(beta), beta, -np.inf)[:, None]
                             - np.logaddexp(tw0, np.where(np.isfinite(beta), beta, -np.inf)[:, None]))
        for f in range(s):
            side = np.sign(slope[used, f])
            one = max(np.mean(side > 0), np.mean(side < 0))
            gap = np.min(np.abs(gt_q[used][:, [0, 2]] - true_d[f])) if not np.any(
                (gt_q[used, 0] <= true_d[f]) & (gt_q[used, 2] >= true_d[f])) else 0.0
            print(f"| {f} | {true_d[f]:.3f} | {gap:.2f} | {100 * one:.0f} % | {est['fit'][0, f] - true_d[f]:+.3f} | "
                  f"{est['floors at the truth, held'][0, f] - true_d[f]:+.3f} | {est['no floors'][0, f] - true_d[f]:+.3f} | "
                  f"{k[f]:+.2f} | {level[f]:+.3f} | {k[f] * level[f]:+.3f} | {100 * np.median(floor_share[used, f]):.0f} % | "
                  f"{(est['fit'][0, f] - true_d[f]) / k[f]:+.3f} | {est['fine floors'][0, f] - true_d[f]:+.3f} |")
        # the tail: capture - twin (no floor) against the twin's own fall below its top, both matched at the peak
        near = np.argsort(np.abs(true_d[None, :] - peaks[:, None]), -1)[:, :2]
        off = np.take_along_axis(cap0 - tw0, near, -1).mean(-1)
        exc = (cap0 - tw0) - off[:, None]  # (R, S) capture above the twin, 0 near the peak
        fall = top[:, None] - tw0  # how far the twin has fallen below its top
        fl = np.where(np.isfinite(beta), top - beta, np.nan)
        print("\nthe capture's excess over the unfloored twin (log, levels matched at each region's two frames nearest "
              "its peak) by how far the twin has fallen below its top, relative to the region's fitted floor "
              "(fall - floor depth; a noise floor predicts log(1 + e^x)):\n")
        print("| twin fall - floor depth (log) | frames x regions | excess, median (log) | noise floor's "
              "log(1 + e^x) |")
        print("|---|---|---|---|")
        x = (fall - fl[:, None])[used]
        e = exc[used]
        for lo, hi in ((-6, -3), (-3, -2), (-2, -1), (-1, 0), (0, 1), (1, 2), (2, 4)):
            m = np.isfinite(x) & (x >= lo) & (x < hi)
            if m.sum():
                mid = np.median(x[m])
                print(f"| {lo} to {hi} | {int(m.sum())} | {np.median(e[m]):+.2f} | {np.log1p(np.exp(mid)):.2f} |")
    return out.getvalue()


def aif_texture(folder: Path) -> tuple[float, float]:
    """The all-in-focus image's grey standard deviation and Laplacian rms (8-bit DN; 16-bit files scaled to 8)."""
    import cv2

    im = cv2.imread(str(folder / "gt_aif.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
    im = im.mean(-1) * (255.0 / 65535.0 if im.max() > 255 else 1.0)
    return float(im.std()), float(np.sqrt(np.mean(cv2.Laplacian(im, cv2.CV_64F) ** 2)))


def nuisance_choice(results: list[str], cache: Path, threads: int) -> str:
    """What a fix would need, tried on stored fits (not an estimator change): the family chosen as
    `focusfit.score_families` does, but with every family given one more parameter, a level misfit lambda read as
    focus through each frame's level sensitivity (e = f + lambda k, lambda profiled, flat prior: the same price for
    every family where it is identifiable, so no setting), k from the scene's untouched copy (its prepared sweep at
    its fit's estimates: an approximation for the other sets), the rows' own sigma (bootstrap spread and systematic
    error, no error scale). Scenes whose untouched sweep is in the cache only."""
    import math

    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose import focusrobust as fr

    rows = list({(r["capture"], r["kind"]): r for f in results for r in map(json.loads, Path(f).read_text().splitlines())
                 if r.get("frame_systematic_d")}.values())
    out = io.StringIO()
    with redirect_stdout(out):
        print("\n### The family chosen with a level misfit read as focus profiled out (stored fits; "
              + ", ".join(results) + ")\n")
        print("| scene | k (D per log unit), frames near to far | family right as run | with lambda profiled | "
              "changed (set: as run -> with lambda) |")
        print("|---|---|---|---|---|")
        for cap in sorted({r["capture"] for r in rows}):
            if not (cache / f"{cap}_none.npz").exists():
                continue
            sweep, *_ = sweep_of(f"{cap}:none", cache, threads)
            prep, rep = fr.prepare(sweep)
            k = ff.level_sensitivity(prep, np.asarray(rep["frame_focus_d"][-1]))[0]
            rs = sorted((r for r in rows if r["capture"] == cap), key=lambda r: list(bench.kinds()).index(r["kind"]))
            ok, changed = 0, []
            for r in rs:
                e = np.asarray(next(x for x in r["families"] if x["family"] == "per_frame")["true_d"], np.float64)[0]
                rep_d = np.asarray(next(x for x in r["families"] if x["family"] == "none")["true_d"], np.float64)
                w = 1.0 / (np.asarray(r["frame_focus_sd_d"], np.float64)[0] ** 2
                           + np.asarray(r["frame_systematic_d"], np.float64)[0] ** 2)
                sc = {}
                for x in r["families"]:
                    f = np.asarray(x["true_d"], np.float64)
                    jac, widths = ff.family_design(x["family"], rep_d, f, np.ones_like(rep_d))
                    res = f[0] - e
                    j = np.concatenate([jac[0], k[:, None]], 1)
                    if np.linalg.matrix_rank(j) > jac.shape[-1]:  # lambda identifiable besides the family
                        lam = -np.sum(w * res * k) / np.sum(w * k * k)
                        chi2 = float(np.sum(w * (res + lam * k) ** 2))
                    else:
                        j, chi2 = jac[0], float(np.sum(w * res * res))
                    kk = j.shape[1]
                    logdet = float(np.linalg.slogdet(j.T @ (j * w[:, None]))[1]) if kk else 0.0
                    sc[x["family"]] = (round(chi2 + logdet - kk * math.log(2 * math.pi)
                                             + 2 * sum(math.log(v) for v in widths), 9), int(x["k"]))
                best = min(sc, key=lambda n: sc[n])
                ok += best == r["family_true"]
                if best != r["family"]:
                    changed.append(f"{r['kind']}: {r['family']} -> {best}")
            print(f"| {cap} | {' '.join(f'{v:+.2f}' for v in k)} | {sum(r['family_ok'] for r in rs)}/{len(rs)} | "
                  f"{ok}/{len(rs)} | {'; '.join(changed) or '-'} |")
    return out.getvalue()


def aif16_variant(scene: int) -> Path:
    """cache/captures/scene<S>_aif16: the capture's frames and depth (hard links) with its all-in-focus image
    written at 16 bits (the procedural scene's own, as `make_sample_capture.py` hands it to aat-render) instead of
    aat-render's 8-bit gt_aif.png: does the twin's all-in-focus quantisation bend the focus curves?"""
    import os

    import cv2

    from aat_deploy.io.color import linear_to_srgb
    from training.data.scenes import SceneConfig, procedural_scene

    src = bench.CACHE / "captures" / f"scene{scene}"
    dst = bench.CACHE / "captures" / f"scene{scene}_aif16"
    dst.mkdir(parents=True, exist_ok=True)
    for f in src.iterdir():
        if f.is_file() and f.name != "gt_aif.png" and not (dst / f.name).exists():
            os.link(f, dst / f.name)
    rgb, _ = procedural_scene(SceneConfig(height=640, width=960, near_m=0.7, far_m=5.0), np.random.default_rng(scene))
    cv2.imwrite(str(dst / "gt_aif.png"), np.round(linear_to_srgb(rgb)[..., ::-1] * 65535).astype(np.uint16))
    return dst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sets", nargs="+", help="capture:kind, e.g. scene2038:none")
    ap.add_argument("--cache", default=str(SWEEP_CACHE))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--chain", nargs="+", default=[""], help="effects in the twin, comma-separated (e.g. "
                    "vignetting,raw_pipeline); several: each in turn ('' or none: the first round's twin)")
    ap.add_argument("--nuisance", nargs="+", metavar="RESULTS", help="also: the family choice on these stored fits "
                    "with a level misfit read as focus profiled out (`nuisance_choice`), for the scenes whose "
                    "untouched sweep is cached")
    ap.add_argument("--noise-floor", action="store_true", help="a twin with noise: its sweep carries the noise by its "
                    "expectation, scaled for the RAW development (`noisefloor`), not a binned draw")
    ap.add_argument("--out", help="also write the output here (markdown)")
    ap.add_argument("--aif16", type=int, nargs="*", default=[], metavar="SCENE", help="first make these scenes' "
                    "variant with a 16-bit all-in-focus image (`aif16_variant`), then analyse the sets")
    a = ap.parse_args()
    if a.out and a.nuisance and Path(a.out).resolve() in {Path(f).resolve() for f in a.nuisance}:
        raise SystemExit(f"{a.out}: is one of the results read; choose another --out")  # before any work
    for scene in a.aif16:
        aif16_variant(scene)
    chains = ["" if c == "none" else c for c in a.chain]
    text = "".join(report(s, Path(a.cache), a.threads, c, a.noise_floor) for c in chains for s in a.sets)
    if a.nuisance:
        text += nuisance_choice(a.nuisance, Path(a.cache), a.threads)
    print(text, end="")
    if a.out:
        from aat_deploy.io.atomic import write_text_atomic

        write_text_atomic(Path(a.out), "# Why a scene's per-frame focus estimates are compressed (issue 32)\n\n"
                          f"`python -m benchmarks.probes.focus_scene_coverage {' '.join(a.sets)}"
                          f"{' --chain ' + ' '.join(c or 'none' for c in chains) if any(chains) else ''}"
                          f"{' --noise-floor' if a.noise_floor else ''}"
                          f"{' --nuisance ' + ' '.join(a.nuisance) if a.nuisance else ''}`\n" + text)


if __name__ == "__main__":
    main()
