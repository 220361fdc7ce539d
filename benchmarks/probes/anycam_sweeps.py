"""How much the blur changes across the any-camera training sweeps against the held-out test stacks (issue 35).

    python -m benchmarks.probes.anycam_sweeps [--configs configs/anycam/dfv_aat.json configs/anycam/dfv_aat_v3.json]
        [--out results/anycam_sweeps.json] [--figure results/figures/anycam_sweeps.png]
        [--window-coverage [--coverage-split train|val] [--coverage-every N]]
    python -m benchmarks.probes.anycam_sweeps --test-only z35 [--cache cache/heldout]
    python -m benchmarks.probes.anycam_sweeps --figure-only [--configs ...] [--out ...] [--figure ...]

Per sweep, in pixels of blur diameter: the total blur change k x (1/near - 1/far) (k: the defocus scale the net is
told, px per diopter, at the sweep's geometric-mean focus) and the blur change per frame spacing, both for the
16-frame dense render and for the stack a validation item reads (S drawn as `AnyCamDataset.__getitem__` does:
3 to `cameras.max_frames`). Training side: every item of each config's training data, drawn without rendering
(`AnyCamDataset.draw_sweep`). Test side: only camera and schedule parameters, never a lens's map or a test
image: each lens's focal length, f-number and pixel pitch (paraxial, from its lens file, as the runtime reads
them; k at most K_MAX_PX_PER_D, as the runtime brings frames to) with `bench_anycam`'s fixed schedule, and the
paper protocol's focus distances as its cached test sets hold them (only where cached; they follow each scene's
depth range). Prints quantiles and the shares under 9 px and within 20-120 px, and the draw limits' quantities (wide
sweeps' working width; parametric best-focus maps past infinity or past half the far focus's diopters); writes JSON
and a histogram of the training sweeps with the test rows as the JSON holds them (a line per lens's fixed protocol,
the median and 5-95 % band of its paper protocol's stacks).
--window-coverage also reads the cached renders: how much of its sweep's depth each 128 px window spans.
--test-only LENS ...: only those lenses' test rows (no training sweeps, no figure), printed and put into --out in
place of the lenses' earlier test rows, the rest of the file kept (a lens file corrected since, as the Z35 was).
--figure-only: the figure again from --out's test rows and the configs' training sweeps (drawn again, no rendering,
no cache; refused if they no longer match the file's), nothing else written: after --test-only.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from aat_deploy.io.atomic import atomic_file, write_text_atomic

ROOT = Path(__file__).resolve().parents[2]
QUANTILES = (5, 25, 50, 75, 95)


def training_sweeps(config: Path) -> list[dict]:
    """One row per training item of a config: kind (traced / wide / parametric), class, total and per-spacing
    blur change (px)."""
    from training.data import cameras as cams
    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.train.config import load_config

    cfg = load_config(config)
    ds = AnyCamDataset(AnyCamConfig(**{**dict(cfg.data), "only_cached": False, "cache_dir": None}))
    rows = []
    for i in range(ds.cfg.n_items):
        sw = ds.draw_sweep(np.random.default_rng([ds.cfg.seed, i, 35]), i)
        span = sw.span_px()
        s = int(np.random.default_rng([i, 5]).integers(cams.S_RANGE[0], cams.max_frames(span) + 1))
        rows.append({"kind": "traced" if sw.traced else "wide" if sw.wide else "parametric",
                     "class": sw.info.get("class"), "span_px": span, "dense_step_px": span / (len(sw.focus) - 1),
                     "read_step_px": span / (s - 1), "frames_read": s, "width_px": int(sw.sensor_hw[1]),
                     "map_far_ratio": None if sw.traced else map_far_ratio(sw.cam, sw.focus)})
    return rows


def map_far_ratio(cam, focus_m: np.ndarray) -> float:
    """The least best-focus diopters of a parametric camera's map (`cameras.least_map_diopters`: any frame, either
    astigmatic focus, the full sensor) over its far frame's nominal diopters: below 0 the map passes infinity
    somewhere, where a net that weights that frame answers up to 1 km (`cameras.limit_far_map` keeps it >= its
    floor)."""
    from training.data.cameras import least_map_diopters

    return float(least_map_diopters(cam, focus_m).min() * float(np.max(focus_m)))


def test_sweeps(cache: Path, lenses: list[str] | None = None) -> list[dict]:
    """One row per test-protocol sweep of `lenses` (default every held-out set's): lens, protocol, total and
    per-spacing blur change (px)."""
    from aat_deploy.anycam.model import K_MAX_PX_PER_D
    from aat_deploy.calibrate.format import thin_lens_defocus_scale_px_per_d
    from aat_deploy.lens.io import load_lens
    from aat_deploy.optics.paraxial import paraxial_data
    from benchmarks.bench_anycam import LENSES, test_spec
    from training.train.testsets import _dataset

    rows = []
    for key, spec in LENSES.items():
        if lenses is not None and key not in lenses:
            continue
        lens = load_lens(ROOT / spec["lens"])
        p = paraxial_data(lens)

        def span(focus: np.ndarray) -> float:
            k = thin_lens_defocus_scale_px_per_d(p.efl_mm, p.fno, lens.sensor.pixel_mm * 1000.0,
                                                 float(np.sqrt(focus[0] * focus[-1])))
            return min(k, K_MAX_PX_PER_D) * (1.0 / focus[0] - 1.0 / focus[-1])

        near, far = spec["range_m"]
        f = np.array([near, far])
        s = span(f)
        rows.append({"lens": key, "protocol": "fixed", "span_px": s, "step_px": s / (spec["stack_size"] - 1),
                     "frames": spec["stack_size"]})
        ds = _dataset(test_spec(key, "paper", 24, real=False), str(cache))
        for i in range(24):
            path = ds.cache / f"{i:06d}.npz" if ds.cache is not None else None
            if path is None or not path.is_file():
                continue
            with np.load(path) as z:
                fm = np.sort(np.asarray(z["focus_m"], np.float64))  # only the focus distances are read
            s = span(fm)
            rows.append({"lens": key, "protocol": "paper", "span_px": s, "step_px": s / (len(fm) - 1),
                         "frames": len(fm)})
    return rows


def window_coverage(config: Path, every: int = 4, split: str = "train") -> dict:
    """How much of its sweep a cached render's window spans in depth: (1/d_2% - 1/d_98%) / (1/near - 1/far) of its
    depth map, per kind, with the working width (px across the full sensor). Reads the renders cached for the config
    (every `every`-th item); a narrow field of view (a high working resolution) sees a thin slice of the scene."""
    from training.data.anycam import AnyCamConfig, AnyCamDataset
    from training.data.cache import item_path
    from training.train.config import load_config

    cfg = load_config(config)
    data = cfg.data if split == "train" else cfg.val_data
    ds = AnyCamDataset(AnyCamConfig(**{**dict(data), "only_cached": False, "fixed_subsets": False}))
    rows = {}
    for i in range(0, ds.cfg.n_items, every):
        f = item_path(ds.cache, i) if ds.cache is not None else None
        if f is None or not f.is_file():
            continue
        with np.load(f) as z:
            d, fm, cam, width = z["depth_m"], z["focus_m"], json.loads(str(z["camera"])), int(z["sensor_hw"][1])
        kind = "wide" if ds.is_wide(i) else "traced" if cam.get("traced") else "parametric"
        cov = (1 / np.percentile(d, 2) - 1 / np.percentile(d, 98)) / (1 / fm[0] - 1 / fm[-1])
        rows.setdefault(kind, []).append((float(cov), width))
    out = {}
    for kind, r in rows.items():
        cov, w = np.array(r).T
        out[kind] = {"n": len(cov), **{f"p{q}": float(np.percentile(cov, q)) for q in (10, 50, 90)},
                     "median_width_under_1000px": float(np.median(cov[w < 1000])) if (w < 1000).any() else None,
                     "median_width_2000px_up": float(np.median(cov[w >= 2000])) if (w >= 2000).any() else None}
    return out


def stats(x) -> dict:
    x = np.asarray(x, np.float64)
    return {"n": int(x.size), **{f"p{q}": float(np.percentile(x, q)) for q in QUANTILES},
            "under_9px": float(np.mean(x < 9.0)), "in_20_120px": float(np.mean((x >= 20) & (x <= 120)))}


def figure(train: dict, test: dict, path: Path) -> list[tuple[str, float]]:
    """Per config a histogram of its training sweeps' total blur change, with `test` (`test_summary`: "<lens>
    <protocol>" -> quantiles) drawn on it: a red line per lens's fixed protocol, a blue line at the median of its
    paper-protocol stacks over their 5-95 % band. Returns the lines drawn: (row name, px)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bins = np.geomspace(0.5, 400, 40)
    fig, ax = plt.subplots(1, len(train), figsize=(5 * len(train), 3.9), squeeze=False)
    drawn = []
    for a, (name, rows) in zip(ax[0], train.items()):
        a.hist([r["span_px"] for r in rows], bins=bins, color="0.6", label="training sweeps (the config's items)")
        for row, st in test.items():
            lens, protocol = row.split(" ")
            s = st["span_px"]
            colour = "r" if protocol == "fixed" else "b"
            if s["n"] > 1:
                a.axvspan(s["p5"], s["p95"], color=colour, alpha=0.08, lw=0, zorder=0)
            a.axvline(s["p50"], color=colour, lw=0.8, alpha=0.7)
            a.text(s["p50"], 0.98, f" {lens}", color=colour, fontsize=6, rotation=90, va="top", ha="right",
                   transform=a.get_xaxis_transform())
            drawn.append((row, float(s["p50"])))
        a.set(xscale="log", xlabel="total blur change over the sweep (px)", ylabel="items", title=name)
    ax[0, 0].plot([], [], "r", label="test, fixed protocol (per lens)")
    ax[0, 0].plot([], [], "b", label="test, paper protocol (per lens: median, 5-95 % of its stacks)")
    fig.legend(*ax[0, 0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return drawn


def test_summary(rows: list[dict]) -> dict:
    """{"<lens> <protocol>": quantiles of the total and per-spacing blur change, frames} of test_sweeps' rows."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        groups.setdefault(f"{r['lens']} {r['protocol']}", []).append(r)
    return {k: {"span_px": stats([r["span_px"] for r in rs]), "step_px": stats([r["step_px"] for r in rs]),
                "frames": rs[0]["frames"]} for k, rs in groups.items()}


def print_test(test: dict) -> None:
    for name, st in test.items():
        s, r = st["span_px"], st["step_px"]
        print(f"| test {name} ({st['frames']} frames) | {s['n']} | " + " / ".join(f"{s[f'p{q}']:.1f}" for q in QUANTILES)
              + f" | {s['under_9px']:.0%} | {s['in_20_120px']:.0%} | {r['p5']:.1f} / {r['p50']:.1f} / {r['p95']:.1f} |")


def test_only(lenses: list[str], cache: Path, out: Path) -> int:
    """--test-only: the lenses' test rows, printed and put into `out` in place of their earlier rows (a lens's
    paper-protocol row is dropped when its set is not cached under `cache`); the rest of `out` is kept."""
    from benchmarks.bench_anycam import LENSES

    unknown = sorted(set(lenses) - set(LENSES))
    if unknown:
        raise SystemExit(f"--test-only: unknown lens {', '.join(unknown)} (known: {', '.join(LENSES)})")
    test = test_summary(test_sweeps(cache, lenses))
    print("| sweeps | n | total blur change (px) p5 / p25 / p50 / p75 / p95 | under 9 px | 20-120 px "
          "| blur per frame spacing as read (px) p5 / p50 / p95 |")
    print("|---|---|---|---|---|---|")
    print_test(test)
    old = json.loads(out.read_text()) if out.is_file() else {"summary": {"training": {}, "test": {}}, "configs": []}
    merged = {}  # the file's order, these lenses' rows where theirs were
    for k, v in old["summary"].get("test", {}).items():
        if k.split(" ")[0] not in lenses:
            merged[k] = v
        else:
            merged.update({n: t for n, t in test.items() if n.split(" ")[0] == k.split(" ")[0]})
    old["summary"]["test"] = {**merged, **test}
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps(old, indent=1))
    print(f"wrote {out} (test rows of {', '.join(lenses)})")
    return 0


def figure_only(configs: list[Path], out: Path, path: Path) -> int:
    """--figure-only: `figure` from `out`'s test rows and the configs' training sweeps drawn again, which must
    reproduce the file's training quantiles (else the histogram would not be the file's: SystemExit)."""
    if not out.is_file():
        raise SystemExit(f"--figure-only: {out}: no such results file (run the probe without --figure-only)")
    summary = json.loads(out.read_text())["summary"]
    train = {}
    for c in configs:
        stored = summary["training"].get(c.stem, {}).get("all")
        if stored is None:
            raise SystemExit(f"--figure-only: {out} has no training rows of {c.stem} (its: "
                             f"{', '.join(summary['training'])})")
        rows = training_sweeps(c)
        now = stats([r["span_px"] for r in rows])
        if any(not np.isclose(now[k], v, rtol=1e-9, atol=0) for k, v in stored["span_px"].items()):
            raise SystemExit(f"--figure-only: {c.stem}'s training sweeps drawn now differ from {out}'s "
                             f"(p50 {now['p50']:.3f} px here, {stored['span_px']['p50']:.3f} there): run the probe "
                             "whole")
        train[c.stem] = rows
    figure(train, summary["test"], path)
    print(f"wrote {path} (test rows of {out}: {', '.join(summary['test'])})")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configs", nargs="+", type=Path,
                    default=[ROOT / "configs/anycam/dfv_aat.json", ROOT / "configs/anycam/dfv_aat_v3.json"])
    ap.add_argument("--cache", type=Path, default=ROOT / "cache" / "heldout", help="the held-out sets' cache")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "anycam_sweeps.json")
    ap.add_argument("--figure", type=Path, default=ROOT / "results" / "figures" / "anycam_sweeps.png")
    ap.add_argument("--window-coverage", action="store_true",
                    help="also how much of its sweep's depth each cached render's window spans (reads the renders)")
    ap.add_argument("--coverage-split", choices=("train", "val"), default="train",
                    help="whose renders --window-coverage reads (default train)")
    ap.add_argument("--coverage-every", type=int, default=4, help="every n-th render (default 4)")
    ap.add_argument("--test-only", nargs="+", metavar="LENS", default=None,
                    help="only these lenses' test rows, put into --out in place of their earlier ones")
    ap.add_argument("--figure-only", action="store_true",
                    help="only the figure, from --out's test rows and the configs' training sweeps drawn again")
    a = ap.parse_args(argv)
    if a.test_only is not None:
        return test_only(a.test_only, a.cache, a.out)
    if a.figure_only:
        return figure_only(a.configs, a.out, a.figure)
    train = {c.stem: training_sweeps(c) for c in a.configs}
    test = test_sweeps(a.cache)
    summary = {"training": {}, "test": {}}
    for name, rows in train.items():
        groups = {"all": rows, **{k: [r for r in rows if r["kind"] == k] for k in ("parametric", "wide", "traced")}}
        summary["training"][name] = {
            g: {"span_px": stats([r["span_px"] for r in rs]), "dense_step_px": stats([r["dense_step_px"] for r in rs]),
                "read_step_px": stats([r["read_step_px"] for r in rs])} for g, rs in groups.items() if rs}
    summary["test"] = test_summary(test)
    print("| sweeps | n | total blur change (px) p5 / p25 / p50 / p75 / p95 | under 9 px | 20-120 px "
          "| blur per frame spacing as read (px) p5 / p50 / p95 |")
    print("|---|---|---|---|---|---|")
    for name, groups in summary["training"].items():
        for g, st in groups.items():
            s, r = st["span_px"], st["read_step_px"]
            print(f"| training {name}, {g} | {s['n']} | " + " / ".join(f"{s[f'p{q}']:.1f}" for q in QUANTILES)
                  + f" | {s['under_9px']:.0%} | {s['in_20_120px']:.0%} | {r['p5']:.1f} / {r['p50']:.1f} / "
                  f"{r['p95']:.1f} |")
    print_test(summary["test"])
    print("\n| training sweeps | wide sweeps' working width (px) p50 / p90 / max | wide over 1,400 px "
          "| parametric maps past infinity | past half the far focus's diopters |\n|---|---|---|---|---|")
    for name, rows in train.items():
        w = np.array([r["width_px"] for r in rows if r["kind"] == "wide"] or [np.nan], np.float64)
        m = np.array([r["map_far_ratio"] for r in rows if r["map_far_ratio"] is not None], np.float64)
        summary["training"][name]["limits"] = {
            "wide_width_p50": float(np.median(w)), "wide_over_1400": float(np.mean(w > 1400)),
            "maps_past_infinity": float(np.mean(m < 0)), "maps_past_half_far": float(np.mean(m < 0.5 - 1e-6))}
        print(f"| {name} | {np.percentile(w, 50):.0f} / {np.percentile(w, 90):.0f} / {np.max(w):.0f} | "
              f"{np.mean(w > 1400):.0%} | {np.mean(m < 0):.0%} | {np.mean(m < 0.5 - 1e-6):.0%} |")
    if a.window_coverage:
        summary["window_coverage"] = {c.stem: window_coverage(c, a.coverage_every, a.coverage_split)
                                      for c in a.configs}
        print("\n| renders | kind | n | window depth range / sweep range p10 / p50 / p90 | median, < 1000 px across "
              "| median, >= 2000 px across |\n|---|---|---|---|---|---|")
        for name, kinds in summary["window_coverage"].items():
            for kind, st in kinds.items():
                w1, w2 = st["median_width_under_1000px"], st["median_width_2000px_up"]
                print(f"| {name} | {kind} | {st['n']} | {st['p10']:.2f} / {st['p50']:.2f} / {st['p90']:.2f} | "
                      f"{'-' if w1 is None else f'{w1:.2f}'} | {'-' if w2 is None else f'{w2:.2f}'} |")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(a.out, json.dumps({"summary": summary, "configs": [str(c) for c in a.configs]}, indent=1))
    figure(train, summary["test"], a.figure)
    print(f"wrote {a.out} and {a.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
