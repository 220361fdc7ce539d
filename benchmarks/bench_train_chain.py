"""Wall time of `aat-train --lens` per stage, for the presets (the "Train for your own lens" numbers in
BENCHMARKS.md).

    OMP_WAIT_POLICY=PASSIVE nice -n 10 python -m benchmarks.bench_train_chain [--preset tiny small]
        [--lens lenses/canon_ef50mm_f1.8.json] [--out DIR] [--timeout-min 25]

Each preset runs as its own `aat-train` process in a fresh folder (DIR/<preset>, default a temporary folder):
tiny at 96 x 64 px, small and paper at the lens file's sensor (960 x 640 px for the shipped lenses). Then the
same command runs again, which must find every stage up to date (the resume/no-op cost). Stage times come from
the run folder's stage records (DIR/<preset>/stages/*.json). A run that exceeds --timeout-min is stopped and the
stages it finished are reported as such.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STAGES = ["lens", "psf", "train_aat", "train_thin", "export", "evaluate", "report"]
RESOLUTION = {"tiny": "96,64"}


def command(preset: str, lens: str, out: Path) -> list[str]:
    cmd = [sys.executable, "-m", "training.cli.train", "--lens", lens, "--preset", preset, "--out", str(out),
           "--no-progress"]
    if preset in RESOLUTION:
        cmd += ["--resolution", RESOLUTION[preset]]
    return cmd


def run(cmd: list[str], timeout_s: float) -> tuple[float, bool, str]:
    """(wall time s, finished, last lines of output)."""
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE", "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    try:
        res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout_s, check=False)
        ok, text = res.returncode == 0, res.stdout + res.stderr
    except subprocess.TimeoutExpired as e:
        ok, text = False, f"stopped after {timeout_s:.0f} s\n{(e.stdout or b'')[-2000:]!r}"
    return time.perf_counter() - t0, ok, "\n".join(text.strip().splitlines()[-4:])


def stage_table(out: Path) -> list[tuple[str, float | None]]:
    rows = []
    for s in STAGES:
        p = out / "stages" / f"{s}.json"
        rows.append((s, json.loads(p.read_text())["seconds"] if p.is_file() else None))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", nargs="+", default=["tiny", "small"], choices=["tiny", "small", "paper"])
    ap.add_argument("--lens", default=str(ROOT / "lenses" / "canon_ef50mm_f1.8.json"))
    ap.add_argument("--out", help="folder for the runs (kept); default: a temporary folder, deleted")
    ap.add_argument("--timeout-min", type=float, default=25.0, help="stop a preset's run after this many minutes")
    args = ap.parse_args()
    base = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_chain_"))
    results = {}
    try:
        for preset in args.preset:
            out = base / preset
            if out.exists():
                shutil.rmtree(out)
            cmd = command(preset, args.lens, out)
            wall, ok, tail = run(cmd, args.timeout_min * 60)
            print(f"{preset}: {'finished' if ok else 'NOT finished'} in {wall:.1f} s\n{tail}", flush=True)
            rerun = run(cmd, 600)[0] if ok else None
            results[preset] = (wall, ok, rerun, stage_table(out), json.loads((out / "config.json").read_text())
                               if (out / "config.json").is_file() else {})
    finally:
        if not args.out:
            shutil.rmtree(base, ignore_errors=True)
    lens = Path(args.lens).name
    print(f"\n### aat-train --lens {lens}: wall time per stage (s), {os.cpu_count()} CPU cores\n")
    names = list(results)
    print("| stage | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for i, s in enumerate(STAGES):
        cells = []
        for n in names:
            v = results[n][3][i][1]
            cells.append("not reached" if v is None else f"{v:.1f}")
        print(f"| {s} | " + " | ".join(cells) + " |")
    print("| **whole command** | " + " | ".join(
        f"{results[n][0]:.1f}" + ("" if results[n][1] else " (stopped)") for n in names) + " |")
    print("| same command again (all up to date) | " + " | ".join(
        "–" if results[n][2] is None else f"{results[n][2]:.1f}" for n in names) + " |")
    for n in names:
        c = results[n][4]
        if c:
            t = c["train"]
            print(f"\n{n}: {c['net']} {c['size']}, {c['stack']} frames, crops {t['crop_hw'][1]}x{t['crop_hw'][0]}, "
                  f"{t['n_items']} training scenes, {t['steps']} steps x batch {t['batch_size']}, PSF fit "
                  f"{c['psf']['fit_minutes'] * 60:.0f} s on {c['psf']['axis_n']} traced PSFs, "
                  f"{c['eval']['n_scenes']} evaluation scenes")


if __name__ == "__main__":
    main()
