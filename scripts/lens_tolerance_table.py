"""Write a lens's tolerance sensitivity table next to its PSF surrogate, so the `lens_tolerance` effect (and
`aat-diagnose`) renders it without torch: the change of the best-focus surface per 0.05 mm of every air gap and
of every element's decentre, traced through the prescription (`training.optics.tolerance`).

    python -m scripts.lens_tolerance_table LENS.json --psf models/psf_rf50.onnx   # -> models/tolerance_<key>.json
    python -m scripts.lens_tolerance_table LENS.json --out DIR [--force] [--focus-m 0.07,0.15,0.5]

The file name carries the lens's optics key (surfaces, stop, sensor size; not its pixels), which the effect checks.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("lens", help="lens file (aat-lens-v1)")
    ap.add_argument("--psf", help="the lens's PSF surrogate: the table goes next to it")
    ap.add_argument("--out", help="folder for the table (instead of --psf's)")
    ap.add_argument("--rays", type=int, default=1024, help="rays per field point")
    ap.add_argument("--force", action="store_true", help="replace an existing table")
    ap.add_argument("--focus-m", default="0.5,1.5,20",
                    help="focus distances of the table, m from the sensor (default 0.5,1.5,20; a phone lens's "
                         "working range is nearer, e.g. 0.07,0.15,0.5)")
    a = ap.parse_args(argv)
    if not (a.psf or a.out):
        print("lens_tolerance_table: error: give --psf or --out", file=sys.stderr)
        return 2
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import table_name
    from training.optics.tolerance import sensitivity_table

    try:
        lens = load_lens(a.lens)
    except Exception as e:  # noqa: BLE001 (the lens reader's errors name the file)
        print(f"lens_tolerance_table: error: {e}", file=sys.stderr)
        return 2
    folder = Path(a.out) if a.out else Path(a.psf).parent
    path = folder / table_name(lens)
    if path.exists() and not a.force:
        print(f"lens_tolerance_table: error: {path} exists (use --force)", file=sys.stderr)
        return 2
    try:
        focus_m = tuple(float(t) for t in a.focus_m.split(","))
    except ValueError:
        print(f"lens_tolerance_table: error: --focus-m {a.focus_m!r}: expected comma-separated metres",
              file=sys.stderr)
        return 2
    t0 = time.time()
    table = sensitivity_table(lens, focus_m=focus_m, n_rays=a.rays,
                              progress=lambda m: print(f"  {m}", file=sys.stderr, flush=True))
    folder.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(table))
    os.replace(tmp, path)
    print(f"{path} ({len(table['perturbations'])} perturbations, {time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
