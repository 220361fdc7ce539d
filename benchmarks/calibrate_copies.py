"""Random copies of a lens for bench_calibrate (`--copies K --copy-seed S`): the calibration against the
prescription's map on several copies per lens drawn from a distribution fixed before any result was seen.

The single hand-chosen copy of bench_calibrate b (one element decentred along x, the sensor tilted 0.5 / -0.3 deg)
departs from the EF50's prescription by only 0.015 D, because on that lens its decentre and its tilt cancel
(BENCHMARKS.md, "Why the EF50's copy gains less"); choosing another copy after seeing that would tune the benchmark.
So each copy here is drawn (`draw_copy`), per lens, with the magnitudes of the lens's own hand-chosen copy
(`LensSetup.copy_effects`) and random directions:

- **decentre**: one glass group (`lens_tolerance.elements`: a cemented group is one) chosen uniformly among the
  lens's, decentred by the hand-chosen copy's amount (the 50 mm lenses 0.1 mm, the phone 5 um, the Z35 3 um) in a
  direction uniform on the circle;
- **sensor tilt**: the hand-chosen copy's magnitude (hypot(0.5, 0.3) = 0.583 deg on every lens but the phone's
  hypot(0.3, 0.2) and the Z35's hypot(0.1, 0.06)) about an axis in the sensor plane whose direction is uniform on
  the circle (tilt_x = m cos phi, tilt_y = m sin phi);
- the reported focus 1.1 x the true one (`focus_metadata` scale, as the hand-chosen copy) and sensor noise.

Copy k of lens L is drawn from `numpy.random.default_rng([seed, crc32(L), k])` (element, then the decentre's
direction, then the tilt's), so K copies are the first K of every larger run and a run resumes copy by copy.
Each copy gets parts a and b exactly as the hand-chosen one (its own chart sweeps and fit, the same held-out scenes
rendered through it, the four mappings), and its field's departure from the prescription's
(`benchmarks.probes.calibrate_gain.amplitudes`: the RMS over the 8 depth frames of the copy's field term minus the
nominal lens's). Pooled over copies and scenes: ratios of mean MAEs with a two-level bootstrap (copies resampled,
and the held-out scenes, the same in every copy, resampled once per replicate for all of them: crossed;
`aat_deploy.eval.stats.nested_paired_ratio`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
import zlib
from pathlib import Path

import numpy as np

from aat_deploy.eval.stats import fmt_interval as fmt
from aat_deploy.eval.stats import nested_paired_ratio

MAPPINGS = ("thin lens", "prescription map", "calibration", "oracle")
RATIOS = (("calibration", "prescription map"), ("calibration", "oracle"), ("prescription map", "oracle"),
          ("calibration", "thin lens"))
ZONES = ("mae", "mae_outer", "mae_d")


def _params(effect: str) -> dict:
    return {k: float(v) for k, v in (p.split("=", 1) for p in effect.split(":")[1:]) if k != "table"}


def distribution(setup) -> dict:
    """The copies' distribution for a bench_calibrate LensSetup: the magnitudes of its hand-chosen copy."""
    eff = {e.split(":")[0]: _params(e) for e in setup.copy_effects}
    lt, st, fm = eff["lens_tolerance"], eff["sensor_tilt"], eff["focus_metadata"]
    return {"decentre_mm": math.hypot(lt.get("decentre_x_mm", 0.0), lt.get("decentre_y_mm", 0.0)),
            "tilt_deg": math.hypot(st.get("tilt_x_deg", 0.0), st.get("tilt_y_deg", 0.0)),
            "element": "uniform over the lens's glass groups", "directions": "uniform on the circle",
            "focus_scale": fm.get("scale", 1.0), "focus_bias_d": fm.get("bias_d", 0.0), "noise": "noise" in eff}


def draw_copy(setup, n_elements: int, seed: int, k: int) -> dict:
    """Copy k of the lens (its settings and effects, bench_calibrate's syntax), reproducible from (seed, lens, k)."""
    d = distribution(setup)
    # the lens's key: a setup that adds a chart to a lens's (cellphone_near) draws the lens's own copies
    rng = np.random.default_rng([seed, zlib.crc32((setup.sweep_key or setup.key).encode()), k])
    element = int(rng.integers(0, n_elements))
    theta, phi = rng.uniform(0.0, 2 * math.pi, 2)
    short = lambda v: float(f"{v:.6g}")  # as the effect string carries it (6 significant digits)
    dx, dy = short(d["decentre_mm"] * math.cos(theta)), short(d["decentre_mm"] * math.sin(theta))
    tx, ty = short(d["tilt_deg"] * math.cos(phi)), short(d["tilt_deg"] * math.sin(phi))
    effects = (f"lens_tolerance:element={element}:decentre_x_mm={dx:g}:decentre_y_mm={dy:g}",
               f"sensor_tilt:tilt_x_deg={tx:g}:tilt_y_deg={ty:g}",
               f"focus_metadata:bias_d={d['focus_bias_d']:g}:scale={d['focus_scale']:g}") + (
        ("noise",) if d["noise"] else ())
    return {"index": k, "element": element, "decentre_mm": [dx, dy], "tilt_deg": [tx, ty], "effects": list(effects)}


def copy_setup(setup, seed: int, copy: dict):
    """The LensSetup whose "copy" is this random copy (its chart sweeps cached under their own name)."""
    return dataclasses.replace(setup, copy_effects=tuple(copy["effects"]), copy_name=f"copy_s{seed}_{copy['index']}")


def pooled(copies: list[dict]) -> dict:
    """Ratios of mean MAEs pooled over copies and scenes with the two-level bootstrap: copies resampled and the
    scenes (the same in every copy) resampled once per replicate for all of them (crossed); "... nested": the
    scenes drawn anew within each copy (narrower: it treats each copy's scenes as new ones)."""
    out = {}
    for a, b in RATIOS:
        for z in ZONES:
            pa, pb = [c["depth"]["per_scene"][a] for c in copies], [c["depth"]["per_scene"][b] for c in copies]
            out[f"{a} / {b} {z}"] = nested_paired_ratio(pa, pb, z, crossed=True)
            out[f"{a} / {b} {z} nested"] = nested_paired_ratio(pa, pb, z)
    return out


def run(base_setup, rig, k_copies: int, seed: int, n: int, n_boot: int, out_path: Path, log, save) -> dict:
    """Parts a and b and the field departure for copies 0..k_copies-1 of one lens; copies already in out_path's
    results (the same seed, scenes and distribution) are kept, so a run resumes copy by copy. Returns the lens's
    results {"seed", "n", "distribution", "copies": [...], "pooled": {...}}."""
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import elements
    from benchmarks import bench_calibrate as B
    from benchmarks.probes.calibrate_gain import amplitudes

    dist = distribution(base_setup)
    key = base_setup.key
    res = json.loads(out_path.read_text()) if out_path.is_file() else {}
    mine = res.setdefault("copies", {}).get(key)
    if mine and (mine["seed"], mine["n"], mine["distribution"]) != (seed, n, dist):
        raise SystemExit(f"{out_path}: holds {key}'s copies of seed {mine['seed']}, n {mine['n']}; this run asks for "
                         f"seed {seed}, n {n}: give another --out")
    mine = mine or {"seed": seed, "n": n, "distribution": dist, "copies": []}
    res["copies"][key] = mine
    done = {c["index"] for c in mine["copies"]}
    n_el = len(elements(load_lens(B.ROOT / base_setup.lens)))
    for k in range(k_copies):
        if k in done:
            continue
        copy = draw_copy(base_setup, n_el, seed, k)
        s = copy_setup(base_setup, seed, copy)
        r = rig.with_setup(s)
        t0 = time.time()
        log(f"{key} copy {k}: {', '.join(copy['effects'])}")
        amp = amplitudes(r)["field terms"]
        copy["departure_d"] = {name: amp[name] for name in amp if name != "prescription (nominal lens)"}
        log(f"  field departure from the prescription {amp['copy - prescription']['all']:.4f} D "
            f"({amp['copy - prescription']['outer']:.4f} outer)")
        rows, fits = B.part_map(r, n_boot, log, variants=("copy",))
        copy["map"] = rows[0]
        if "copy" not in fits:
            copy["depth"] = None
        else:
            copy["depth"] = B.part_depth(r, fits["copy"][0], n, log)
        copy["seconds"] = round(time.time() - t0)
        mine["copies"].append(copy)
        mine["copies"].sort(key=lambda c: c["index"])
        scored = [c for c in mine["copies"] if c["depth"]]
        mine["pooled"] = pooled(scored) if scored else {}
        save(res, out_path)
        log(f"  copy {k} done in {copy['seconds']} s")
    return mine


def departures(base_setup, rig, k_copies: int, seed: int, log) -> dict:
    """Only the field departure from the prescription (D, all / outer) of copies 0..k_copies-1 (no renders:
    seconds per copy), to show where the copies whose depth was run fall in the distribution."""
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import elements
    from benchmarks import bench_calibrate as B
    from benchmarks.probes.calibrate_gain import amplitudes

    n_el = len(elements(load_lens(B.ROOT / base_setup.lens)))
    rows = []
    for k in range(k_copies):
        copy = draw_copy(base_setup, n_el, seed, k)
        amp = amplitudes(rig.with_setup(copy_setup(base_setup, seed, copy)))["field terms"]
        rows.append({**copy, "departure_d": {name: amp[name] for name in amp if name != "prescription (nominal lens)"}})
        log(f"  {base_setup.key} copy {k}: departure {amp['copy - prescription']['all']:.4f} D")
    dep = np.array([r["departure_d"]["copy - prescription"]["all"] for r in rows])
    hand = amplitudes(rig.with_setup(base_setup))["field terms"]["copy - prescription"]
    return {"seed": seed, "distribution": distribution(base_setup), "copies": rows, "hand_chosen_d": hand,
            "quantiles_d": {q: float(np.quantile(dep, float(q))) for q in ("0.1", "0.25", "0.5", "0.75", "0.9")}}


def departure_table(res: dict) -> str:
    """Per lens: the departures' quantiles over the drawn copies, and the hand-chosen copy's departure."""
    out = ["| lens | copies | field departure from the prescription (D): 10 / 25 / 50 / 75 / 90 % | "
           "the hand-chosen copy's |", "|---|---|---|---|"]
    for lens, d in res.get("departures", {}).items():
        q = d["quantiles_d"]
        h = d["hand_chosen_d"]["all"]
        below = np.mean([c["departure_d"]["copy - prescription"]["all"] < h for c in d["copies"]])
        out.append(f"| {lens} | {len(d['copies'])} | " + " / ".join(f"{q[k]:.4f}" for k in sorted(q, key=float))
                   + f" | {h:.4f} ({100 * below:.0f} % of the copies depart less) |")
    return "\n".join(out)


def hand_chosen(res: dict, lens: str) -> dict | None:
    """The lens's hand-chosen copy (bench_calibrate b) where `res` holds both its depth (res["depth"][lens], from
    calibrate_depth_<lens>.json) and its departure (res["departures"][lens]["hand_chosen_d"]): {"departure_d",
    "cal/prescription mae", "... mae_outer", "... mae_d"} (each ratio [point, lo, hi]); None otherwise."""
    d, dep = res.get("depth", {}).get(lens), res.get("departures", {}).get(lens)
    if not d or not dep or "cal/prescription mae" not in d:
        return None
    return {"departure_d": dep["hand_chosen_d"]["all"],
            **{f"cal/prescription {z}": d[f"cal/prescription {z}"] for z in ZONES if f"cal/prescription {z}" in d}}


def figure(res: dict, path: Path) -> None:
    """PNG: per lens, each copy's calibration / prescription map MAE ratio (overall and outer field, 95 % interval
    over its scenes) against its field departure from the prescription; the 0.8 target as a line; where `res`
    also holds the hand-chosen copy's depth and departure (`hand_chosen`), its ratios as open markers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aat_deploy.io.atomic import atomic_file

    lenses = {k: [c for c in m["copies"] if c["depth"]] for k, m in res.get("copies", {}).items()}
    lenses = {k: v for k, v in lenses.items() if v}
    if not lenses:
        return
    fig, axes = plt.subplots(1, len(lenses), figsize=(5.2 * len(lenses), 3.8), squeeze=False)
    for ax, (lens, cs) in zip(axes[0], lenses.items()):
        for z, mk, lab in (("mae", "o", "MAE"), ("mae_outer", "s", "MAE, outer field")):
            x = [c["departure_d"]["copy - prescription"]["all"] for c in cs]
            r = np.array([c["depth"][f"cal/prescription {z}"] for c in cs])
            ax.errorbar(x, r[:, 0], yerr=[r[:, 0] - r[:, 1], r[:, 2] - r[:, 0]], fmt=mk, capsize=3, label=lab,
                        color="C0" if z == "mae" else "C1")
        h = hand_chosen(res, lens)
        for z, mk, c in (("mae", "o", "C0"), ("mae_outer", "s", "C1")):
            if h and f"cal/prescription {z}" in h:
                v = h[f"cal/prescription {z}"]
                ax.errorbar([h["departure_d"]], [v[0]], yerr=[[v[0] - v[1]], [v[2] - v[0]]], fmt=mk, mfc="none",
                            color=c, capsize=3, ls="none", label=f"hand-chosen copy, {'MAE' if z == 'mae' else 'outer'}")
        ax.axhline(0.8, color="k", ls="--", lw=1, label="target 0.8")
        ax.axhline(1.0, color="grey", lw=1)
        ax.set_title(f"{lens}: {len(cs)} random copies")
        ax.set_xlabel("field departure from the prescription (D RMS)")
        ax.set_ylabel("calibration / prescription map (95 % interval)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def tables(res: dict) -> str:
    """Per copy and pooled, per lens (BENCHMARKS.md's)."""
    out = ["| lens | copy | decentred element, (x, y) mm | sensor tilt (x, y) deg | field departure from the "
           "prescription, all / outer (D) | map RMS inside (D) | calibration / prescription map, MAE | outer | "
           "MAE in D | calibration / oracle, MAE |", "|---|---|---|---|---|---|---|---|---|---|"]
    for lens, m in res.get("copies", {}).items():
        for c in m["copies"]:
            dep = c["departure_d"]["copy - prescription"]
            mp = c["map"]
            mrms = f"{mp['inside']['calibration']['rms_d']:.4f}" if "inside" in mp else "refused"
            if c["depth"]:
                per = c["depth"]
                r = [fmt(per[f"cal/prescription {z}"]) for z in ZONES] + [fmt(per["cal/oracle mae"])]
            else:
                r = ["-"] * 4
            out.append(f"| {lens} | {c['index']} | {c['element']}, ({c['decentre_mm'][0]:+.3f}, "
                       f"{c['decentre_mm'][1]:+.3f}) | ({c['tilt_deg'][0]:+.2f}, {c['tilt_deg'][1]:+.2f}) | "
                       f"{dep['all']:.4f} / {dep['outer']:.4f} | {mrms} | " + " | ".join(r) + " |")
        p = m.get("pooled")
        if p:
            k = len([c for c in m["copies"] if c["depth"]])
            out.append(f"| {lens} | **pooled, {k} copies x {m['copies'][0]['depth']['scenes']} scenes** | | | | | "
                       + " | ".join(f"**{fmt(p[f'calibration / prescription map {z}'])}**" for z in ZONES)
                       + f" | {fmt(p['calibration / oracle mae'])} |")
    return "\n".join(out)
