"""Write lenses/ideal_thin_rf50.json: a perfect thin lens with the RF50's focal length, F-number and sensor.

This is the optics of the thin-lens baseline: the only difference from the RF50 is the aberrations.
    python -m scripts.make_thin_lens [--force]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from aat_deploy.lens.io import load_lens, save_lens
from aat_deploy.lens.schema import Lens, Surface
from aat_deploy.optics.paraxial import paraxial_data

ROOT = Path(__file__).resolve().parents[1]


def thin_lens_like(real: Lens) -> Lens:
    """An ideal (aberration-free) lens in one plane, which is also the stop, matching EFL and F-number."""
    p = paraxial_data(real)
    ideal = Surface(
        curvature_per_mm=0.0,
        thickness_mm=p.efl_mm,  # sensor at the focal plane: infinity focus
        semi_diameter_mm=p.entrance_pupil_mm / 2.0,
        kind="ideal",
        focal_length_mm=p.efl_mm,
    )
    return Lens(
        name=f"Ideal thin lens matching {real.name}",
        surfaces=(ideal,),
        stop_index=0,
        sensor=real.sensor,
        design_wavelength_nm=real.design_wavelength_nm,
        provenance={
            "source": f"scripts/make_thin_lens.py from {real.provenance.get('file', 'lenses/canon_rf50mm_f1.8.json')}",
            "matches": f"EFL {p.efl_mm:.6f} mm, F/{p.fno:.6f}, sensor {real.sensor.width_mm} x {real.sensor.height_mm} mm "
            f"at {p.wavelength_nm} nm (paraxial values of the real lens)",
            "model": "a perfect paraxial lens: every object plane images without aberration; the stop is the lens",
        },
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", default=str(ROOT / "lenses/canon_rf50mm_f1.8.json"))
    ap.add_argument("--out", default=str(ROOT / "lenses/ideal_thin_rf50.json"))
    ap.add_argument("--force", action="store_true", help="overwrite an existing file")
    a = ap.parse_args()
    save_lens(thin_lens_like(load_lens(a.real)), a.out, force=a.force)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
