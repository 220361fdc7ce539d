"""Focus-metadata errors on captures like the shipped sample (issue 32): the withheld-effect benchmark's focus sets
made from real-looking captures rather than from its own TIFF renders.

Captures: `captures/sample_rf50` and others rendered like it (`python -m scripts.make_sample_capture --scene-seed S --seed
N`: a procedural scene through the RF50 with vignetting and noise, 8 DNG frames 0.6-6 m that the runtime develops
with LibRaw). Each set is a copy of one capture whose reported focus distances (a `capture.json` sidecar, as a
user would correct EXIF) carry one error:
- focus scale 0.9, 0.95, 1.05, 1.1, 1.15 (reported distance = scale x true): family `scale`;
- offsets of +-0.05 and +-0.1 D (reported = true + b diopters): family `offset`, bias_d = b;
- a quantised set (each reported value rounded to 0.1 D steps): family `quantisation`;
- a monotone curve (reported = true + a (true - 1)^2 - a / 3 diopters, a = +-0.1): family `monotone`;
- the untouched copy: family `none`, and focus metadata never named.
Each set is diagnosed as `aat-diagnose COPY --model MODEL --out OUT` does by default (every registered effect,
3 greedy rounds, torch-free twins) with the shipped main model. Scored: the focus family (`focus.family`), the
corrected focus against the truth (diopters; the corrected distances are the reported ones when the family is
`none`), the per-frame estimates (`focus.frame_focus_d`) and whether any sits on its search bound (+-0.4 D around
the reported value) while the truth does not.

    python -m benchmarks.bench_diagnose_focus [--captures 3] [--kinds scale_1.1,none] [--out RESULTS.jsonl]
    flock /work/heavy.lock nice -n 10 python -m benchmarks.bench_diagnose_focus        # the whole benchmark
    python -m benchmarks.bench_diagnose_focus --table [RESULTS.jsonl ...]               # the table only
    python -m benchmarks.bench_diagnose_focus --fit-only --folders cache/bench_diagnose_focus/captures/scene2029 \
        --out results/diagnose_focus_tune2029.jsonl                                     # the tuning capture's sets
    python -m benchmarks.bench_diagnose_focus --systematic results/diagnose_focus_tune2029.jsonl  # tune SYSTEMATIC_D
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh 4 --out results/diagnose_focus_fresh_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh2 4 --out results/diagnose_focus_fresh2_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh3 4 --out results/diagnose_focus_fresh3_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh4 4 --out results/diagnose_focus_fresh4_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh5 4 --out results/diagnose_focus_fresh5_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh6 4 --out results/diagnose_focus_fresh6_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh7 4 --out results/diagnose_focus_fresh7_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh8 4 --out results/diagnose_focus_fresh8_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh9 4 --out results/diagnose_focus_fresh9_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh10 4 --out results/diagnose_focus_fresh10_fitonly.jsonl
    python -m benchmarks.bench_diagnose_focus --fit-only --fresh11 4 --out results/diagnose_focus_fresh11_fitonly.jsonl

The tuning capture (scene 2029, rendered like the others with --scene-seed 2029 --seed 4) is not in the benchmark:
`focusfit.SYSTEMATIC_D`, the family choice's only setting, is chosen on its sets alone (`--systematic`: the family
each set's stored fits choose per setting), then the benchmark's sets are run with it.

Captures are rendered once into --cache (git-ignored), the copies hard-link their frames; results are appended to
--out, one JSON line per set, and sets already there are skipped (a stopped run continues where it stopped). Each
set's `diagnosis.json` stays in its folder.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import atomic_file
from benchmarks import RESULTS

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "cache" / "bench_diagnose_focus"
RESULTS_FILE = RESULTS / "diagnose_focus.jsonl"
SCENES = ((2026, 1), (2027, 2), (2028, 3))  # (scene seed, noise seed); 2026/1 = the shipped sample
# Fresh test captures (issue 32), declared before any of them was rendered or run (2026-11-26, 15:20 UTC): rendered
# exactly like scenes 2027 and 2028 (make_sample_capture.py, next noise seeds), scene ids never used before. Test
# material: nothing is chosen or tuned on them (the tuning capture is scene 2029). `--fresh N` runs the first N.
FRESH_SCENES = ((2030, 5), (2031, 6), (2032, 7), (2033, 8))
# The second round of fresh test captures (issue 32, the end-of-curve precision fix), declared 2026-11-26 18:36 UTC,
# before any of them was rendered or run and before the fix was run on anything but stored fits: rendered exactly
# like scenes 2027-2033, scene ids and noise seeds never used before (scenes 2030-2033 were looked at and are
# development material now). Test material: nothing is chosen or tuned on them. `--fresh2 N` runs the first N.
FRESH_SCENES_2 = ((2034, 9), (2035, 10), (2036, 11), (2037, 12))
# The third round (issue 32: per-value searches run to convergence, the family chosen with the capture's own error
# scale), declared 2026-11-26 21:15 UTC, before any of them was rendered or run: rendered exactly like scenes
# 2027-2037, scene ids and noise seeds never used before (scenes 2030-2037 were looked at and are development
# material now). Test material: nothing is chosen or tuned on them. `--fresh3 N` runs the first N.
FRESH_SCENES_3 = ((2038, 13), (2039, 14), (2040, 15), (2041, 16))
# The fourth round (issue 32: each frame's systematic error never below the level misfit the capture shows times its
# level sensitivity, `focusfit.SYSTEMATIC_FROM_LEVEL`), declared 2026-11-27 00:55 UTC, before any of them was
# rendered or run and before the change was run on anything but stored fits: rendered exactly like scenes
# 2027-2041, scene ids and noise seeds never used before (scenes 2030-2041 were looked at and are development
# material now). Test material: nothing is chosen or tuned on them. `--fresh4 N` runs the first N.
FRESH_SCENES_4 = ((2042, 17), (2043, 18), (2044, 19), (2045, 20))
# The fifth round (issue 32: RAW captures' focus fitted on the focus twin, with the development, vignetting and the
# noise by its expected floor, the full well fitted against it; noise-dominated frames left out, without an
# estimate), declared 2026-11-27 07:14 UTC, before any of them was rendered or run: rendered exactly like scenes
# 2027-2045, scene ids and noise seeds never used before (scenes 2030-2045 were looked at and are development
# material now). Test material: nothing is chosen or tuned on them. `--fresh5 N` runs the first N.
FRESH_SCENES_5 = ((2046, 21), (2047, 22), (2048, 23), (2049, 24))
# The sixth round (issue 32: a held-out test of the noise rule, `focusfit.NOISE_DOMINATED_SHARE`: frames whose expected
# measure is at least half noise are left out, without an estimate of their own), declared 2026-11-27 09:30 UTC (committed b7b953c),
# before any candidate scene was rendered, screened or run (the code: the focus twin as adopted in 26a7f4b, the
# first-round fit). Why: scenes 2030-2049 held one scene like 2038 (far, little texture: its nearest frames
# noise-dominated), a development scene, so the rule has never met held-out data. The scenes are chosen from
# candidates by a rule fixed here on the procedural scene's own ground truth (its depth and all-in-focus image), which
# looks at no render and no diagnosis result: candidate scene seeds 2050, 2051, ... (FRESH6_CANDIDATES, in that
# order, never used before: every earlier set is 2026-2049), each the scene `make_sample_capture.py --scene-seed S`
# makes (`sample_scene`); kept if (a) "far": the 99th percentile of its inverse depth is at most FRESH6_MAX_NEAR_D
# (every frame's content but 1 % of the image at least 1.18 m away; scene 2038: 0.60 D, 2035: 0.78 D, the other
# development scenes 2034-2048: 1.04-1.43 D), and (b) "little texture": the mean squared Laplacian of its linear
# luminance binned 4 x 4 (240 x 160 px, area average), over the luminance's mean squared, is at most FRESH6_MAX_TEXTURE
# (scene 2038: 0.0070; 2034-2048: 0.0059-0.164). The thresholds were set on development scenes 2034-2048 only; the
# pass rate of the rule, about 2 % (5 of scene seeds 10000-10299, which are never candidates), is why the candidates
# run to 2649. The first FRESH6_K kept, in candidate order, are the sixth round, rendered exactly like scenes
# 2027-2049 with noise seeds FRESH6_NOISE_SEEDS (25-28, never used before: 1-24 are) in that order. Test material:
# nothing is chosen or tuned on them; whatever they show is reported whole, and no candidate is redrawn. `--fresh6 N`
# runs the first N.
FRESH6_CANDIDATES = range(2050, 2650)
FRESH6_MAX_NEAR_D = 0.85  # the 99th percentile of the scene's inverse depth (diopters), at most
# mean squared Laplacian of the 4 x 4 binned luminance / mean luminance^2 (1/px^4, binned pixels), at most
FRESH6_MAX_TEXTURE = 0.02
FRESH6_NOISE_SEEDS = (25, 26, 27, 28)
FRESH6_K = len(FRESH6_NOISE_SEEDS)
# The seventh round (issue 32: the quantisation grid detected from every reported value, the frames left out of the
# fit included, and a left-out frame under `none` undetermined, `focusfit.reported_values`, 45e04dd), declared
# 2026-11-27 10:09 UTC (committed 00e4d34), before any candidate was rendered, screened or run. Why: the sixth round (2065, 2073, 2141,
# 2182, now development material) missed the targets on far scenes with little texture, where frames are left out
# (quantised sets 3/4 wrong: the grid read from the frames left in), and the fix was made on development scenes (2038
# and the sixth round's) only, so it has not met held-out data. The same declared selection rule as the sixth round
# (`fresh6_keeps`: FRESH6_MAX_NEAR_D, FRESH6_MAX_TEXTURE, on the procedural scene's own ground truth, no render and no
# diagnosis result), candidates FRESH7_CANDIDATES in order from 2183 (never used: the earlier sets are 2026-2049 and
# the sixth round's candidates 2050-2182, screened up to its fourth kept scene), the first FRESH7_K kept rendered
# exactly like scenes 2027-2182 with noise seeds FRESH7_NOISE_SEEDS (29-32, never used before: 1-28 are), in that
# order. Test material: nothing is chosen or tuned on them; whatever they show is reported whole, and no candidate is
# redrawn. `--fresh7 N` runs the first N (screening statistics in cache/fresh7_stats.json).
FRESH7_CANDIDATES = range(2183, 2783)
FRESH7_NOISE_SEEDS = (29, 30, 31, 32)
FRESH7_K = len(FRESH7_NOISE_SEEDS)
# The eighth round (issue 32: the families fitted to the per-frame estimates with the evidence's own weights,
# `focusfit.fit_on_estimates`, and a left-out frame alone in its quantisation bin at the bin's centre with the bin's
# standard error, `focusfit.left_out_sd`; f56e7a3), declared 2026-11-27 12:33 UTC, before any candidate was rendered,
# screened or run. Why: the change was made and judged on development rows only (stored fits of scenes 2029-2048,
# 2038, the sixth and seventh rounds', all looked at), and the seventh round missed the 0.02 D target (34/44). The
# same declared selection rule as the sixth and seventh rounds (`fresh6_keeps`: FRESH6_MAX_NEAR_D, FRESH6_MAX_TEXTURE,
# on the procedural scene's own ground truth, no render and no diagnosis result), candidates FRESH8_CANDIDATES in
# order from 2370 (never used: the seventh round screened 2183-2369, up to its fourth kept scene), the first FRESH8_K
# kept rendered exactly like scenes 2027-2369 with noise seeds FRESH8_NOISE_SEEDS (33-36, never used before: 1-32 are),
# in that order; the first-round focus fit (`--fit-only`) with the code as landed, run once. Test material: nothing
# is chosen or tuned on them; whatever they show is reported whole, and no candidate is redrawn. `--fresh8 N` runs
# the first N (screening statistics in cache/fresh8_stats.json).
FRESH8_CANDIDATES = range(2370, 2970)
FRESH8_NOISE_SEEDS = (33, 34, 35, 36)
FRESH8_K = len(FRESH8_NOISE_SEEDS)
# The ninth round (issue 32: each fitted frame weighed in the families' parameter fits by its margin over the noise rule,
# `focusfit.signal_weight`, `WEIGHT_BY_NOISE_SHARE`, with the standard errors of that estimator), declared 2026-11-27
# 15:46 UTC, before any candidate was rendered, screened or run. Why: the change was made and judged on development rows
# only (the 288 stored sets of scenes 2029-2369; the eighth round's scenes 2383, 2431, 2467, 2472 not used), where it
# made the corrected focus more precise but could not move the 0.02 D count, and the eighth round missed that target
# (28/44) by the mechanism it is for. The same declared selection rule as the sixth to eighth rounds (`fresh6_keeps`:
# FRESH6_MAX_NEAR_D, FRESH6_MAX_TEXTURE, on the procedural scene's own ground truth, no render and no diagnosis
# result), candidates FRESH9_CANDIDATES in order from 2473 (never used: the eighth round screened 2370-2472, up to its
# fourth kept scene), the first FRESH9_K kept rendered exactly like scenes 2027-2472 with noise seeds
# FRESH9_NOISE_SEEDS (37-40, never used before: 1-36 are), in that order; the first-round focus fit (`--fit-only`) with
# the code as landed, run once. Test material: nothing is chosen or tuned on them; whatever they show is reported
# whole, and no candidate is redrawn. `--fresh9 N` runs the first N (screening statistics in cache/fresh9_stats.json).
FRESH9_CANDIDATES = range(2473, 3073)
FRESH9_NOISE_SEEDS = (37, 38, 39, 40)
FRESH9_K = len(FRESH9_NOISE_SEEDS)
# The tenth round (issue 32: a fitted frame whose per-frame estimate sits on its search bound left out and the fit
# redone, `focusfit.LEAVE_OUT_ON_BOUND`), declared 2026-11-27 before any candidate was rendered, screened or run (not
# run this session). Why: the change was made on development rows only (the 288 stored sets of scenes 2029-2369; the
# eighth and ninth rounds' scenes 2383, 2431, 2467, 2472, 2620, 2628, 2655, 2722 not used), where no estimate came
# near its bound, so it changed none of them; its one known case is the ninth round's. The same declared selection
# rule as the sixth to ninth rounds (`fresh6_keeps`: FRESH6_MAX_NEAR_D, FRESH6_MAX_TEXTURE, on the procedural scene's
# own ground truth, no render and no diagnosis result), candidates FRESH10_CANDIDATES in order from 2723 (never used:
# the ninth round screened 2473-2722, up to its fourth kept scene), the first FRESH10_K kept rendered exactly like
# scenes 2027-2722 with noise seeds FRESH10_NOISE_SEEDS (41-44, never used before: 1-40 are), in that order; the
# first-round focus fit (`--fit-only`) with the code as landed at e95900e (`aat_deploy/` as there), run once. Test
# material: nothing is chosen or tuned on them; whatever they show is reported whole, and no candidate is redrawn.
# `--fresh10 N` runs the first N (screening statistics in cache/fresh10_stats.json).
FRESH10_CANDIDATES = range(2723, 3323)
FRESH10_NOISE_SEEDS = (41, 42, 43, 44)
FRESH10_K = len(FRESH10_NOISE_SEEDS)
# The eleventh round (issue 32: the family choice prices the nearest fitted frame's error at twice the model's,
# `focusfit.CHOICE_NEAREST_FACTOR`), declared 2026-11-27 before any candidate was rendered, screened or run. Why: the
# change was adopted on development rows only (rounds 1-10 and the development scenes, 432 sets rescored:
# `benchmarks/probes/focus_choice_nearest.py`), where its gain sits mostly in rounds 8-9, whose misses showed the
# mechanism. The same declared selection rule as the sixth to tenth rounds (`fresh6_keeps`: FRESH6_MAX_NEAR_D,
# FRESH6_MAX_TEXTURE, on the procedural scene's own ground truth, no render and no diagnosis result), candidates
# FRESH11_CANDIDATES in order from 3240 (never used: the tenth round screened 2723-3239, up to its fourth kept scene),
# the first FRESH11_K kept rendered exactly like scenes 2027-3239 with noise seeds FRESH11_NOISE_SEEDS (45-48, never used
# before: 1-44 are), in that order; the first-round focus fit (`--fit-only`) with the code as landed at e6bdee8
# (`aat_deploy/` as there and at its branch commit 696b53d), run once. Test material: nothing is chosen or tuned on them; whatever they show is reported
# whole, and no candidate is redrawn. `--fresh11 N` runs the first N (screening statistics in cache/fresh11_stats.json).
FRESH11_CANDIDATES = range(3240, 3840)
FRESH11_NOISE_SEEDS = (45, 46, 47, 48)
FRESH11_K = len(FRESH11_NOISE_SEEDS)
QUANT_STEP_D = 0.1
BOUND_TOL_D = 0.002


def kinds() -> dict[str, tuple[str, dict]]:
    """Set kind -> (the family the diagnosis should choose, the error's settings)."""
    out = {"none": ("none", {})}
    out.update({f"scale_{s}": ("scale", {"scale": s}) for s in (0.9, 0.95, 1.05, 1.1, 1.15)})
    out.update({f"offset_{b:+.2f}": ("offset", {"bias_d": b}) for b in (-0.1, -0.05, 0.05, 0.1)})
    out["quantised"] = ("quantisation", {"step_d": QUANT_STEP_D})
    out["monotone"] = ("monotone", {"a": 0.1})
    return out


def reported_d(kind: str, true_d: np.ndarray, capture_index: int) -> np.ndarray:
    """The focus (diopters) the copy's metadata reports for frames truly focused at true_d."""
    _, p = kinds()[kind]
    if kind == "none":
        return true_d.copy()
    if "scale" in p:  # reported distance = scale x true distance
        return true_d / p["scale"]
    if "bias_d" in p:
        return true_d + p["bias_d"]
    if "step_d" in p:
        return np.round(true_d / p["step_d"]) * p["step_d"]
    a = p["a"] * (1 if capture_index % 2 == 0 else -1)  # the curve bends either way
    return true_d + a * (true_d - 1.0) ** 2 - a / 3


def rendered_capture(scene: int, seed: int, cache: Path) -> Path:
    """cache/captures/scene<scene>: a capture rendered like the shipped sample (made once)."""
    folder = cache / "captures" / f"scene{scene}"
    if not (folder / "virtual_camera.json").exists():
        print(f"rendering {folder} (scene {scene}, noise seed {seed})", flush=True)
        subprocess.run([sys.executable, str(ROOT / "scripts" / "make_sample_capture.py"), "--out", str(folder),
                        "--scene-seed", str(scene), "--seed", str(seed), "--force"], check=True, cwd=ROOT)
    return folder


def capture_folders(n: int, cache: Path) -> list[Path]:
    """The shipped sample and n - 1 captures rendered like it (made once into cache)."""
    if n > len(SCENES):
        raise SystemExit(f"--captures: at most {len(SCENES)}")
    return [ROOT / "captures" / "sample_rf50" if k == 0 else rendered_capture(scene, seed, cache)
            for k, (scene, seed) in enumerate(SCENES[:n])]


def scene_stats(scene: int) -> dict:
    """The sixth round's selection statistics of a procedural scene (`sample_scene`, its ground truth only: no render,
    no diagnosis): near_d, the 99th percentile of its inverse depth (diopters); texture, the mean squared Laplacian of
    its linear luminance (RGB mean) binned 4 x 4 by area averaging, over the luminance's mean squared (1/px^4 in
    binned pixels: the Laplacian is per px^2, squared)."""
    import cv2

    from scripts.make_sample_capture import sample_scene

    rgb, depth = sample_scene(scene)
    lum = rgb.mean(-1)
    binned = cv2.resize(lum, (lum.shape[1] // 4, lum.shape[0] // 4), interpolation=cv2.INTER_AREA)
    lap = cv2.Laplacian(binned, cv2.CV_32F)
    return {"near_d": float(np.quantile(1.0 / depth, 0.99)), "texture": float(np.mean(lap ** 2) / lum.mean() ** 2)}


def fresh6_keeps(st: dict) -> bool:
    """The sixth round's rule (declared with FRESH6_CANDIDATES): far and little texture."""
    return st["near_d"] <= FRESH6_MAX_NEAR_D and st["texture"] <= FRESH6_MAX_TEXTURE


def fresh6_scenes(n: int, cache: Path, candidates: range = FRESH6_CANDIDATES, seeds: tuple = FRESH6_NOISE_SEEDS,
                  name: str = "fresh6") -> tuple:
    """((scene, noise seed), ...): the first n candidates (FRESH6_CANDIDATES, in order) the rule keeps, the k-th with
    FRESH6_NOISE_SEEDS[k] (the seventh round: FRESH7_CANDIDATES, FRESH7_NOISE_SEEDS, name "fresh7"; the eighth:
    FRESH8_*, "fresh8"; the ninth: FRESH9_*, "fresh9"; the tenth: FRESH10_*, "fresh10"; the eleventh: FRESH11_*,
    "fresh11"). The statistics
    are cached in cache/<name>_stats.json (every candidate screened, kept or not, is listed there)."""
    if not 1 <= n <= len(seeds):
        raise SystemExit(f"--{name}: 1 to {len(seeds)}")
    path = cache / f"{name}_stats.json"
    stats = {int(k): v for k, v in json.loads(path.read_text()).items()} if path.exists() else {}
    kept = []
    for scene in candidates:
        if scene not in stats:
            stats[scene] = scene_stats(scene)
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_file(path) as tmp:
                tmp.write_text(json.dumps(stats, indent=0) + "\n")
        if fresh6_keeps(stats[scene]):
            kept.append(scene)
            if len(kept) == n:
                return tuple(zip(kept, seeds))
    raise SystemExit(f"--{name}: only {len(kept)} of {candidates.start}-{candidates.stop - 1} kept")


def fresh_folders(n: int, cache: Path, scenes: tuple = FRESH_SCENES, flag: str = "--fresh") -> list[Path]:
    """The first n fresh test captures (`FRESH_SCENES`, or `FRESH_SCENES_2`), rendered once into cache."""
    if not 1 <= n <= len(scenes):
        raise SystemExit(f"{flag}: 1 to {len(scenes)}")
    return [rendered_capture(scene, seed, cache) for scene, seed in scenes[:n]]


def make_copy(src: Path, root: Path, rep_m: np.ndarray) -> Path:
    """root/<capture>: src's files (hard links, else copies) with a capture.json reporting rep_m (metres) for its
    frames in ascending true focus."""
    dst = root / src.name
    frames = sorted(p.name for p in src.glob("frame_*.dng"))
    sidecar = {"frames": [{"file": f, "focus_m": round(float(m), 6)} for f, m in zip(frames, rep_m)]}
    if dst.exists() and json.loads((dst / "capture.json").read_text()) == sidecar:
        return root
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for p in src.iterdir():
        if p.is_file() and p.name != "capture.json":
            try:
                os.link(p, dst / p.name)
            except OSError:
                shutil.copy2(p, dst / p.name)
    (dst / "capture.json").write_text(json.dumps(sidecar, indent=1) + "\n")
    return root


def score(kind: str, family: str, true_d: np.ndarray, rep_d: np.ndarray, res: dict) -> dict:
    f = res.get("focus") or {}
    named = [e["effect"] for e in res["ranked_effects"]] + [e["effect"] for e in res["image_effects"]]
    corr = f.get("corrected_focus", [{}])[0].get("corrected_m") if f else None
    corr_d = 1.0 / np.asarray(corr) if corr else rep_d
    per = np.asarray(f.get("frame_focus_d", [rep_d.tolist()])[0], np.float64)
    lo, hi = rep_d - 0.4, rep_d + 0.4
    on_bound = ((np.abs(per - lo) < BOUND_TOL_D) & (np.abs(true_d - lo) > 0.01)) | \
               ((np.abs(per - hi) < BOUND_TOL_D) & (np.abs(true_d - hi) > 0.01))
    return {"kind": kind, "family_true": family, "family": f.get("family"), "family_ok": f.get("family") == family,
            "params": f.get("params"), "params_ci": f.get("params_ci"), "support": f.get("support"),
            "focus_named": "focus_metadata" in named, "focus_cause": "focus_metadata" in res.get("causes", []),
            "corrected_err_d": (corr_d - true_d).round(4).tolist(),
            "corrected_max_err_d": float(np.abs(corr_d - true_d).max()),
            "reported_max_err_d": float(np.abs(rep_d - true_d).max()),
            # a noise-dominated frame has no estimate (null: NaN here); the largest error is the others'
            "frame_err_d": (per - true_d).round(4).tolist(),
            "frame_max_err_d": float(np.nanmax(np.abs(per - true_d))) if np.isfinite(per).any() else None,
            "frames_on_bound": int(on_bound.sum()), "verdict": res.get("verdict"), "named": named,
            "robust": f.get("robust"), "frame_focus_sd_d": f.get("frame_focus_sd_d"),
            "frame_systematic_d": f.get("frame_systematic_d"), "corrected_sd_d": f.get("corrected_sd_d"),
            "frame_consistency": f.get("frame_consistency"), "error_scale": f.get("error_scale"),
            "undetermined_covers": undetermined_covers(f, true_d),
            "frames_undetermined": int(np.sum(f.get("frames_undetermined") or [])),
            "frames_noise_dominated": (f.get("frames_noise_dominated") or [[]])[0],
            "frames_left_out_on_bound": (f.get("frames_left_out_on_bound") or [[]])[0],
            "frame_noise_share": (f.get("frame_noise_share") or [[]])[0], "focus_twin": f.get("focus_twin"),
            "families": [{k: x.get(k) for k in ("family", "k", "score", "true_d")} for x in f.get("families", [])]}


def undetermined_covers(f: dict, true_d: np.ndarray) -> list[bool] | None:
    """Per frame reported undetermined: does its 95 % interval (`corrected_focus[].total_ci_m`, the systematic
    part included) contain the truth? None without the flag (older rows, or no interval)."""
    cf = (f.get("corrected_focus") or [{}])[0]
    ci, und = cf.get("total_ci_m"), cf.get("undetermined")
    if not ci or und is None:
        return None
    return [bool(min(lo, hi) <= 1.0 / t <= max(lo, hi)) for (lo, hi), u, t in zip(ci, und, true_d) if u]


def undetermined_frames(row: dict) -> np.ndarray:
    """(S,) the frames of a row's (first) capture reported undetermined: the corrected focus's standard error
    (`corrected_sd_d`, rounded to 1e-5 D in the row) at least `focusfit.UNDETERMINED_SD_D`."""
    from aat_deploy.diagnose import focusfit as ff

    sd = np.asarray(row.get("corrected_sd_d") or [[0.0] * len(row["corrected_err_d"])], np.float64)[0]
    return sd >= ff.UNDETERMINED_SD_D


def reported_outside(row: dict, z: float = 1.959964) -> bool | None:
    """Does some frame's reported focus lie outside the 95 % interval of its corrected focus (corrected focus
    +- z standard errors, `corrected_sd_d`: the `total_ci_m` the verdict tests, in diopters)? None without the
    stored fits."""
    fams = {f["family"]: f for f in row.get("families") or []}
    if row.get("family") not in fams or "none" not in fams or not row.get("corrected_sd_d"):
        return None
    rep = np.asarray(fams["none"]["true_d"], np.float64)[0]
    corr = np.asarray(fams[row["family"]]["true_d"], np.float64)[0]
    sd = np.asarray(row["corrected_sd_d"], np.float64)[0]
    return bool(np.any(np.abs(rep - corr) > z * sd))


def rescored(row: dict, commit: str, consistency: bool | None = None, residual_scale: bool | None = None,
             on_estimates: bool = False, noise_weight: bool | None = None) -> dict | None:
    """The row as the current code's `focusfit.fit_metadata` would end it, from the row's stored fits (every
    family's corrected focus, the per-frame estimates' bootstrap spread and systematic errors): the capture's error
    scale (`error_scale`, with the residual scale), the family chosen with it and with the nearest fitted frame's
    error taken larger (`choice_systematic`; `score_families`, `select`; its
    corrected focus the row's fit of that family), the corrected focus's standard error (`corrected_sd`, times
    max(1, `frame_consistency`) with the consistency scale), the frames reported undetermined and whether their 95 %
    intervals hold the truth. Everything before the choice is the row's; the bootstrap's support and the settings'
    intervals are the row's too (they need the replicates), so a row whose family changed keeps its old `support`
    (`family_rescored` says it changed). consistency, residual_scale: with or without the consistency scale (issue
    32, off) and the residual scale (`focusfit.SCALE_BY_RESIDUALS`); None: as the code. on_estimates: the families
    refitted to the row's per-frame estimates first (`focusfit.fit_on_estimates`, as `fit_metadata` does with
    `FAMILIES_ON_ESTIMATES`); False: the row's own fits. Frames the row left out (`frames_noise_dominated`,
    `frames_left_out_on_bound`) count nothing, and get `focusfit.left_out_sd`. noise_weight: with on_estimates, the
    frames' working weights from the row's noise shares (`focusfit.signal_weight`, `WEIGHT_BY_NOISE_SHARE`; None: as
    the code; rows without noise shares weigh every frame alike). None for rows without the stored fits."""
    from aat_deploy.diagnose import focusfit as ff

    fams = {x["family"]: x for x in row.get("families") or []}
    if row.get("family") not in fams or "per_frame" not in fams or row.get("frame_systematic_d") is None:
        return None
    rep = np.asarray(fams["none"]["true_d"], np.float64)
    fits = {k: ff.FamilyFit(k, int(x["k"]), {}, np.asarray(x["true_d"], np.float64), 0.0) for k, x in fams.items()}
    exc = np.asarray(row.get("frames_noise_dominated") or np.zeros(rep.shape[-1], bool), bool)[None]
    if row.get("frames_left_out_on_bound"):  # left out because its estimate sat on its bound: as a noise-dominated one
        exc = exc | np.asarray(row["frames_left_out_on_bound"], bool)[None]
    sd = np.asarray(row["frame_focus_sd_d"], np.float64)
    sd = np.where(np.isfinite(sd), sd, 0.0)  # a left-out frame's is null
    sys_d = np.asarray(row["frame_systematic_d"], np.float64)
    frames = (np.isfinite(rep) & ~exc).astype(np.float64)
    old = fits[row["family"]].true_d[0]
    quant = ff.quantiser(np.unique(np.round(rep[np.isfinite(rep)], 9)))  # every reported value's grid, as the fit's
    if "quantisation" in fits and quant is not None:
        fits["quantisation"].detail = {"quantiser": quant[0], "step_d": quant[1]}
    share = np.asarray(row["frame_noise_share"], np.float64).reshape(rep.shape) if row.get("frame_noise_share") else None
    use_w = ff.WEIGHT_BY_NOISE_SHARE if noise_weight is None else noise_weight
    aw = ff.signal_weight(share if on_estimates and use_w else None, frames)
    if on_estimates:
        fits = ff.fit_on_estimates(fits, rep, sd, frames, sys_d, quant, weight=aw)
    use_scale = ff.SCALE_BY_RESIDUALS if residual_scale is None else residual_scale
    sys_c = ff.choice_systematic(sd, sys_d, frames, rep)  # the nearest fitted frame's, for the choice
    scale = ff.error_scale(fits, sd, frames, sys_c) if use_scale else 1.0
    sys_s = ff.scaled_systematic(sd, sys_c, scale)
    ff.score_families(fits, sd, frames, sys_s)
    fit = ff.select(fits)
    cons = ff.frame_consistency(fit, rep, fits["per_frame"].true_d, sd, frames, sys_d, weight=aw)
    on = ff.SCALE_BY_CONSISTENCY if consistency is None else consistency
    tsd = ff.corrected_sd(fit, rep, sd, frames, sys_d, at=(frames > 0) | exc, weight=aw) * (np.maximum(1.0, cons) if on else 1.0)
    tsd = ff.left_out_sd(fit, rep, frames, exc, tsd)
    und = (tsd >= ff.UNDETERMINED_SD_D) & ((frames > 0) | exc)
    true_d = old - np.asarray(row["corrected_err_d"], np.float64)  # the row's truth (to 1e-4 D)
    err = fit.true_d[0] - true_d
    z = 1.959964
    covers = [bool(abs(c - t) <= z * e) for c, t, e, u in zip(fit.true_d[0], true_d, tsd[0], und[0]) if u]
    return {**row, "family": fit.name, "family_ok": fit.name == row.get("family_true", fit.name),
            "family_rescored": fit.name != row["family"], "corrected_err_d": err.round(4).tolist(),
            "corrected_max_err_d": float(np.abs(err).max()), "error_scale": round(scale, 4),
            "families": [{"family": k, "k": f.k, "score": f.score, "true_d": f.true_d.tolist()} for k, f in fits.items()],
            "corrected_sd_d": np.round(tsd, 5).tolist(), "frame_consistency": np.round(cons, 3).tolist(),
            "frames_undetermined": int(und[0].sum()), "undetermined_covers": covers, "rescored_from": row.get("commit"),
            "commit": commit}


SYSTEMATIC_GRID_D = (0.005, 0.0075, 0.01, 0.013, 0.015, 0.02, 0.025, 0.03, 0.04, 0.05)


def rechosen(row: dict, systematic_d: float) -> str | None:
    """The family the focus fit of this row's set chooses with `focusfit.SYSTEMATIC_D` = systematic_d, from the
    row's stored fits (every family's corrected focus, the per-frame estimates' bootstrap spread): the choice
    `focusfit.score_families` makes, not the bootstrap's support. None for rows without the fits (older runs)."""
    from aat_deploy.diagnose import focusfit as ff

    fams = row.get("families") or []
    if not fams or any(x.get("true_d") is None for x in fams) or row.get("frame_focus_sd_d") is None:
        return None
    fits = {x["family"]: ff.FamilyFit(x["family"], int(x["k"]), {}, np.asarray(x["true_d"], np.float64), 0.0)
            for x in fams}
    sd = np.asarray(row["frame_focus_sd_d"], np.float64)
    # per-frame systematic errors (rows from issue 32's level sensitivity on): the same factors at this setting
    sys_d = (np.asarray(row["frame_systematic_d"], np.float64) * systematic_d / ff.SYSTEMATIC_D
             if row.get("frame_systematic_d") else systematic_d)
    ff.score_families(fits, sd, np.ones_like(sd), sys_d)
    return ff.select(fits).name


def systematic_table(rows: list[dict]) -> float | None:
    """Family right per setting of the family choice's systematic allowance on these rows (`rechosen`), and the
    setting that gets the most right (ties: the one nearest the rows' rms per-frame error, the allowance's
    meaning: what the per-frame estimates get wrong beyond their bootstrap spread). Tune on the tuning capture's
    rows only (scene 2029), then report the evaluation rows at the chosen setting."""
    from aat_deploy.diagnose import focusfit as ff

    rows = [r for r in {(r["capture"], r["kind"]): r for r in rows}.values() if rechosen(r, ff.SYSTEMATIC_D)]
    if not rows:
        print("no rows with the stored fits (families' true_d, frame_focus_sd_d)")
        return None
    same = sum(rechosen(r, ff.SYSTEMATIC_D) == r["family"] for r in rows)
    rms = float(np.sqrt(np.mean(np.concatenate([np.square(r["frame_err_d"]) for r in rows]))))
    print(f"\n{len(rows)} sets ({', '.join(sorted({r['capture'] for r in rows}))}); rechosen at the code's "
          f"SYSTEMATIC_D = {ff.SYSTEMATIC_D}: {same}/{len(rows)} as the run chose; rms per-frame error {rms:.4f} D\n")
    print("| systematic allowance (D) | family right | 95 % interval | wrong (set: chosen) |")
    print("|---|---|---|---|")
    scores = []
    for sd in SYSTEMATIC_GRID_D:
        got = [(r, rechosen(r, sd)) for r in rows]
        ok = sum(g == r["family_true"] for r, g in got)
        lo, hi = wilson(ok, len(rows))
        wrong = ", ".join(f"{r['capture']} {r['kind']}: {g}" for r, g in got if g != r["family_true"])
        print(f"| {sd} | {ok}/{len(rows)} | {100 * lo:.0f}-{100 * hi:.0f} % | {wrong or '-'} |")
        scores.append((ok, -abs(sd - rms), sd))
    best = max(scores)[2]
    print(f"\nmost right (ties: nearest the rms per-frame error): {best} D")
    return best


def focus_fit_only(model, twins, data: list, chain: str = "") -> dict:
    """The first round's focus fit alone (`fitters.fit_focus_metadata` on the twin without extra effects, binned
    as the diagnosis bins it, with its binning correction), in the diagnosis's answer layout. chain: effects in the
    twin instead (comma-separated, at their default settings: a later round's twin, e.g. the capture's own
    noise,vignetting,raw_pipeline; a probe, not what the diagnosis's first round fits)."""
    from aat_deploy.diagnose import fitters
    from aat_deploy.diagnose.search import DiagnoseConfig
    from aat_deploy.render import effects as fx

    cfg = DiagnoseConfig()
    effects = fx.parse(chain.split(",")) if chain else []
    factor = max(1, min(8, data[0].frames.shape[-1] // cfg.search_px))
    full = [fitters.fit_curves(twins.render(c, c.aif_linear, effects, seed=cfg.seed + i), factor)
            for i, c in enumerate(data)]
    state = fitters.FitState(twins, data, [c.aif_linear for c in data], effects, fx.make, factor, cfg.fit_boot,
                             cfg.seed, {}, full)
    rep = fitters.fit_focus_metadata(state).report
    return {"focus": {**rep["focus_fit"], "corrected_focus": rep["corrected_focus"]}, "ranked_effects": [],
            "image_effects": [], "causes": [], "verdict": None}


def _list(xs) -> str:
    return ", ".join(f"{x:.3f}" for x in xs)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion k / n."""
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    c = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    m = (p + z * z / (2 * n)) / (1 + z * z / n)
    return (max(0.0, m - c), min(1.0, m + c))


def table(rows: list[dict]) -> None:
    """The benchmark's table and its summary lines; a set in several rows (files) counts once, its last row."""
    rows = sorted({(r["capture"], r["kind"]): r for r in rows}.values(), key=lambda r: r["capture"])
    caps = sorted({r["capture"] for r in rows})
    print(f"\n{len(rows)} sets, {len(caps)} captures (per capture: {', '.join(caps)}; code "
          f"{', '.join(sorted({str(r.get('commit')) for r in rows}))})\n")
    print("| set | captures | family right | families chosen | corrected focus max error (D), per capture | "
          "per-frame max error (D) | frames on a bound | frames undetermined | focus metadata named | a cause |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    order = list(kinds())
    for kind in sorted({r["kind"] for r in rows}, key=order.index):
        rs = [r for r in rows if r["kind"] == kind]
        fams: dict = {}
        for r in rs:
            fams[r["family"]] = fams.get(r["family"], 0) + 1
        print(f"| {kind} | {len(rs)} | {sum(r['family_ok'] for r in rs)}/{len(rs)} | "
              f"{', '.join(f'{k} {v}' for k, v in sorted(fams.items(), key=lambda x: str(x[0])))} | "
              f"{_list(r['corrected_max_err_d'] for r in rs)} | {_list(r['frame_max_err_d'] for r in rs)} | "
              f"{sum(r['frames_on_bound'] for r in rs)} | {sum(r.get('frames_undetermined') or 0 for r in rs)} | "
              f"{sum(r['focus_named'] for r in rs)}/{len(rs)} | "
              f"{sum(r.get('focus_cause', False) for r in rs)}/{len(rs)} |")
    n, ok = len(rows), sum(r["family_ok"] for r in rows)
    lo, hi = wilson(ok, n)
    print(f"\nfamily right: {ok}/{n} ({100 * ok / max(n, 1):.0f} %, 95 % interval {100 * lo:.0f}-{100 * hi:.0f} %; "
          "target >= 90 %)")
    err = [r for r in rows if r["kind"] != "none"]
    # a set with a frame the fit reports as undetermined (`focusfit.UNDETERMINED_SD_D`) is not counted as
    # corrected within 0.02 D, whatever its point value: it is its own row
    und = [r for r in err if r.get("frames_undetermined")]
    within = sum(r["corrected_max_err_d"] <= 0.02 and not r.get("frames_undetermined") for r in err)
    lo, hi = wilson(within, len(err))
    e = np.array([r["corrected_max_err_d"] for r in err])
    if len(e):
        rng = np.random.default_rng(0)
        boot = [np.mean(rng.choice(e, len(e))) for _ in range(2000)]
        print(f"corrected focus within 0.02 D of the truth in every frame: {within}/{len(err)} sets with an error "
              f"({100 * lo:.0f}-{100 * hi:.0f} %); largest error per set: mean {e.mean():.3f} D (95 % bootstrap "
              f"{np.quantile(boot, 0.025):.3f}-{np.quantile(boot, 0.975):.3f}), median {np.median(e):.3f}, max "
              f"{e.max():.3f}; the reported focus was off by up to {np.mean([r['reported_max_err_d'] for r in err]):.3f} "
              "D on average")
        lo, hi = wilson(len(und), len(err))
        if any("frames_undetermined" in r for r in err):  # rows from before the flag do not say
                print(f"sets with a frame reported undetermined (not counted as within 0.02 D): {len(und)}/{len(err)} "
                  f"({100 * lo:.0f}-{100 * hi:.0f} %)" + "".join(
                      f"; {r['capture']} {r['kind']}: {r['frames_undetermined']} frame(s), max error "
                      f"{r['corrected_max_err_d']:.3f} D" + (
                          f", its 95 % interval containing the truth in {sum(r['undetermined_covers'])}/"
                          f"{len(r['undetermined_covers'])}" if r.get("undetermined_covers") is not None else "")
                      for r in und))
        over = [r for r in err if r["corrected_max_err_d"] > 0.02 and not r.get("frames_undetermined")]
        print("sets over 0.02 D with every frame reported determined: " + (", ".join(
            f"{r['capture']} {r['kind']} {r['corrected_max_err_d']:.3f} D" for r in over) or "none"))
        flags = [(np.abs(r["corrected_err_d"]), undetermined_frames(r), r.get("undetermined_covers") or [])
                 for r in err if r.get("corrected_sd_d")]
        if flags:  # frame by frame: a determined frame claims a corrected distance, an undetermined one does not
            det = np.concatenate([e[~u] for e, u, _ in flags])
            cov = [c for _, _, cs in flags for c in cs]
            print(f"frames reported determined within 0.02 D of the truth: {int(np.sum(det <= 0.02))}/{len(det)}; "
                  f"frames reported undetermined: {sum(int(u.sum()) for _, u, _ in flags)}, their 95 % interval "
                  f"holding the truth in {sum(cov)}/{len(cov)}")
            # are the standard errors honest? every frame's 95 % interval (corrected +- 1.96 SE) over
            # the sets whose family has any (not `none`)
            zs = {}
            for r in err:
                if r.get("corrected_sd_d") and np.any(r["corrected_sd_d"]):
                    with np.errstate(divide="ignore", invalid="ignore"):
                        zs.setdefault(r["capture"], []).append(
                            np.abs(r["corrected_err_d"]) / np.asarray(r["corrected_sd_d"], np.float64)[0])
            if zs:
                z = {c: np.concatenate(v) for c, v in zs.items()}
                every = np.concatenate(list(z.values()))
                # a frame with a standard error of 0 (a fitted frame under `none`) has no ratio: not printed as inf
                has = every[np.isfinite(every)]
                print(f"frames whose 95 % interval holds the truth: {int(np.sum(every <= 1.959964))}/{len(every)} ("
                      + ", ".join(f"{c} {int(np.sum(v <= 1.959964))}/{len(v)}" for c, v in sorted(z.items()))
                      + f"); largest |error| / standard error {f'{has.max():.2f}' if len(has) else 'none'}"
                      + (f" (frames with a standard error of 0, no ratio: {len(every) - len(has)})"
                         if len(has) < len(every) else ""))
    un = [r for r in rows if r["kind"] == "none"]
    if un:
        bad = sum(r["focus_named"] or r["family"] != "none" for r in un)
        how = "family other than none; the focus fit alone names no effect" if all(r.get("fit_only") for r in un) \
            else "family other than none, or focus_metadata named"
        print(f"untouched copies blaming focus metadata ({how}): {bad}/{len(un)}")
    whole = [r for r in err if not r.get("fit_only")]
    if whole:
        named = sum(r["focus_named"] for r in whole)
        cause = sum(r.get("focus_cause", False) for r in whole)
        lo, hi = wilson(cause, len(whole))
        verdicts: dict = {}
        for r in whole:
            verdicts[r["verdict"]] = verdicts.get(r["verdict"], 0) + 1
        print(f"sets with an error: focus metadata named in {named}/{len(whole)}, a cause (explains the gap) in "
              f"{cause}/{len(whole)} ({100 * lo:.0f}-{100 * hi:.0f} %); verdicts "
              + ", ".join(f"{k} {v}" for k, v in sorted(verdicts.items(), key=lambda x: str(x[0]))))
    bound = sum(r["frames_on_bound"] > 0 for r in rows)
    print(f"sets with a per-frame estimate on its search bound while the truth is not there: {bound}/{n}")
    if any("frames_left_out_on_bound" in r for r in rows):  # rows from the code that leaves such frames out
        out = sum(any(r.get("frames_left_out_on_bound") or []) for r in rows)
        print(f"sets with a frame left out because its estimate sat on its search bound (no estimate, undetermined "
              f"unless its family reaches it; `focusfit.LEAVE_OUT_ON_BOUND`): {out}/{n}")
    for label, key in (("wall clock", "seconds"), ("CPU time, all threads", "cpu_seconds")):
        t = [r[key] for r in rows if r.get(key)]
        if t:
            what = "the focus fit alone" if all(r.get("fit_only") for r in rows) else "diagnosing a set"
            print(f"{what}, {label}: {np.mean(t):.0f} s on average ({min(t):.0f}-{max(t):.0f} s, {len(t)} sets)")


def compare(old: list[dict], new: list[dict]) -> None:
    """Two runs of the same sets (e.g. before and after a change of the standard errors): per set in both, whether
    the family and the corrected focus are the same, how far the corrected focus's standard errors moved (largest
    relative change over the frames) and the frames reported undetermined before and after."""
    a = {(r["capture"], r["kind"]): r for r in old}
    b = {(r["capture"], r["kind"]): r for r in new}
    both = sorted(set(a) & set(b))
    print(f"\n{len(both)} sets in both\n")
    print("| set | family same | corrected focus same (to 1e-4 D) | standard errors: largest relative change | "
          "undetermined before -> after | verdict and effects named same |")
    print("|---|---|---|---|---|---|")
    moved = []
    for key in both:
        x, y = a[key], b[key]
        sx, sy = np.asarray(x.get("corrected_sd_d") or [[0.0]]), np.asarray(y.get("corrected_sd_d") or [[0.0]])
        rel = float(np.max(np.abs(sy - sx) / np.maximum(sx, 1e-12))) if sx.shape == sy.shape and sx.any() else 0.0
        moved.append(rel)
        same_corr = np.allclose(x["corrected_err_d"], y["corrected_err_d"], atol=1e-4)
        print(f"| {key[0]} {key[1]} | {'yes' if x['family'] == y['family'] else 'NO'} | "
              f"{'yes' if same_corr else 'NO'} | {100 * rel:.2f} % | "
              f"{int(undetermined_frames(x).sum())} -> {int(undetermined_frames(y).sum())} | "
              f"{'yes' if (x.get('verdict'), x.get('named')) == (y.get('verdict'), y.get('named')) else 'NO'} |")
    fams = sum(a[k]["family"] == b[k]["family"] for k in both)
    corr = sum(np.allclose(a[k]["corrected_err_d"], b[k]["corrected_err_d"], atol=1e-4) for k in both)
    same = sum((a[k].get("verdict"), a[k].get("named")) == (b[k].get("verdict"), b[k].get("named")) for k in both)
    print(f"\nsame family in {fams}/{len(both)}, same corrected focus in {corr}/{len(both)}; standard errors moved "
          f"by more than 1 % in {sum(m > 0.01 for m in moved)} set(s); same verdict and effects named in "
          f"{same}/{len(both)}")
    # frames that became undetermined in sets every frame of which was within 0.02 D before: precision given up
    fine = [k for k in both if a[k]["kind"] != "none" and a[k]["corrected_max_err_d"] <= 0.02]
    new_und = sum(int(np.sum(undetermined_frames(b[k]) & ~undetermined_frames(a[k]))) for k in fine)
    outside = [(k, reported_outside(a[k]), reported_outside(b[k])) for k in both]
    outside = [(k, x, y) for k, x, y in outside if x is not None and y is not None]
    print(f"sets whose reported focus lies outside its corrected focus's 95 % interval (the systematic part "
          f"included) in some frame (`verdict.focus_measured`'s test): {sum(x for _, x, _ in outside)} before, "
          f"{sum(y for _, _, y in outside)} after, of {len(outside)}; changed: "
          + (", ".join(f"{k[0]} {k[1]}" for k, x, y in outside if x != y) or "none"))
    print(f"frames undetermined: {sum(int(undetermined_frames(a[k]).sum()) for k in both)} before, "
          f"{sum(int(undetermined_frames(b[k]).sum()) for k in both)} after; newly undetermined in the {len(fine)} "
          f"sets with an error that were within 0.02 D before: {new_und}")
    by_scene(a, b, both)


def by_scene(a: dict, b: dict, both: list) -> None:
    """Per capture, the sets in both runs against issue 32's targets, before -> after: family right; corrected
    focus within 0.02 D of the truth in every frame with no frame reported undetermined (the table's count) and in
    every frame whatever the flags (undetermined: `undetermined_frames`, from the rows' standard errors, the rule of
    the current code); the untouched copy blaming focus; sets with an estimate on a bound; the per-frame
    estimates' largest error a set (median over the sets; noise-dominated frames, which have none, left out); and the
    frames without an estimate of their own (noise-dominated)."""
    print("\n| capture | sets | family right | within 0.02 D (no frame undetermined) | within 0.02 D (every frame) | "
          "untouched blaming focus | sets with an estimate on a bound | per-frame largest error, median (D) | "
          "frames without an estimate |")
    print("|---|---|---|---|---|---|---|---|---|")
    for cap in sorted({k[0] for k in both}):
        keys = [k for k in both if k[0] == cap]
        cells = []
        for f in (lambda r: r["family_ok"],
                  lambda r: r["kind"] != "none" and r["corrected_max_err_d"] <= 0.02 and not undetermined_frames(r).any(),
                  lambda r: r["kind"] != "none" and r["corrected_max_err_d"] <= 0.02,
                  lambda r: r["kind"] == "none" and (r["focus_named"] or r["family"] != "none"),
                  lambda r: r["frames_on_bound"] > 0):
            cells.append(f"{sum(bool(f(a[k])) for k in keys)} -> {sum(bool(f(b[k])) for k in keys)}")
        med = [np.median([r[k]["frame_max_err_d"] if r[k].get("frame_max_err_d") is not None else np.nan
                          for k in keys]) for r in (a, b)]
        nodom = [sum(int(np.sum(r[k].get("frames_noise_dominated") or [])) for k in keys) for r in (a, b)]
        print(f"| {cap} | {len(keys)} | " + " | ".join(cells) + f" | {med[0]:.3f} -> {med[1]:.3f} | "
              f"{nodom[0]} -> {nodom[1]} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--captures", type=int, default=3, help="the sample and this many minus one captures like it")
    ap.add_argument("--folders", nargs="+", help="these capture folders instead (e.g. the tuning capture "
                    "scene2029, rendered like the others with --scene-seed 2029 --seed 4, which is not in the "
                    "benchmark: focusfit.SYSTEMATIC_D was set on it)")
    ap.add_argument("--fresh", type=int, metavar="N", help="the first N fresh test captures (FRESH_SCENES: scenes "
                    "2030-2033, declared before they were rendered) instead; the monotone curve bends either way "
                    "by their order, as for --captures")
    ap.add_argument("--fresh2", type=int, metavar="N", help="the first N of the second fresh test captures "
                    "(FRESH_SCENES_2: scenes 2034-2037, declared before they were rendered) instead")
    ap.add_argument("--fresh3", type=int, metavar="N", help="the first N of the third fresh test captures "
                    "(FRESH_SCENES_3: scenes 2038-2041, declared before they were rendered) instead")
    ap.add_argument("--fresh4", type=int, metavar="N", help="the first N of the fourth fresh test captures "
                    "(FRESH_SCENES_4: scenes 2042-2045, declared before they were rendered) instead")
    ap.add_argument("--fresh5", type=int, metavar="N", help="the first N of the fifth fresh test captures "
                    "(FRESH_SCENES_5: scenes 2046-2049, declared before they were rendered) instead")
    ap.add_argument("--fresh6", type=int, metavar="N", help="the first N of the sixth fresh test captures (far scenes "
                    "with little texture, chosen from scene seeds 2050- by FRESH6's declared rule before any was "
                    "rendered: a held-out test of the noise rule) instead")
    ap.add_argument("--fresh7", type=int, metavar="N", help="the first N of the seventh fresh test captures (the "
                    "sixth round's rule on scene seeds 2183-, declared before any was rendered or screened) instead")
    ap.add_argument("--fresh8", type=int, metavar="N", help="the first N of the eighth fresh test captures (the "
                    "sixth round's rule on scene seeds 2370-, declared before any was rendered or screened) instead")
    ap.add_argument("--fresh9", type=int, metavar="N", help="the first N of the ninth fresh test captures (the "
                    "sixth round's rule on scene seeds 2473-, declared before any was rendered or screened) instead")
    ap.add_argument("--fresh10", type=int, metavar="N", help="the first N of the tenth fresh test captures (the "
                    "sixth round's rule on scene seeds 2723-, declared before any was rendered or screened) instead")
    ap.add_argument("--fresh11", type=int, metavar="N", help="the first N of the eleventh fresh test captures (the "
                    "sixth round's rule on scene seeds 3240-, declared before any was rendered or screened) instead")
    ap.add_argument("--kinds", help=f"only these sets (comma-separated of {', '.join(kinds())})")
    ap.add_argument("--sets", help="only these sets, in this order (comma-separated capture:kind, e.g. "
                    "scene2027:monotone; captures numbered as without it, so a set is the same set)")
    ap.add_argument("--model", default=str(ROOT / "models" / "rf50_dfvnet_aat_field.onnx"))
    ap.add_argument("--rounds", type=int, default=3, help="greedy rounds (aat-diagnose's default: 3)")
    ap.add_argument("--threads", type=int, default=2, help="the DfF model's threads (1 in a heavy-job lane)")
    ap.add_argument("--cache", default=str(CACHE), help="rendered captures and the sets' copies")
    ap.add_argument("--out", default=str(RESULTS_FILE), help="results, one JSON line per set (resumable)")
    ap.add_argument("--fit-only", action="store_true", help="only the focus fit of the first round (the twin "
                    "without extra effects), not the whole diagnosis: minutes instead of a quarter hour per set, "
                    "for development; its rows are marked fit_only")
    ap.add_argument("--fit-chain", default="", help="with --fit-only: these effects in the twin (comma-separated, "
                    "default settings; e.g. noise,vignetting,raw_pipeline, how the captures were made), as a later "
                    "round's focus fit sees them; rows carry fit_chain")
    ap.add_argument("--noise-floor", action="store_true", help="with --fit-chain: the twin's noise carried by its "
                    "expectation in the focus sweep (`fitters.NOISE_FLOOR`, `noisefloor`); rows carry noise_floor")
    ap.add_argument("--table", nargs="*", metavar="RESULTS", help="only print the table of these results files")
    ap.add_argument("--like", nargs="+", metavar="RESULTS", help="with --table: only the sets (capture, kind) these "
                    "results files have (to tabulate an older run on the sets of a newer one)")
    ap.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"), help="only compare two results files (each may be several joined by commas) set by set "
                    "(family, corrected focus, its standard errors, undetermined frames)")
    ap.add_argument("--rescore", nargs=2, metavar=("OLD", "NEW"), help="only rewrite a results file's rows from their "
                    "stored fits as the current code ends the focus fit (`rescored`: standard errors, undetermined "
                    "frames) into NEW, for --compare OLD NEW")
    ap.add_argument("--consistency", choices=("on", "off"), help="with --rescore: with or without the consistency "
                    "scale (`focusfit.frame_consistency`; default: as the code, focusfit.SCALE_BY_CONSISTENCY)")
    ap.add_argument("--residual-scale", choices=("on", "off"), help="with --rescore: with or without the capture's "
                    "error scale (`focusfit.error_scale`; default: as the code, focusfit.SCALE_BY_RESIDUALS)")
    ap.add_argument("--systematic", nargs="+", metavar="RESULTS", help="only print the family choice's hits per "
                    "setting of its systematic allowance (focusfit.SYSTEMATIC_D) on these results (rows with the "
                    "stored fits); tune it on the tuning capture's rows only")
    a = ap.parse_args()
    if a.fit_chain and not a.fit_only:
        raise SystemExit("--fit-chain: only with --fit-only")
    if a.noise_floor:
        from aat_deploy.diagnose import fitters

        fitters.NOISE_FLOOR = True
    if a.table is not None:
        rows = [json.loads(x) for f in (a.table or [a.out]) for x in Path(f).read_text().splitlines() if x.strip()]
        if a.like:  # only the sets (capture, kind) of these results files
            keep = {(r["capture"], r["kind"]) for f in a.like for r in map(json.loads, Path(f).read_text().splitlines())}
            rows = [r for r in rows if (r["capture"], r["kind"]) in keep]
        table(rows)
        return
    if a.compare:
        old, new = ([json.loads(x) for g in f.split(",") for x in Path(g).read_text().splitlines() if x.strip()]
                    for f in a.compare)  # each side: one results file, or several joined by commas
        compare(old, new)
        return
    if a.rescore:
        commit = os.environ.get("AAT_COMMIT") or subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
        src, dst = Path(a.rescore[0]), Path(a.rescore[1])
        if dst.exists():  # the input itself included: rescoring never overwrites a results file
            raise SystemExit(f"{dst}: exists; --rescore writes a new file (choose another name)")
        rows = [json.loads(x) for x in src.read_text().splitlines() if x.strip()]
        new = [rescored(r, commit, None if a.consistency is None else a.consistency == "on",
                        None if a.residual_scale is None else a.residual_scale == "on") for r in rows]
        with atomic_file(dst) as tmp:
            tmp.write_text("".join(json.dumps(r) + "\n" for r in new if r is not None))
        print(f"{sum(r is not None for r in new)}/{len(rows)} rows rescored into {a.rescore[1]}")
        return
    if a.systematic:
        systematic_table([json.loads(x) for f in a.systematic for x in Path(f).read_text().splitlines() if x.strip()])
        return
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from tqdm import tqdm

    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.diagnose.search import DiagnoseConfig, diagnose
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.infer.model import DfFModel

    names = a.kinds.split(",") if a.kinds else list(kinds())
    unknown = set(names) - set(kinds())
    if unknown:
        raise SystemExit(f"--kinds: unknown {', '.join(sorted(unknown))}; known: {', '.join(kinds())}")
    cache, out = Path(a.cache), Path(a.out)
    caps = ([Path(f) for f in a.folders] if a.folders else fresh_folders(a.fresh, cache) if a.fresh
            else fresh_folders(a.fresh2, cache, FRESH_SCENES_2, "--fresh2") if a.fresh2
            else fresh_folders(a.fresh3, cache, FRESH_SCENES_3, "--fresh3") if a.fresh3
            else fresh_folders(a.fresh4, cache, FRESH_SCENES_4, "--fresh4") if a.fresh4
            else fresh_folders(a.fresh5, cache, FRESH_SCENES_5, "--fresh5") if a.fresh5
            else fresh_folders(a.fresh6, cache, fresh6_scenes(a.fresh6, cache), "--fresh6") if a.fresh6
            else fresh_folders(a.fresh7, cache, fresh6_scenes(a.fresh7, cache, FRESH7_CANDIDATES, FRESH7_NOISE_SEEDS,
                                                              "fresh7"), "--fresh7") if a.fresh7
            else fresh_folders(a.fresh8, cache, fresh6_scenes(a.fresh8, cache, FRESH8_CANDIDATES, FRESH8_NOISE_SEEDS,
                                                              "fresh8"), "--fresh8") if a.fresh8
            else fresh_folders(a.fresh9, cache, fresh6_scenes(a.fresh9, cache, FRESH9_CANDIDATES, FRESH9_NOISE_SEEDS,
                                                              "fresh9"), "--fresh9") if a.fresh9
            else fresh_folders(a.fresh10, cache, fresh6_scenes(a.fresh10, cache, FRESH10_CANDIDATES,
                                                               FRESH10_NOISE_SEEDS, "fresh10"), "--fresh10") if a.fresh10
            else fresh_folders(a.fresh11, cache, fresh6_scenes(a.fresh11, cache, FRESH11_CANDIDATES,
                                                               FRESH11_NOISE_SEEDS, "fresh11"), "--fresh11") if a.fresh11
            else capture_folders(a.captures, cache))
    done = {(r["capture"], r["kind"]) for r in map(json.loads, out.read_text().splitlines())} if out.exists() else set()
    # kind by kind (every capture's untouched copy first): a run stopped early still covers every capture
    todo = [(k, c, n) for n in names for k, c in enumerate(caps) if (c.name, n) not in done]
    if a.sets:  # a chosen order of (capture, kind) pairs, each keeping its capture's index
        order = [tuple(x.split(":")) for x in a.sets.split(",")]
        unknown = [x for x in order if x not in {(c.name, n) for _, c, n in todo} | done]
        if unknown:
            raise SystemExit(f"--sets: unknown {', '.join(':'.join(x) for x in unknown)}")
        todo = sorted((t for t in todo if (t[1].name, t[2]) in order), key=lambda t: order.index((t[1].name, t[2])))
    model = DfFModel(a.model, threads=a.threads)
    lens, _ = find_lens(model, None)
    src = find_surrogate(lens, None, a.threads)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows = [json.loads(x) for x in out.read_text().splitlines()] if out.exists() else []
    commit = os.environ.get("AAT_COMMIT") or subprocess.run(  # AAT_COMMIT: a run from an exported snapshot
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    bar = tqdm(todo, desc="sets", unit="set")
    for k, cap, kind in bar:
        bar.set_postfix_str(f"{cap.name} {kind}")
        true_m = np.asarray(json.loads((cap / "virtual_camera.json").read_text())["focus_m"], np.float64)
        true_d = 1.0 / np.sort(true_m)  # frames near to far (the files' and the diagnosis's order): diopters falling
        rep = reported_d(kind, true_d, k)
        root = make_copy(cap, cache / "sets" / cap.name / kind, 1.0 / rep)
        t0, c0 = time.time(), time.process_time()
        twins = make_renderer(model, lens, src, torch_free=True, threads=a.threads)  # a fresh render cache per set
        data = [load_capture_data(root / cap.name, model)]
        if a.fit_only:
            res = focus_fit_only(model, twins, data, a.fit_chain)
        else:
            res, _, _ = diagnose(model, twins, data, DiagnoseConfig(max_effects=a.rounds))
            (root / "diagnosis.json").write_text(json.dumps(res, indent=1, default=float))
        # the diagnosis sorts frames by reported distance: every error here keeps the true order
        row = {"capture": cap.name, **score(kind, kinds()[kind][0], true_d, rep, res),
               "seconds": round(time.time() - t0, 1), "cpu_seconds": round(time.process_time() - c0, 1),
               "model": Path(a.model).name, "fit_only": a.fit_only,
               **({"fit_chain": a.fit_chain} if a.fit_chain else {}), **({"noise_floor": True} if a.noise_floor else {}),
               "commit": commit}
        rows.append(row)
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        tqdm.write(f"{cap.name} {kind}: family {row['family']} ({'right' if row['family_ok'] else 'wrong'}), "
                   f"corrected max error {row['corrected_max_err_d']:.3f} D, {row['seconds']:.0f} s")
    table(rows)


if __name__ == "__main__":
    main()
