"""Stamp a lens's focus table, exit pupil and best-focus map into an exported PSF surrogate's metadata (no
retraining), so that torch-free twins (`aat_deploy.diagnose.twin`) render sensor tilt and focus breathing with the real-ray
focus table, and `aat-infer --method focus --psf PSF.onnx` maps frames aberration-aware:

    python scripts/stamp_psf_optics.py PSF.onnx LENS.json     # e.g. models/psf_rf50.onnx lenses/canon_rf50mm_f1.8.json

The lens file must be the one the surrogate was fitted for, sensor included (its prescription hash is checked).
The best-focus map is `<lens folder>/best_focus/<lens stem>.json` (made by `aat-lens focus-map LENS`, which can also stamp it: `--stamp PSF.onnx`); without it
only the focus table and exit pupil are stamped, and the script says how to make it.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aat_deploy.focus.bestfocus import load_json, map_path_for_lens  # noqa: E402
from aat_deploy.lens.io import load_lens  # noqa: E402
from training.psf.export import stamp_optics_metadata  # noqa: E402

if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    mp = map_path_for_lens(sys.argv[2])
    fmap = load_json(mp) if mp.is_file() else None
    md = stamp_optics_metadata(sys.argv[1], load_lens(sys.argv[2]), best_focus=fmap)
    print(f"{sys.argv[1]}: stamped {', '.join(sorted(md))}")
    if fmap is None:
        print(f"no best-focus map ({mp}): make it with `aat-lens focus-map {sys.argv[2]}`, then "
              "stamp again")
