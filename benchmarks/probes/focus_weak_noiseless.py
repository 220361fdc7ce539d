"""Where the focus twin misfits the capture in the weak frames, with the noise off on both sides (issue 32, after
"The full well by photon transfer"; development scenes only). Understanding only: it chooses nothing.

The focus twin's expected curve of a region is log(S_twin + N): its noiseless focus measure S_twin (the binned sweep,
binning correction anchored at the frames) under the noise's expected floor N (`noisefloor`). The capture's is
log(M), M the noisy capture's measure. With the same scene rendered without noise (`make_sample_capture --effects
vignetting`: the same optics and development, only the noise left out) the capture's own noiseless measure S_cap is
known, and the misfit splits exactly into

    log(S_twin + N) - log(M) = [log(S_twin + N) - log(S_cap + N)]     the twin's *signal*, seen through the floor
                             + [log(S_cap + N) - log(M)]              the *noise* term: the floor against the noise
                                                                      the capture really has, given its content,

and the noise term again into the developed noise's own energy E = |lap(noisy - quiet)|^2 against N (its level,
region by region) and the cross term X = M - S_cap - E (= 2 lap(quiet) . lap(noisy - quiet); mean 0 for a linear
development and noise independent of the content). All per region, frame and channel of the binned frames
(`FIT_GRID`), channel means of the logs, each region's level over the frames removed (as the fit profiles it out)
and every frame's exposure gain removed (`focusrobust.frame_gains_log`), N at the full well the captures were
rendered with (`--full-well-e`, 8,000 e-: `aat-render --effects noise`'s default). Everything at the frames' true
focus (the copies report it).

Tables (per scene):
- per frame: the noise share at the truth (`focusfit.noise_share`), the residual terms (rms over the textured regions,
  log units) and their focus reading (the linearised per-frame shift sum_r s r / sum_r s^2 over the textured regions, s
  the twin's slope there, diopters; positive = the capture looks focused further out in diopters than it is);
- the per-frame estimates (`focusfit.frame_focus`, exposure-corrected, no floors nor weights) less the truth of: the
  quiet capture against the twin without noise (`quiet`), the quiet capture with the expected floor added against the
  twin with it (`quiet+N`), the noisy capture against the twin with it (`noisy`); and the full well
  `fitters.full_well_on_floor` fits on `quiet+N` and on `noisy` (so: which term moves the fitted full well);
- the signal term's candidates per frame: the twin's region brightness against the capture's (regions' median
  removed: vignetting / lighting) and the full-resolution twin (binned) against the binned sweep at the frames
  (should be 0: anchored there).

    python -m benchmarks.probes.focus_weak_noiseless --scene 3303 cache/p32/noise/scene3303quiet \\
        cache/bench_diagnose_focus/captures/scene3303 [--scene ...] [--per-channel] --out results/focus_weak_noiseless.md

`--per-channel`: the binning correction each channel's own under its floor (`anchors.PER_CHANNEL`; docs/diagnosis.md,
"Not the whole of it on 3303").
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import write_text_atomic

CHAIN = ("noise", "vignetting", "raw_pipeline")  # the focus twin's chain for these captures


def lap_energy(frames: np.ndarray, grid: tuple[int, int], other: np.ndarray | None = None) -> np.ndarray:
    """(R, S, C) region mean of the squared 3 x 3 Laplacian of binned frames (S, C, H, W), in their own units (the
    measure `compare.focus_curves` takes the log of, before any normalisation); with `other` (the same shape): of the
    cross term 2 lap(frames) lap(other)."""
    import cv2

    from aat_deploy.diagnose.compare import region_index

    s, c, h, w = frames.shape
    reg = region_index(h, w, grid).ravel()
    n_r = grid[0] * grid[1]
    cnt = np.bincount(reg, minlength=n_r)
    out = np.empty((n_r, s, c))

    def lap(x):
        return cv2.Laplacian(np.ascontiguousarray(x, np.float32), cv2.CV_32F, ksize=3).astype(np.float64)

    for i in range(s):
        for j in range(c):
            la = lap(frames[i, j])
            e = la ** 2 if other is None else 2 * la * lap(other[i, j])
            out[:, i, j] = np.bincount(reg, weights=e.ravel(), minlength=n_r) / cnt
    return out


def profiled(r: np.ndarray) -> np.ndarray:
    """(R, S) with every region's mean over the frames removed."""
    return r - r.mean(-1, keepdims=True)


def focus_reading(r: np.ndarray, slope: np.ndarray, used: np.ndarray) -> np.ndarray:
    """(S,) the per-frame focus shift (diopters) a level-profiled residual r = capture - twin (R, S) reads as, to first
    order: sum_r s r / sum_r s^2 over the used regions (s the twin's slope, log units per diopter)."""
    s, x = slope[used], r[used]
    return (s * x).sum(0) / np.maximum((s * s).sum(0), 1e-12)


def source_aif(scene_seed: int) -> np.ndarray:
    """(3, H, W) linear: the all-in-focus image the capture was rendered from, as `scripts.make_sample_capture` gave it
    to `aat-render` (16-bit sRGB PNG), where the capture folder's `gt_aif.png` (the twin's) is 8-bit sRGB."""
    from aat_deploy.io.color import linear_to_srgb, srgb_to_linear
    from scripts.make_sample_capture import sample_scene

    rgb, _ = sample_scene(scene_seed)
    return srgb_to_linear(np.round(linear_to_srgb(rgb) * 65535) / 65535).transpose(2, 0, 1).astype(np.float32)


def scene_report(scene: str, quiet: Path, noisy: Path, full_well_e: float, threads: int, work: Path) -> tuple[str, dict]:
    """Both tables for one scene, the twin rendered from the capture folder's `gt_aif.png` (as the diagnosis does) and
    from the 16-bit source the capture was rendered from (an oracle: a user has only the former)."""
    texts, rows = [], []
    for label in ("gt_aif.png", "16-bit source"):
        t, r = aif_report(scene, quiet, noisy, full_well_e, threads, work, label)
        texts.append(t)
        rows.append(r)
    return "".join(texts), {"scene": scene, "by_aif": rows}


def aif_report(scene: str, quiet: Path, noisy: Path, full_well_e: float, threads: int, work: Path,
               label: str) -> tuple[str, dict]:
    from aat_deploy.diagnose import anchors, fitters, noisefloor
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.diagnose import focusrobust as fr
    from aat_deploy.diagnose.binned import bin_frames
    from aat_deploy.diagnose.compare import focus_curves, region_brightness
    from aat_deploy.diagnose.gap import DiagnoseConfig
    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.lookup import find_lens, find_surrogate
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.infer.normalise import normalise_scale, normalise_stack
    from aat_deploy.render import effects as fx
    from aat_deploy.render.effects.noise import Noise
    from benchmarks import bench_diagnose_focus as bench

    model = DfFModel(str(bench.ROOT / "models" / "rf50_dfvnet_aat_field.onnx"), threads=threads)
    lens, _ = find_lens(model, None)
    twins = make_renderer(model, lens, find_surrogate(lens, None, threads), torch_free=True, threads=threads)
    true_m = np.sort(np.asarray(json.loads((noisy / "virtual_camera.json").read_text())["focus_m"], np.float64))
    q_true = np.sort(np.asarray(json.loads((quiet / "virtual_camera.json").read_text())["focus_m"], np.float64))
    if not np.allclose(true_m, q_true):
        raise SystemExit(f"{quiet} and {noisy} are not focused alike")
    dq = load_capture_data(bench.make_copy(quiet, work / f"{scene}_quiet", true_m) / quiet.name, model)
    dn = load_capture_data(bench.make_copy(noisy, work / f"{scene}_noisy", true_m) / noisy.name, model)
    if not np.allclose(dq.aif_linear, dn.aif_linear):
        raise SystemExit(f"{quiet} and {noisy} do not show the same scene")
    aif = dn.aif_linear if label == "gt_aif.png" else source_aif(int(scene))
    if aif.shape != dn.aif_linear.shape:
        raise SystemExit(f"scene {scene}: the source all-in-focus image is {aif.shape}, the capture's {dn.aif_linear.shape}")
    factor = max(1, min(8, dn.frames.shape[-1] // DiagnoseConfig().search_px))
    chain = fx.parse(list(CHAIN))
    seed = 0
    state = fitters.FitState(twins, [dn], [aif], chain, fx.make, factor, 0, seed, {}, None)
    raw = fitters.focus_sweep(state, correct=False, noise_floor=True)  # at the noise's default full well
    fw0 = float(noisefloor.noise_of(chain).params["full_well_e"])
    qchain = noisefloor.quiet([e for e in chain if not state.tb.has_stack_hook(e)])
    own = np.asarray(twins.true_focus(dn, chain, seed), np.float64).ravel()
    sweep = raw.with_correction(anchors.correction(raw.grid_d, [[anchors.anchor_deltas(
        state, qchain, [own], per_channel=anchors.PER_CHANNEL)[0]]]))  # --per-channel: each channel's own
    sweep = sweep.with_full_well(fw0 / full_well_e)
    truth = sweep.base_d.copy()
    used = sweep.weight[0] > 0

    # the captures' binned frames (white = 1, unnormalised) and their measures in the fit's units
    qb, nb_ = bin_frames(dq.frames, factor), bin_frames(dn.frames, factor)
    grid = ff.FIT_GRID

    def curves(stack):
        return focus_curves(normalise_stack(stack), grid)  # (R, S, C)

    def lum(stack):
        return region_brightness(normalise_stack(stack), grid)

    cap_q_c, cap_n_c = curves(qb), curves(nb_)
    noise = Noise(full_well_e=full_well_e)
    fac = noisefloor.developed_factor(chain, factor)
    floor_q = noisefloor.floor(qb, float(normalise_scale(qb)), noise.binned(factor), fac, grid)  # Q's units
    synth = np.log(np.exp(cap_q_c) + floor_q).mean(-1)

    def with_capture(d, cap, lum_):
        return dataclasses.replace(d, capture=cap[None], capture_lum=lum_[None])

    quiet_sw = with_capture(sweep.with_full_well(0.0), cap_q_c.mean(-1), lum(qb))
    synth_sw = with_capture(sweep, synth, lum(qb))
    noisy_sw = with_capture(sweep, cap_n_c.mean(-1), lum(nb_))

    def corrected(d):
        return dataclasses.replace(d, capture=d.capture - 2.0 * fr.frame_gains_log(d)[:, None, :])

    def estimate(d):
        c = corrected(d)
        return (ff.frame_focus(c, start=truth) - truth)[0]

    def fitted_fw(d):
        # full_well_on_floor's ratio is against the full well the sweep was made with (`full_well_e` here)
        fw, rep = fitters.full_well_on_floor(d, full_well_e)
        return fw

    # residuals capture - twin at the truth, gains removed, levels profiled (R, S)
    def residual(d):
        c = corrected(d)
        return profiled((c.capture - fr.twin_at(c, truth))[0])

    r_noisy, r_synth = residual(noisy_sw), residual(synth_sw)
    # the misfit twin - capture = -(capture - twin): signal term = twin vs synth; noise term = synth vs noisy
    t_signal = -r_synth  # log(S_twin + N) - log(S_cap + N)
    t_noise = r_synth - r_noisy  # log(S_cap + N) - log(M)
    # the noise term split in the captures' own (unnormalised, per channel) units
    s_c, m_c = lap_energy(qb, grid), lap_energy(nb_, grid)
    e_c = lap_energy(nb_ - qb, grid)
    x_c = lap_energy(qb, grid, nb_ - qb)
    fl_raw = noisefloor.floor(qb, 1.0, noise.binned(factor), fac, grid)
    t_level = profiled((np.log(s_c + fl_raw) - np.log(s_c + e_c)).mean(-1))  # the floor against the noise's own energy
    t_cross = profiled((np.log(s_c + e_c) - np.log(np.maximum(m_c, 1e-30))).mean(-1))  # the cross term
    # the noise term in those units differs from t_noise only by the exposure gains and the normalisation (global)
    slope = (ff.curves_at(sweep, np.broadcast_to((truth + 0.005)[:, None, :], sweep.capture.shape).copy())
             - ff.curves_at(sweep, np.broadcast_to((truth - 0.005)[:, None, :], sweep.capture.shape).copy()))[0] / 0.01
    share = ff.noise_share(sweep, truth)[0]
    e_energy_ratio = np.median((e_c / fl_raw)[used], axis=(0, 2))  # per frame
    x_share = np.median((x_c / np.maximum(s_c, 1e-30))[used], axis=(0, 2))  # cross term over the signal, per frame

    # each region's signal level in the twin against the capture (per channel, its mean over the frames of the
    # full-resolution twin's log measure less the quiet capture's, less its median over the regions: the stacks'
    # normalisations differ): profiled out exactly without noise, but not under an additive floor
    full_c = focus_curves(normalise_stack(bin_frames(twins.render(dn, aif, qchain, seed=seed), factor)), grid)  # (R, S, C)
    lev = (full_c - cap_q_c).mean(1, keepdims=True)
    lev = lev - np.median(lev[used], axis=0, keepdims=True)
    synth_lv = with_capture(sweep, np.log(np.exp(cap_q_c + lev) + floor_q).mean(-1), lum(qb))
    est = {"quiet": estimate(quiet_sw), "quiet+N": estimate(synth_sw), "noisy": estimate(noisy_sw),
           "quiet+N, levels": estimate(synth_lv)}
    fws = {"quiet+N": fitted_fw(synth_sw), "noisy": fitted_fw(noisy_sw), "quiet+N, levels": fitted_fw(synth_lv)}
    # the twin's exposure against the capture's, in white-level units (`TwinRenderer.linear` scales the all-in-focus
    # image by the 99.5th percentiles of the capture's frames and of the image): per frame, the binned capture's mean
    # over the binned twin's (no noise) at the truth; the floor in the capture's units is the twin's at a full well k
    # times as large (`SweepData.with_full_well(1 / k)`)
    tw_lin = np.clip(state.tb.linear(state.caps_b[0], state.aifs_b[0], qchain, seed), 0, None)
    k_f = nb_.reshape(len(nb_), -1).mean(1) / tw_lin.reshape(len(tw_lin), -1).mean(1)
    k = float(np.median(k_f))
    exp_sw = noisy_sw.with_full_well(1.0 / k)
    est["noisy, floor at the capture's exposure"] = estimate(exp_sw)
    est["noisy, robust, floor at the capture's exposure"] = (
        np.asarray(fr.prepare(exp_sw)[1]["frame_focus_d"][-1])[0] - truth[0])
    # what the focus fit does: the robust preparation (floors, weights) at the full well fitted on the noisy capture
    ratio = 0.0 if fws["noisy"] is None else full_well_e / fws["noisy"]
    est["noisy, robust"] = np.asarray(fr.prepare(noisy_sw.with_full_well(ratio))[1]["frame_focus_d"][-1])[0] - truth[0]
    # the signal term's candidates: brightness across the field, and the full-resolution twin against the sweep
    full = full_c.mean(-1)  # = fitters.fit_curves
    tw_lum = region_brightness(normalise_stack(np.clip(state.tb.linear(state.caps_b[0], state.aifs_b[0], qchain, seed),
                                                       0, None)), grid)
    b_res = lum(qb) - tw_lum  # (R, S) log capture over twin
    b_res = b_res - np.median(b_res, 0, keepdims=True)
    sweep_at = fr.twin_at(sweep.with_full_well(0.0), truth)[0]
    full_vs_sweep = profiled(full - sweep_at)
    full_vs_cap = profiled(full - cap_q_c.mean(-1))

    def rms(x):
        return np.sqrt(np.mean(x[used] ** 2, axis=0))

    lines = [f"\n### scene {scene}, the twin from {label} (quiet {quiet}, noisy {noisy}; N at {full_well_e:.0f} e-)\n",
             f"Per frame, over the textured regions ({int(used.sum())} of {used.size}): rms of each term (log units) and its focus reading (D; the level-profiled term as capture - twin).\n",
             "| frame | focus (D) | noise share | signal term rms | reads (D) | noise term rms | reads (D) | of it: floor vs "
             "noise energy rms | reads (D) | cross term rms | reads (D) | noise energy / floor (median) | cross / signal "
             "(median) |", "|" + "---|" * 13]
    for f in range(len(truth[0])):
        lines.append(
            f"| {f} | {truth[0, f]:.3f} | {share[f]:.2f} | {rms(t_signal)[f]:.3f} | "
            f"{focus_reading(-t_signal, slope, used)[f]:+.4f} | {rms(t_noise)[f]:.3f} | "
            f"{focus_reading(-t_noise, slope, used)[f]:+.4f} | {rms(t_level)[f]:.3f} | "
            f"{focus_reading(-t_level, slope, used)[f]:+.4f} | {rms(t_cross)[f]:.3f} | "
            f"{focus_reading(-t_cross, slope, used)[f]:+.4f} | {e_energy_ratio[f]:.3f} | {x_share[f]:+.3f} |")
    lines += ["", "Per-frame estimates less the truth (D; `frame_focus`, exposure-corrected, no floors or weights):\n",
              "| frame | quiet vs twin without noise | quiet+N vs twin with N | quiet with the twin's region levels, +N, vs "
              "twin with N | noisy vs twin with N | noisy, robust preparation at the fitted full well | noisy vs twin with N "
              "at the capture's exposure | the same, robust preparation |",
              "|---|---|---|---|---|---|---|---|"]
    for f in range(len(truth[0])):
        lines.append(f"| {f} | {est['quiet'][f]:+.4f} | {est['quiet+N'][f]:+.4f} | {est['quiet+N, levels'][f]:+.4f} | "
                     f"{est['noisy'][f]:+.4f} | "
                     f"{est['noisy, robust'][f]:+.4f} | {est['noisy, floor at the capture' + chr(39) + 's exposure'][f]:+.4f} | "
                     f"{est['noisy, robust, floor at the capture' + chr(39) + 's exposure'][f]:+.4f} |")
    lv = lev.mean(-1)[used, 0]
    # the floors themselves: the sweep's at the truth (linear between sweep steps) against the one on the capture's
    # own frames, each over its own signal (the stacks' normalisations cancel): log(N_twin / S_twin) - log(N_cap /
    # S_cap) per region, frame and channel
    g = sweep.grid_d
    u = np.interp(truth[0], g, np.arange(len(g)))
    i0 = np.clip(np.floor(u).astype(int), 0, len(g) - 2)
    t = (u - i0)[None, :, None]
    fl_tw = sweep.floor_c[0][:, i0] * (1 - t) + sweep.floor_c[0][:, i0 + 1] * t  # (R, S, C)
    sig_tw = np.exp(sweep.signal_c[0][:, i0] * (1 - t) + sweep.signal_c[0][:, i0 + 1] * t)
    nsr = np.log(fl_tw / sig_tw) - np.log(floor_q / np.exp(cap_q_c))
    nsr_c = np.median(nsr[used], axis=0)  # (S, C)
    flr = np.log(fl_tw) - np.log(floor_q)
    flr = flr - np.median(flr[used], axis=(0, 1), keepdims=True)
    flr_c = np.median(flr[used], axis=0)  # (S, C): the floors' ratio per frame and channel, its overall median removed
    lines += ["", "Full well `full_well_on_floor` fits (e-): on quiet+N "
              f"{fws['quiet+N']}, on quiet with the twin's region levels +N {fws['quiet+N, levels']}, on noisy "
              f"{fws['noisy']} (rendered {full_well_e:.0f}).", "",
              f"The capture's exposure over the twin's (white-level units, binned, per frame): "
              f"{', '.join(f'{x:.3f}' for x in k_f)}; median k = {k:.3f}: the floor in the capture's units is the twin's "
              f"at {full_well_e * k:.0f} e-.", "",
              f"The regions' signal levels, twin less capture (channel mean, the regions' median removed): rms "
              f"{float(np.sqrt(np.mean(lv ** 2))):.3f} log, 10-90 % {np.percentile(lv, 10):+.3f} .. "
              f"{np.percentile(lv, 90):+.3f}; per channel rms "
              + ", ".join(f"{float(np.sqrt(np.mean(lev[used, 0, c] ** 2))):.3f}" for c in range(3)) + ".", "",
              "The twin's floor against the capture's, per frame and channel (medians over the textured regions): "
              "log(N_twin / S_twin) - log(N_cap / S_cap), and log(N_twin / N_cap) less its overall median:\n",
              "| frame | noise/signal R | G | B | floor ratio R | G | B |", "|---|---|---|---|---|---|---|"]
    for f in range(len(truth[0])):
        lines.append(f"| {f} | " + " | ".join(f"{x:+.3f}" for x in nsr_c[f]) + " | "
                     + " | ".join(f"{x:+.3f}" for x in flr_c[f]) + " |")
    lines += ["", "Signal term's candidates per frame (rms over the textured regions, log units): brightness capture/twin "
              "(regions' median removed), full-resolution twin - sweep at the frames, full-resolution twin - quiet "
              "capture (levels profiled):\n", "| frame | brightness | full - sweep | full - quiet capture |",
              "|---|---|---|---|"]
    for f in range(len(truth[0])):
        lines.append(f"| {f} | {rms(b_res)[f]:.4f} | {rms(full_vs_sweep)[f]:.4f} | {rms(full_vs_cap)[f]:.4f} |")
    per_c = np.stack([rms(profiled(full_c[..., c] - cap_q_c[..., c])) for c in range(3)])  # (C, S)
    lines += ["", "The full-resolution twin (binned) less the quiet capture per channel, levels profiled (rms over the "
              "textured regions, log units), and the capture's channel means (linear, white = 1):\n",
              "| frame | R | G | B |", "|---|---|---|---|"]
    for f in range(len(truth[0])):
        lines.append(f"| {f} | {per_c[0, f]:.4f} | {per_c[1, f]:.4f} | {per_c[2, f]:.4f} |")
    lines.append("| mean level | " + " | ".join(f"{float(np.mean(dq.frames[:, c])):.3f}" for c in range(3)) + " |")
    out = {"scene": scene, "aif": label, "full_minus_quiet_per_channel_rms": per_c.tolist(), "truth_d": truth[0].tolist(), "noise_share": share.tolist(),
           "signal_rms": rms(t_signal).tolist(), "signal_reads_d": focus_reading(-t_signal, slope, used).tolist(),
           "noise_rms": rms(t_noise).tolist(), "noise_reads_d": focus_reading(-t_noise, slope, used).tolist(),
           "level_reads_d": focus_reading(-t_level, slope, used).tolist(),
           "cross_reads_d": focus_reading(-t_cross, slope, used).tolist(),
           "energy_over_floor": e_energy_ratio.tolist(), "cross_over_signal": x_share.tolist(),
           "estimates_d": {k: v.tolist() for k, v in est.items()}, "fitted_full_well_e": fws,
           "region_level_rms_log": float(np.sqrt(np.mean(lv ** 2))),
           "noise_over_signal_twin_less_capture": nsr_c.tolist(), "exposure_ratio_per_frame": k_f.tolist(), "floor_ratio_log": flr_c.tolist()}
    return "\n".join(lines) + "\n", out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", nargs=3, action="append", metavar=("NAME", "QUIET", "NOISY"), required=True)
    ap.add_argument("--full-well-e", type=float, default=8000.0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--work", type=Path, default=Path("cache/p32/weak"), help="the copies reporting the true focus")
    ap.add_argument("--out", type=Path, help="markdown table (written atomically); a .json beside it")
    ap.add_argument("--per-channel", action="store_true", help="the binning correction each channel's own under its "
                    "floor (`anchors.PER_CHANNEL`)")
    a = ap.parse_args(argv)
    if a.per_channel:
        from aat_deploy.diagnose import anchors

        anchors.PER_CHANNEL = True
    texts, rows = [], []
    for name, q, n in a.scene:
        t, r = scene_report(name, Path(q), Path(n), a.full_well_e, a.threads, a.work)
        print(t, flush=True)
        texts.append(t)
        rows.append(r)
    if a.out:
        cmd = "python -m benchmarks.probes.focus_weak_noiseless " + " ".join(
            f"--scene {n} {q} {m}" for n, q, m in a.scene) + (" --per-channel" if a.per_channel else "") + f" --out {a.out}"
        write_text_atomic(a.out, "# The focus twin's misfit in the weak frames, noise off on both sides (issue 32)\n\n"
                          f"`{cmd}`\n" + "".join(texts))
        write_text_atomic(a.out.with_suffix(".json"), json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
