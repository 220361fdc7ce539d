"""Training and validation curves of DfF runs (their `log.jsonl`), one figure, so convergence can be seen.

    python -m scripts.plot_training_curves runs/table2/paper50_dfvnet_aat runs/table2/paper50_dfvnet_thin \
        --out results/figures/curves_paper50_dfvnet.png [--force]

Left: the training loss (mean over windows of 200 steps); right: validation MAE (m) on the run's held-out
validation items, both against the optimizer step. The legend gives each run's steps, wall time and the relative
change of validation MAE over the last quarter of the run (a plateau shows as a change near 0). Also prints that
table.
"""

from __future__ import annotations

import argparse
import gzip
import json
import sys
from pathlib import Path


def read_log(run: Path) -> tuple[list[dict], list[dict]]:
    """(training rows, validation rows) of a run's log.jsonl (or log.jsonl.gz: the finished runs' logs kept in
    results/training/ are compressed)."""
    train, val = [], []
    f = run / "log.jsonl"
    if not f.is_file() and f.with_suffix(".jsonl.gz").is_file():
        f = f.with_suffix(".jsonl.gz")
    if not f.is_file():
        raise SystemExit(f"{f}: no training log")
    text = gzip.decompress(f.read_bytes()).decode() if f.suffix == ".gz" else f.read_text()
    for line in text.splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue  # a torn last line of a killed run
        if "val" in row:
            val.append(row)
        elif "total" in row:
            train.append(row)
    return train, val


def plateau(val: list[dict], key: str = "mae") -> float | None:
    """Relative change of validation `key` over the last quarter of the steps (negative = still improving)."""
    if len(val) < 3:
        return None
    last = val[-1]["step"]
    ref = [v for v in val if v["step"] <= 0.75 * last]
    if not ref:
        return None
    a, b = ref[-1]["val"][key], val[-1]["val"][key]
    return (b - a) / a if a else None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--out", required=True)
    ap.add_argument("--force", action="store_true")
    a = ap.parse_args(argv)
    out = Path(a.out)
    if out.exists() and not a.force:
        raise SystemExit(f"{out}: exists (use --force to overwrite)")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from aat_deploy.io.atomic import atomic_file

    fig, (ax_t, ax_v) = plt.subplots(1, 2, figsize=(11, 4))
    print("| run | steps | wall time (h) | stacks seen | final val MAE (m) | change over last quarter |")
    print("|---|---|---|---|---|---|")
    for r in a.runs:
        run = Path(r)
        train, val = read_log(run)
        if train:
            steps = np.array([t["step"] for t in train])
            loss = np.array([t["total"] for t in train])
            w = max(1, int(round(200 / max(1, np.median(np.diff(steps)) if len(steps) > 1 else 1))))
            k = np.ones(w) / w
            sm = np.convolve(loss, k, mode="valid") if len(loss) >= w else loss
            ax_t.plot(steps[len(steps) - len(sm):], sm, label=run.name)
        change = plateau(val)
        wall = train[-1].get("wall_s") if train else None
        seen = train[-1].get("stacks_seen") if train else None
        if val:
            ax_v.plot([v["step"] for v in val], [v["val"]["mae"] for v in val], marker="o", ms=3,
                      label=f"{run.name} ({train[-1]['step'] if train else 0} steps"
                            + (f", {wall / 3600:.1f} h" if wall else "") + ")")
        last = val[-1]["val"]["mae"] if val else float("nan")
        print(f"| {run.name} | {train[-1]['step'] if train else 0} | {wall / 3600 if wall else float('nan'):.2f} | "
              f"{seen} | {last:.4f} | {'' if change is None else f'{change:+.1%}'} |")
    ax_t.set_xlabel("step")
    ax_t.set_ylabel("training loss (200-step mean)")
    ax_t.set_yscale("log")
    ax_v.set_xlabel("step")
    ax_v.set_ylabel("validation MAE (m)")
    for ax in (ax_t, ax_v):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(out) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
