"""Make a lens's best-focus map for the aberration-aware classical depth from focus (`aat-infer --method focus
--lens LENS`): real-ray traced (training.optics.field_focus), then calibrated on rendered stacks
(training.render.focus_calibration), written next to the lens as `<lens folder>/best_focus/<lens stem>.json`:

    python scripts/make_focus_map.py lenses/canon_rf50mm_f1.8.json [--force] [--no-calibrate] [--psf trace|PSF.onnx]
                                     [--out PATH] [--stamp PSF.onnx]

--stamp also writes the map into that PSF surrogate's metadata (as scripts/stamp_psf_optics.py does), so
`aat-infer --method focus --psf PSF.onnx` finds it. About 4 min tracing plus 3 min calibrating on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def make(lens_path: Path, calibrate: bool = True, psf: str = "trace", progress: bool = True):
    """(map, calibration points) for a lens file."""
    from aat_deploy.lens.io import load_lens
    from training.optics.field_focus import best_focus_map
    from training.render.focus_calibration import CalibrationConfig
    from training.render.focus_calibration import calibrate as run_calibration

    lens = load_lens(lens_path)
    fmap = best_focus_map(lens, progress=progress)
    points: list[dict] = []
    if calibrate:
        fmap, points = run_calibration(lens, fmap, CalibrationConfig(psf=psf), progress=progress)
    notes = dict(fmap.notes)
    notes["lens_file"] = str(lens_path)
    notes["calibration_points"] = points
    from dataclasses import replace

    return replace(fmap, notes=notes), points


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("lens", type=Path)
    ap.add_argument("--out", type=Path, help="default: <lens folder>/best_focus/<lens stem>.json")
    ap.add_argument("--force", action="store_true", help="replace an existing map")
    ap.add_argument("--no-calibrate", action="store_true", help="traced map only (no rendered calibration)")
    ap.add_argument("--psf", default="trace", help="PSFs of the calibration renders: trace (default) or a .onnx")
    ap.add_argument("--stamp", type=Path, help="also stamp the map into this PSF surrogate's metadata")
    a = ap.parse_args(argv)
    from aat_deploy.focus.bestfocus import map_path_for_lens

    out = a.out or map_path_for_lens(a.lens)
    if out.exists() and not a.force:
        print(f"make_focus_map: error: {out}: exists (pass --force to replace it)", file=sys.stderr)
        return 2
    t0 = time.time()
    fmap, points = make(a.lens, not a.no_calibrate, a.psf)
    fmap.save_json(out)
    print(f"wrote {out} ({time.time() - t0:.0f} s)")
    for p in points:
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in p.items()}))
    if a.stamp:
        from aat_deploy.lens.io import load_lens
        from training.psf.export import stamp_optics_metadata

        md = stamp_optics_metadata(a.stamp, load_lens(a.lens), best_focus=fmap)
        print(f"{a.stamp}: stamped {', '.join(sorted(md))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
