"""Stamp a lens's focus table and exit pupil into an exported PSF surrogate's metadata (no retraining), so that
torch-free twins (`aat_deploy.twin`) render sensor tilt and focus breathing with the real-ray focus table:

    python scripts/stamp_psf_optics.py PSF.onnx LENS.json     # e.g. models/psf_rf50.onnx lenses/canon_rf50mm_f1.8.json

The lens file must be the one the surrogate was fitted for, sensor included (its prescription hash is checked).
Surrogates exported since these keys exist carry them already (`training.psf.export.optics_metadata`).
"""

from __future__ import annotations

import sys

from training.lens.io import load_lens
from training.psf.export import stamp_optics_metadata

if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    md = stamp_optics_metadata(sys.argv[1], load_lens(sys.argv[2]))
    print(f"{sys.argv[1]}: stamped {', '.join(sorted(md))}")
