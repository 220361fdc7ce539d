"""Is the phone's outer-field tile bias the chart's texture? (issue 33, part a: 0.138 D RMS on `cellphone_near`
against 0.02 D; its largest remaining cause named was the outer tiles' bias, -0.18 to -0.23 D at field radius
0.66-0.9, put down to the chart's dead leaves not being the photographs the truth is made of.)

    OMP_NUM_THREADS=1 python -m benchmarks.probes.chart_texture --spectra          # seconds: the textures' statistics
    OMP_NUM_THREADS=1 python -m benchmarks.probes.chart_texture [--textures "dead leaves,photos"] \
        [--variants copy,copy_s2026_0,copy_s2026_1,copy_s2026_2] [--out results/chart_texture.json]

The test, on development copies only (bench_calibrate's `cellphone_near`: the hand-chosen copy `copy` and the
phone's three declared random copies of seed 2026, `copy_s2026_K`; `nominal` too; no held-out depth scene is
rendered or read): the same four charts (7, 10, 18 cm measured, 5.5 cm fitted), poses, sweeps (0.55 D steps),
noise seeds and fit, with only the chart's texture changed:

- `dead leaves`: `aat-calibrate chart`'s sharp discs (the benchmark's before this probe; its sweeps are
  bench_calibrate's cached ones);
- `photos`: **the oracle**: a mosaic of the truth's own texture, `training.data.textures.photo_texture` crops of
  the training photographs drawn exactly as the truth's calibration draws them (lenses/best_focus: 48 of them per
  point, 112 px at sensor scale), one per 128 px block of the chart at sensor scale, cross-faded over 16 px, grey
  (Rec. 709 luminance), upsampled to the chart's 3 image pixels per sensor pixel. No texture a chart can print is
  closer to what the truth averaged;
- `soft leaves`: the chart adopted after this probe (`aat-calibrate chart --frame-px W`, bench_calibrate's default
  since): the dead leaves softened by 0.7 sensor pixels, as `leaves-blur0.7` (its sweeps cached under
  bench_calibrate's names);
- `leaves-blurS`: the dead leaves blurred by a Gaussian of S sensor pixels (a chart with less fine detail, as
  photographs have: `--spectra`);
- `leaves-minR`: dead leaves whose smallest disc is R sensor pixels in radius (1.5 image px = 0.5 sensor px now);
- a suffix `@K` draws the texture anew (K = 1, 2, ...: the discs or photographs of another seed; `leaves-blur0@K`
  is the dead leaves of another draw): how much the map moves with the chart's draw alone.

Per texture and variant: part a's map error (inside: the 10 reported focus settings over 7-18 cm; RMS over the
sensor, D, the calibration as the benchmark stores it: `bench_calibrate.map_errors`), and the tiles' bias by
field radius (each counted tile's object minus the truth's in-focus object at the tile for its measured peak's
frame: `phone_map_budget`'s; D of object, mean and SD and count); beside it the same tiles made exactly from the
truth (`ideal tiles`: what the fit alone leaves). `--spectra`: each texture's power by spatial-frequency band at
sensor scale (cycles per sensor pixel; the chart's texture as the camera sees it in focus at its centre, before
the lens) and its gradients' orientation (share along the axes).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import zlib
from pathlib import Path

import numpy as np

from benchmarks import RESULTS

COPY_SEED = 2026  # the phone's random copies: their seed and number, declared before any was rendered (f2eb611)
DECLARED_COPIES = 3
BLOCK_PX, FADE_PX = 128, 16  # the photo mosaic's blocks and their cross-fade (sensor px)
BANDS = (0.0, 0.03, 0.06, 0.12, 0.25, 0.5)  # cycles per sensor pixel


# -- the textures -----------------------------------------------------------------------------------------------------
def _to_u8(lin: np.ndarray) -> np.ndarray:
    """Linear light in [0, 1] -> sRGB-encoded uint8 (chart_scene decodes it back)."""
    x = np.clip(lin, 0, 1)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.clip(np.round(s * 255), 0, 255).astype(np.uint8)


def photo_mosaic(hs: int, ws: int, rng: np.random.Generator, block_px: int = BLOCK_PX) -> np.ndarray:
    """(hs, ws) float32 linear grey at sensor scale: photo_texture crops (the truth calibration's draw) one per
    block_px block, each FADE_PX larger on every side and cross-faded with its neighbours (raised cosine)."""
    from training.data.textures import photo_texture

    acc = np.zeros((hs, ws), np.float64)
    wsum = np.zeros((hs, ws), np.float64)
    n = block_px + 2 * FADE_PX
    ramp = 0.5 - 0.5 * np.cos(np.pi * (np.arange(2 * FADE_PX) + 0.5) / (2 * FADE_PX))
    win1 = np.concatenate([ramp, np.ones(n - 4 * FADE_PX), ramp[::-1]])
    win = np.outer(win1, win1)
    for r0 in range(-FADE_PX, hs, block_px):
        for c0 in range(-FADE_PX, ws, block_px):
            tex = photo_texture(rng, n, n, "train")
            lum = tex[..., 0] * 0.2126 + tex[..., 1] * 0.7152 + tex[..., 2] * 0.0722
            ra, ca = max(r0, 0), max(c0, 0)
            rb, cb = min(r0 + n, hs), min(c0 + n, ws)
            acc[ra:rb, ca:cb] += (lum * win)[ra - r0:rb - r0, ca - c0:cb - c0]
            wsum[ra:rb, ca:cb] += win[ra - r0:rb - r0, ca - c0:cb - c0]
    return (acc / np.maximum(wsum, 1e-9)).astype(np.float32)


def texture_for(name: str, spec, k: float) -> np.ndarray:
    """(H, W) uint8 texture `name` for a chart of ChartSpec `spec` seen at k image pixels per sensor pixel."""
    import cv2

    from aat_deploy.calibrate.chart import chart_px, dead_leaves

    wp, hp = chart_px(spec)
    px = spec.px_per_mm
    name, _, draw = name.partition("@")  # "@K": another random draw of the same texture (K = 0: the chart's own)
    seed = spec.seed + 1_000_003 * int(draw or 0)
    rng = np.random.default_rng([seed, zlib.crc32(name.encode())])
    leaf_max = 0.1 * min(spec.size_mm) * px
    if name == "photos":
        hs, ws = int(np.ceil(hp / k)), int(np.ceil(wp / k))
        lin = cv2.resize(photo_mosaic(hs, ws, rng), (wp, hp), interpolation=cv2.INTER_CUBIC)
        return _to_u8(lin)
    if name.startswith("leaves-blur"):  # the chart's own dead leaves (the same discs), blurred
        s = float(name[len("leaves-blur"):]) * k
        base = dead_leaves(hp, wp, 1.5, leaf_max, np.random.default_rng(seed))
        return cv2.GaussianBlur(base, (0, 0), s) if s > 0 else base
    if name.startswith("leaves-min"):
        return dead_leaves(hp, wp, float(name[len("leaves-min"):]) * k, leaf_max, rng)
    raise ValueError(f"unknown chart texture {name!r}: dead leaves, photos, leaves-blurS, leaves-minR")


def sensor_view(name: str, rig, distance_m: float) -> np.ndarray:
    """(H, W) the chart's texture (no markers) at sensor scale: its image downsampled by the benchmark's k."""
    import cv2

    from aat_deploy.calibrate.chart import ChartSpec, dead_leaves
    from benchmarks import bench_calibrate as B

    k = B.CHART_PX_PER_PX
    w_mm = 1.3 * rig.w / rig.f_px * 1000 * distance_m
    spec = ChartSpec(size_mm=(w_mm, w_mm * rig.h / rig.w), markers=(6, 4),
                     dpi=25.4 * k * rig.w / (w_mm / 1.3), seed=int(distance_m * 1000))
    if name == "dead leaves":
        from aat_deploy.calibrate.chart import chart_px

        wp, hp = chart_px(spec)
        img = dead_leaves(hp, wp, 1.5, 0.1 * min(spec.size_mm) * spec.px_per_mm, np.random.default_rng(spec.seed))
    else:
        img = texture_for(name, spec, k)
    from aat_deploy.io.color import srgb_to_linear

    lin = srgb_to_linear(img.astype(np.float32) / 255.0)
    return cv2.resize(lin, (int(round(lin.shape[1] / k)), int(round(lin.shape[0] / k))), interpolation=cv2.INTER_AREA)


def statistics(img: np.ndarray, crop: int = 64) -> dict:
    """Power share by band (cycles/px, BANDS) averaged over crop x crop patches (Hann-windowed, mean removed), as
    the truth's 64 px crops and a tile see it; the gradients' energy share along the axes (|gx| or |gy| dominant
    within 22.5 deg) against the diagonals; the RMS contrast (SD / mean)."""
    h, w = img.shape
    win = np.outer(np.hanning(crop), np.hanning(crop))
    f = np.fft.fftfreq(crop)
    fr = np.hypot(f[:, None], f[None, :])
    p = np.zeros((crop, crop))
    n = 0
    for r in range(0, h - crop + 1, crop):
        for c in range(0, w - crop + 1, crop):
            x = img[r:r + crop, c:c + crop].astype(np.float64)
            x = (x - x.mean()) * win
            p += np.abs(np.fft.fft2(x)) ** 2
            n += 1
    p /= n
    tot = p[fr > 0].sum()
    bands = {f"{lo:g}-{hi:g}": float(p[(fr > lo) & (fr <= hi)].sum() / tot) for lo, hi in zip(BANDS[:-1], BANDS[1:])}
    gy, gx = np.gradient(img.astype(np.float64))
    e = gx ** 2 + gy ** 2
    ang = np.degrees(np.arctan2(gy, gx)) % 90.0
    axis = (ang < 22.5) | (ang >= 67.5)
    return {"band_power_share": bands, "axis_gradient_share": float(e[axis].sum() / e.sum()),
            "rms_contrast": float(img.std() / img.mean())}


# -- the test ---------------------------------------------------------------------------------------------------------
def rig_for(base_rig, texture: str, variant: str):
    """(rig, variant as bench_calibrate names it) for `variant` (nominal, copy, copy_s2026_K) with `texture`."""
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import elements
    from benchmarks import bench_calibrate as B
    from benchmarks import calibrate_copies as C

    if texture == "soft leaves":  # the adopted chart: `aat-calibrate chart --frame-px`'s, bench_calibrate's default
        setup = dataclasses.replace(base_rig.setup, chart_texture="dead leaves", chart_soften_px=B.SOFT_SENSOR_PX)
    else:  # the sharp dead leaves (the sweeps before the softening) or a probe's texture, unsoftened
        setup = dataclasses.replace(base_rig.setup, chart_texture=texture, chart_soften_px=0.0)
    if variant.startswith(f"copy_s{COPY_SEED}_"):
        k = int(variant.rsplit("_", 1)[1])
        if not 0 <= k < DECLARED_COPIES:
            raise SystemExit(f"{variant}: the phone's declared random copies are 0..{DECLARED_COPIES - 1}")
        n_el = len(elements(load_lens(B.ROOT / setup.lens)))
        setup = C.copy_setup(setup, COPY_SEED, C.draw_copy(setup, n_el, COPY_SEED, k))
        return base_rig.with_setup(setup), "copy"
    return base_rig.with_setup(setup), variant


def run_one(base_rig, texture: str, variant: str, log) -> dict:
    from benchmarks import bench_calibrate as B
    from benchmarks.probes import phone_map_budget as P

    rig, v = rig_for(base_rig, texture, variant)
    t0 = time.time()
    keep: dict = {}
    out = P.run_variant(rig, v, {"lens map (64 px crops)": None}, log, keep=keep)
    eff = B.effects_for(rig.setup, v)
    res = keep["fit"]  # bench_calibrate.fit's with n_boot=0: the map part a scores (its bootstrap only adds intervals)
    e = B.map_errors(rig, res.calibration, eff, rig.setup.inside())["calibration"]
    sc = out["scores"]["lens map (64 px crops)"]
    fitted = [p for p in res.calibration.residuals["per_sweep"] if "distance_given_m" in p]
    row = {"texture": texture, "variant": variant, "map_rms_inside_d": e["rms_d"], "map_p95_inside_d": e["p95_d"],
           "radius_rms_d": e["radius_rms_d"], "radius_mean_d": e["radius_mean_d"],
           "ideal_tiles_rms_d": sc["ideal tiles, held beyond the tiles"]["rms_d"],
           "ideal_tiles_radius_rms_d": sc["ideal tiles, held beyond the tiles"]["radius_rms_d"],
           "tiles": out["fits"]["measured"]["tiles"], "family": out["fits"]["measured"]["family"],
           "tile_radius_max": out["tile_radius_max"], "tile_bias": out["tile_bias"],
           "tile_bias_rms_d": out["tile_bias_rms_d"], "unbracketed": out["unbracketed"],
           "near_chart_fitted_m": fitted[0]["chart_distance_m"] if fitted else None,
           "seconds": round(time.time() - t0)}
    log(f"  {texture} / {variant}: map {row['map_rms_inside_d']:.4f} D inside; tiles' bias "
        + ", ".join(f"{k} {b['mean_d']:+.3f}" for k, b in row["tile_bias"].items() if b["n"]))
    return row


def spectra(base_rig, textures: list[str], distance_m: float) -> dict:
    return {t: statistics(sensor_view(t, base_rig, distance_m)) for t in textures}


def table(res: dict) -> str:
    out = []
    if res.get("spectra"):
        sp = res["spectra"]
        bands = list(next(iter(sp.values()))["band_power_share"])
        out.append(f"\nthe textures at sensor scale (chart at {res['spectra_chart_m']:g} m, 64 px patches): power share "
                   "by band (cycles/px), gradient energy along the axes, RMS contrast\n")
        out.append("| texture | " + " | ".join(bands) + " | axes | contrast |")
        out.append("|---|" + "---|" * (len(bands) + 2))
        for t, s in sp.items():
            out.append(f"| {t} | " + " | ".join(f"{s['band_power_share'][b]:.3f}" for b in bands)
                       + f" | {s['axis_gradient_share']:.3f} | {s['rms_contrast']:.3f} |")
    rows = res.get("rows", [])
    if rows:
        bins = [b for b in rows[0]["tile_bias"] if rows[0]["tile_bias"][b]["n"]]
        out.append("\npart a's map RMS inside (D) and the tiles' bias by field radius (mean D of object, SD, n)\n")
        out.append("| texture | copy | map RMS | p95 | ideal tiles | tiles | near chart (mm) | "
                   + " | ".join(f"bias {b}" for b in bins) + " |")
        out.append("|---|---|---|---|---|---|---|" + "---|" * len(bins))
        for r in rows:
            cells = []
            for b in bins:
                t = r["tile_bias"].get(b, {})
                cells.append("-" if not t.get("n") else f"{t['mean_d']:+.3f} ({t['sd_d']:.2f}, {t['n']})")
            nm = "-" if r["near_chart_fitted_m"] is None else f"{1000 * r['near_chart_fitted_m']:.2f}"
            out.append(f"| {r['texture']} | {r['variant']} | {r['map_rms_inside_d']:.4f} | {r['map_p95_inside_d']:.3f} "
                       f"| {r['ideal_tiles_rms_d']:.4f} | {r['tiles']} | {nm} | " + " | ".join(cells) + " |")
        texs = list(dict.fromkeys(r["texture"] for r in rows))
        if len(texs) > 1:
            out.append("\nmean over the copies (those every texture has):\n")
            common = set.intersection(*({r["variant"] for r in rows if r["texture"] == t} for t in texs))
            out.append("| texture | copies | map RMS | " + " | ".join(f"bias {b}" for b in bins) + " |")
            out.append("|---|---|---|" + "---|" * len(bins))
            for t in texs:
                rr = [r for r in rows if r["texture"] == t and r["variant"] in common]
                cells = [f"{np.mean([r['tile_bias'][b]['mean_d'] for r in rr]):+.3f}" for b in bins]
                out.append(f"| {t} | {len(rr)} | {np.mean([r['map_rms_inside_d'] for r in rr]):.4f} | "
                           + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    from benchmarks import bench_calibrate as B

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--textures", default="dead leaves,photos")
    ap.add_argument("--variants", default="copy," + ",".join(f"copy_s{COPY_SEED}_{k}" for k in range(DECLARED_COPIES)))
    ap.add_argument("--spectra", action="store_true", help="only the textures' statistics (no rendering)")
    ap.add_argument("--spectra-chart-m", type=float, default=0.1)
    ap.add_argument("--out", default=str(RESULTS / "chart_texture.json"))
    a = ap.parse_args(argv)
    log = lambda m: print(m, file=sys.stderr, flush=True)
    base = B.Rig(B.LENSES["cellphone_near"])
    textures = [t.strip() for t in a.textures.split(",") if t.strip()]
    out_path = Path(a.out)
    res = json.loads(out_path.read_text()) if out_path.is_file() else {}
    res.setdefault("setup", "cellphone_near")
    if a.spectra:
        res["spectra"] = {**res.get("spectra", {}), **spectra(base, textures, a.spectra_chart_m)}
        res["spectra_chart_m"] = a.spectra_chart_m
    else:
        rows = [r for r in res.get("rows", [])]
        for t in textures:
            for v in a.variants.split(","):
                row = run_one(base, t, v, log)
                rows = [r for r in rows if (r["texture"], r["variant"]) != (t, v)] + [row]
                res["rows"] = rows
                B.save(res, out_path)
    B.save(res, out_path)
    print(table(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
