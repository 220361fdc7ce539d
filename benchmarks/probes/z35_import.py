"""Is the Nikon Z35's field curvature the lens's or our import's? (issues 33, 35)

    python -m benchmarks.probes.z35_import [--txt ../shared/data/lenses/diffoptics_nikon_z35_f1.8_JPA2019090949.txt]

DiffOptics' format puts `k a4 a6 ...` after the material column (its Aspheric sag adds sum ai[i] r^(2i+4): the
first coefficient after the conic is the r^4 term). Three readings of the same file are compared:
  r2-first  the coefficients as the r^2, r^4, ... terms (how lenses/nikon_z35_f1.8_diffoptics.json was made
            before this probe: an r^2 term changes the paraxial power of two surfaces),
  r4-first  as DiffOptics defines them (r^4, r^6, ...),
  spherical the two aspheres' polynomial terms dropped (conics are 0 in the file).
For each: a hand y-nu paraxial trace straight from the text (nd, no project code; EFL, BFL, where the paraxial
image lies against the file's `I` plane), the Petzval sum sum phi_i/(n_i n_i') and its image-side sag at the image
circle's edge, and real-ray traces (training.optics.field_focus, the best-focus map's own definition): the
min-RMS, sagittal and tangential image shifts at field radius r (sensor diagonal, 1 = corner) for an object at
100 m, sensor at the on-axis best focus, in um and in object diopters (dz / f^2, + = nearer); and the defocus blur
per object diopter in pixels of the lens's sensor (entrance pupil x EFL x 1 D / pixel).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

DEFAULT_TXT = Path("../shared/data/lenses/diffoptics_nikon_z35_f1.8_JPA2019090949.txt")
RADII = (0.29, 0.5, 0.7, 1.0)


def hand_paraxial(txt: Path, a2: dict[int, float]) -> dict:
    """y-nu trace of the file's rows with index nd (material 'nd/V', AIR/OCCLUDER = 1); a2: row -> r^2 coefficient
    added to that surface's curvature (2 a2). Returns EFL, BFL (last surface to focus), the paraxial focus against
    the I plane (mm, + = behind it), the Petzval sum (1/mm) and the Petzval sag at the image-circle edge (um)."""
    rows = [ln.split() for ln in txt.read_text().splitlines() if ln.split() and ln.split()[0] in ("O", "S", "A", "I")]
    rows = [r for r in rows if r[0] != "O"]
    n_of = lambda m: 1.0 if m.upper() in ("AIR", "OCCLUDER") else float(m.split("/")[0])  # noqa: E731
    y, nu, n, petz = 1.0, 0.0, 1.0, 0.0
    for i, r in enumerate(rows[:-1]):
        if i > 0:
            y += float(r[1]) * nu / n
        roc = float(r[2])
        c = (0.0 if roc == 0 else 1.0 / roc) + 2.0 * a2.get(i, 0.0)
        n2 = n_of(r[4])
        phi = (n2 - n) * c
        petz += phi / (n * n2)
        nu -= y * phi
        n = n2
    efl, bfl = -1.0 / nu, -y / nu
    h = float(rows[-1][3]) / 2.0  # image-circle radius
    return {"efl_mm": efl, "bfl_mm": bfl, "focus_minus_I_mm": bfl - float(rows[-1][1]),
            "petzval_per_mm": petz, "petzval_sag_um": -0.5 * h * h * petz * 1000.0, "image_radius_mm": h}


def readings(txt: Path):
    """(name, lens, {row: a2}) for the three readings, from the project's reader of the file."""
    from aat_deploy.lens.io import load_diffoptics_txt

    lens = load_diffoptics_txt(txt)
    asph = [i for i, s in enumerate(lens.surfaces) if any(s.asphere_from_r2)]
    # Each reading is made from the coefficients as written (after the conic), whatever the reader does with them.
    rows = [ln.split() for ln in txt.read_text().splitlines() if ln.split() and ln.split()[0] in "SA"]
    written = {i: tuple(float(t) for t in rows[i][6:]) for i in asph}

    def with_coeffs(f):
        return replace(lens, surfaces=tuple(replace(s, asphere_from_r2=f(written[i])) if i in written else s
                                            for i, s in enumerate(lens.surfaces)))

    r2, r4, sph = with_coeffs(lambda c: c), with_coeffs(lambda c: (0.0,) + c), with_coeffs(lambda c: ())
    return lens, [("r2-first", r2, {i: written[i][0] for i in asph}), ("r4-first", r4, {}), ("spherical", sph, {})]


def traced(lens) -> dict:
    from aat_deploy.optics.paraxial import paraxial_data
    from training.optics.field_focus import image_shift_mm
    from training.optics.focus import focus

    px = paraxial_data(lens)
    zs = focus(lens, 100.0)
    # defocus blur diameter per object diopter (far object): entrance pupil x EFL x 1 D, in sensor pixels
    out = {"efl_mm": px.efl_mm, "fno": px.fno, "hfov_deg": px.hfov_deg,
           "blur_px_per_d": px.entrance_pupil_mm * px.efl_mm * 1e-3 / (px.pixel_um * 1e-3)}
    for r in RADII:
        u = (math.sqrt(0.5), math.sqrt(0.5))  # radial on the diagonal: tangential; across it: sagittal
        rms, tan, sag = (image_shift_mm(lens, r, 100.0, zs, direction=d) for d in (None, u, (-u[1], u[0])))
        out[r] = {k: v * 1000.0 for k, v in (("rms_um", rms), ("tan_um", tan), ("sag_um", sag))}
        out[r]["rms_D"] = -rms / px.efl_mm**2 * 1000.0  # inward image shift = nearer object = +D
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--txt", type=Path, default=DEFAULT_TXT, help="the DiffOptics Z35 text file")
    a = ap.parse_args(argv)
    if not a.txt.is_file():
        print(f"z35_import: {a.txt}: no such file (../shared/data is needed)", file=sys.stderr)
        return 2
    lens, cases = readings(a.txt)
    read = [s.asphere_from_r2 for s in lens.surfaces if any(s.asphere_from_r2)]
    print(f"{a.txt.name}: the project's reader gives asphere_from_r2 = {read}")
    print("\nhand paraxial trace from the text (nd; asphere-independent except through an r^2 term):")
    print("reading   | EFL mm | BFL mm | focus - I plane um | Petzval sum 1/mm | Petzval sag at image edge um")
    for name, _, a2 in cases:
        h = hand_paraxial(a.txt, a2)
        print(f"{name:9s} | {h['efl_mm']:6.3f} | {h['bfl_mm']:6.3f} | {h['focus_minus_I_mm'] * 1000:+18.1f} | "
              f"{h['petzval_per_mm']:+16.4f} | {h['petzval_sag_um']:+.1f} (h = {h['image_radius_mm']:.3f} mm)")
    print("\nreal-ray trace, object at 100 m, sensor at the on-axis best focus; image shift at field radius r "
          "(um, - = towards the lens) and min-RMS in object diopters:")
    print("reading   | EFL mm | F/#  | HFOV deg | blur px/D | " + " | ".join(f"r={r:g}: rms/tan/sag um, D" for r in RADII))
    for name, ln, _ in cases:
        t = traced(ln)
        cells = [f"{t[r]['rms_um']:+.0f}/{t[r]['tan_um']:+.0f}/{t[r]['sag_um']:+.0f}, {t[r]['rms_D']:+.1f} D"
                 for r in RADII]
        print(f"{name:9s} | {t['efl_mm']:6.3f} | {t['fno']:.2f} | {t['hfov_deg']:8.2f} | {t['blur_px_per_d']:9.2f} | " + " | ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
