"""A lens as plain data: surfaces in order, the stop, the sensor. Units: mm throughout.

Coordinates: z is the optical axis, z = 0 at the vertex of the first surface, +z towards the sensor.
Each surface's `thickness_mm` is the axial distance from its vertex to the next vertex; the last surface's
thickness is the nominal distance to the sensor (the focus state stored in the file; `training.optics.focus`
computes the sensor position for any object distance).

Our JSON file format ("aat-lens-v1") is documented in `lenses/README.md` and read/written by
`aat_deploy.lens.io`. This module holds only the dataclasses and derived geometry.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field, replace

from .materials import Material, parse_material

SURFACE_KINDS = ("standard", "ideal")


@dataclass(frozen=True)
class Surface:
    """One refracting surface.

    curvature_per_mm: 1 / radius of curvature (0 = flat). Sag convention: positive curvature = centre of
        curvature on the +z (sensor) side.
    thickness_mm: axial distance from this vertex to the next one (last surface: to the sensor).
    semi_diameter_mm: clear aperture radius; rays hitting outside are lost (vignetting).
    material: medium after the surface ("air", "nd/Vd" or a catalogue glass name).
    conic: conic constant k (0 sphere, -1 paraboloid).
    asphere_from_r2: even-asphere coefficients of r^2, r^4, r^6, ... (mm^(1-2i)); the first entry is r^2.
    kind: "standard" (conic + even asphere) or "ideal" (a perfect paraxial lens of focal length
        `focal_length_mm` in a plane, used for the thin-lens baseline).
    """

    curvature_per_mm: float
    thickness_mm: float
    semi_diameter_mm: float
    material: str = "air"
    conic: float = 0.0
    asphere_from_r2: tuple[float, ...] = ()
    kind: str = "standard"
    focal_length_mm: float | None = None

    @property
    def radius_mm(self) -> float:
        return math.inf if self.curvature_per_mm == 0 else 1.0 / self.curvature_per_mm

    @property
    def is_spherical(self) -> bool:
        return self.kind == "standard" and self.conic == 0 and not any(self.asphere_from_r2)

    @property
    def paraxial_curvature_per_mm(self) -> float:
        """Curvature seen by paraxial rays: sag ~ (c/2 + a2) r^2, so the r^2 asphere term adds 2*a2."""
        a2 = self.asphere_from_r2[0] if self.asphere_from_r2 else 0.0
        return self.curvature_per_mm + 2.0 * a2

    def sag(self, r2: float) -> float:
        """Surface height z(r) relative to the vertex, r2 = x^2 + y^2 in mm^2."""
        c, k = self.curvature_per_mm, self.conic
        z = c * r2 / (1.0 + math.sqrt(max(1.0 - (1.0 + k) * c * c * r2, 0.0)))
        for i, a in enumerate(self.asphere_from_r2, start=1):
            z += a * r2**i
        return z


@dataclass(frozen=True)
class Sensor:
    """Image sensor: physical size (mm) and the working resolution (pixels)."""

    width_mm: float
    height_mm: float
    width_px: int
    height_px: int

    @property
    def pixel_mm(self) -> float:
        """Pixel pitch (mm); pixels are square to 0.5 %, else `validate` rejects the sensor."""
        return self.width_mm / self.width_px

    @property
    def half_diagonal_mm(self) -> float:
        return 0.5 * math.hypot(self.width_mm, self.height_mm)

    def with_resolution(self, width_px: int, height_px: int) -> "Sensor":
        return replace(self, width_px=int(width_px), height_px=int(height_px))

    @staticmethod
    def from_half_diagonal(half_diag_mm: float, width_px: int, height_px: int) -> "Sensor":
        """Sensor of the given half-diagonal and the aspect ratio of the resolution (square pixels)."""
        scale = 2.0 * half_diag_mm / math.hypot(width_px, height_px)
        return Sensor(width_px * scale, height_px * scale, int(width_px), int(height_px))


@dataclass(frozen=True)
class Lens:
    """A rotationally symmetric sequential lens in air."""

    name: str
    surfaces: tuple[Surface, ...]
    stop_index: int
    sensor: Sensor
    design_wavelength_nm: float = 587.5618
    provenance: dict = field(default_factory=dict, compare=False)

    # --- derived geometry -------------------------------------------------------------------------
    @property
    def vertex_z_mm(self) -> tuple[float, ...]:
        """z of every surface vertex (first = 0)."""
        z, out = 0.0, []
        for s in self.surfaces:
            out.append(z)
            z += s.thickness_mm
        return tuple(out)

    @property
    def nominal_sensor_z_mm(self) -> float:
        """Sensor z stored in the prescription (sum of all thicknesses)."""
        return sum(s.thickness_mm for s in self.surfaces)

    @property
    def total_track_mm(self) -> float:
        """First vertex to last vertex."""
        return self.vertex_z_mm[-1]

    def materials(self) -> list[Material]:
        """Medium after each surface, plus the object-space medium (air) at index 0: len = N + 1."""
        return [parse_material("air")] + [parse_material(s.material) for s in self.surfaces]

    def indices(self, wavelength_nm: float) -> list[float]:
        """Refractive index before surface 0, then after each surface, at one wavelength."""
        return [float(m.n(wavelength_nm)) for m in self.materials()]

    def with_stop_semi_diameter(self, semi_diameter_mm: float) -> "Lens":
        surfs = list(self.surfaces)
        surfs[self.stop_index] = replace(surfs[self.stop_index], semi_diameter_mm=float(semi_diameter_mm))
        return replace(self, surfaces=tuple(surfs))

    def to_dict(self) -> dict:
        """Plain-data form in our file format (see aat_deploy.lens.io.save_lens)."""
        surfs = []
        for s in self.surfaces:
            d = {
                "radius_mm": None if s.curvature_per_mm == 0 else 1.0 / s.curvature_per_mm,
                "thickness_mm": s.thickness_mm,
                "semi_diameter_mm": s.semi_diameter_mm,
                "material": s.material,
            }
            if s.conic:
                d["conic"] = s.conic
            if any(s.asphere_from_r2):
                d["asphere_from_r2"] = list(s.asphere_from_r2)
            if s.kind != "standard":
                d["kind"] = s.kind
                d["focal_length_mm"] = s.focal_length_mm
            surfs.append(d)
        return {
            "format": "aat-lens-v1",
            "name": self.name,
            "units": "mm",
            "provenance": self.provenance,
            "design_wavelength_nm": self.design_wavelength_nm,
            "stop_index": self.stop_index,
            "sensor": asdict(self.sensor),
            "surfaces": surfs,
        }

    def prescription_hash(self) -> str:
        """SHA-256 (first 16 hex) of the optical data (surfaces, stop, sensor), not the name or notes."""
        d = self.to_dict()
        key = {k: d[k] for k in ("surfaces", "stop_index", "sensor", "design_wavelength_nm")}
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
