"""Cheap aberrated PSFs of any camera: a thin lens (focal length, f-number, pixel pitch) whose best focus moves over
the field by a random smooth map (field curvature, tilt, astigmatism), for training one DfF net on many cameras.

The best-focus map is in object diopters (1/m, distances from the sensor plane): for a frame focused at F, the
object in best focus at normalised field (x, y) (x right, y up, +-1 at the sensor edges) is at

    D_best(x, y) = 1/F + (c2 r^2 + c4 r^4 + tx x + ty y) * (1 + g (1/F - d_mid))     r: 0 centre, 1 corner

and astigmatism splits it into a tangential and a sagittal focus D_best +- a2 r^2 / 2. A point at depth D is
blurred along the radial direction by the thin-lens blur of its distance to the tangential focus and across it
by that to the sagittal focus (at the tangential focus the meridional rays meet, so the radial extent vanishes),
each widened by a residual blur b0 (diffraction, residual aberrations) in quadrature. The kernel profile is
exp(-c rho^p) over the blur ellipse (rho = 1 at its edge): p = 2 is a Gaussian of sigma = blur / 4 (the
thin-lens baseline's), large p a uniform disk, the shape of a geometric defocus PSF.

`ParametricSource` has the PSF-source interface of `aat_deploy.render.sources` (kernels in the storage of
`aat_deploy.psf.kernel`), so the layered renderer draws with it; `frame_diopters` is the map a DfF net is given
(D_best at every pixel): what tracing the lens or calibrating it gives for a real lens.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from aat_deploy.optics.thin_lens import blur_diameter_px
from aat_deploy.psf.kernel import KernelSpec

FAR_D = 1e-3  # object diopters (1 km): best foci beyond it are extrapolated linearly (`Camera.blur_about_px`)


@dataclass(frozen=True)
class Aberrations:
    """Coefficients of the best-focus map (diopters): c2, c4 field curvature (r^2, r^4, r = 1 at the corner), tx,
    ty tilt (x, y = +-1 at the edges), a2 astigmatism (tangential minus sagittal focus at r = 1), g its change
    with the frame's focus (per diopter, about d_mid); b0_px residual blur diameter (px); shape p of the profile."""

    c2: float = 0.0
    c4: float = 0.0
    tx: float = 0.0
    ty: float = 0.0
    a2: float = 0.0
    g: float = 0.0
    d_mid: float = 1.0
    b0_px: float = 1.0
    shape_p: float = 2.0

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Camera:
    """A camera at its working resolution: focal length (mm), f-number, the full sensor in pixels (H, W) and the
    pixel pitch (mm), with the aberrations of its best-focus map."""

    focal_mm: float
    f_number: float
    sensor_hw: tuple[int, int]
    pixel_mm: float
    aberrations: Aberrations = Aberrations()

    @property
    def epd_mm(self) -> float:
        return self.focal_mm / self.f_number

    @property
    def aspect_wh(self) -> float:
        return self.sensor_hw[1] / self.sensor_hw[0]

    def blur_px(self, depth_m, focus_m) -> np.ndarray:
        """Thin-lens blur-disk diameter (px) at depth_m for focus focus_m (metres from the sensor)."""
        return blur_diameter_px(np.asarray(depth_m, np.float64), np.asarray(focus_m, np.float64), self.focal_mm,
                                self.epd_mm, self.pixel_mm)

    def blur_about_px(self, depth_m, best_d) -> np.ndarray:
        """Thin-lens blur-disk diameter (px) at depth_m about a best focus of best_d object diopters, any sign: a
        best focus at or beyond infinity (best_d <= FAR_D, the far end of a field-curved sweep) is the lens at
        FAR_D plus the blur growth there times the diopters beyond it (first order), so that blur keeps growing
        with |1/depth - best_d| as the map the net is told says (focusing at FAR_D instead left objects at
        infinity sharp in frames whose map put best focus beyond it)."""
        b = np.asarray(best_d, np.float64)
        at = self.blur_px(depth_m, 1.0 / np.maximum(b, FAR_D))
        beyond = np.maximum(FAR_D - b, 0.0)
        return at + self.defocus_px_per_diopter(1.0 / FAR_D) * beyond

    def defocus_px_per_diopter(self, focus_m: float) -> float:
        """Blur growth (px of blur diameter per diopter of defocus) near focus_m: the defocus scale a net is given,
        as the runtime computes it (`aat_deploy.calibrate.format.thin_lens_defocus_scale_px_per_d`)."""
        from aat_deploy.calibrate.format import thin_lens_defocus_scale_px_per_d

        return thin_lens_defocus_scale_px_per_d(self.focal_mm, self.f_number, self.pixel_mm * 1000.0, float(focus_m))

    def radius(self, x, y) -> np.ndarray:
        """Normalised image radius (1 = sensor corner) of field (x, y)."""
        a = self.aspect_wh
        return np.hypot(np.asarray(x) * a, np.asarray(y)) / np.hypot(a, 1.0)

    def shift_diopters(self, x, y, focus_m) -> np.ndarray:
        """Best focus minus the nominal focus (diopters) at field (x, y) for frames focused at focus_m."""
        ab = self.aberrations
        r2 = self.radius(x, y) ** 2
        base = ab.c2 * r2 + ab.c4 * r2 * r2 + ab.tx * np.asarray(x) + ab.ty * np.asarray(y)
        return base * (1.0 + ab.g * (1.0 / np.asarray(focus_m, np.float64) - ab.d_mid))

    def frame_diopters(self, focus_m, h: int, w: int, origin=(0, 0)) -> np.ndarray:
        """(S, h, w) float32: object diopters in best focus at every pixel of an h x w window at `origin` (row,
        col) of the sensor, for frames focused at focus_m (S,)."""
        from aat_deploy.optics.field import pixel_fields

        x, y = pixel_fields(h, w, self.sensor_hw, origin)
        f = np.asarray(focus_m, np.float64).reshape(-1, 1, 1)
        return (1.0 / f + self.shift_diopters(x[None], y[None], f)).astype(np.float32)

    def max_extra_blur_px(self, focus_m) -> float:
        """Upper bound of the blur the aberrations add to the thin lens's (px), for window sizes."""
        ab = self.aberrations
        shift = (abs(ab.c2) + abs(ab.c4) + abs(ab.tx) + abs(ab.ty)) * (1 + abs(ab.g) * 10) + abs(ab.a2)
        f = np.atleast_1d(np.asarray(focus_m, np.float64))
        k = max(self.defocus_px_per_diopter(float(v)) for v in (f.min(), f.max()))
        return float(k * shift + ab.b0_px)


class ParametricSource:
    """PSF source (`aat_deploy.render.sources` interface) of a `Camera`: elliptical kernels of the thin-lens blur
    about the tangential and sagittal foci of its best-focus map. numpy; kernels float32 (N, k, k), unit sum."""

    def __init__(self, camera: Camera, focus_m, size: int = 11):
        self.camera = camera
        self.spec = KernelSpec(size=size, margin_px=camera.max_extra_blur_px(focus_m) + 2.0)

    @property
    def k(self) -> int:
        return self.spec.size

    def blur_px(self, depth_m, focus_m) -> np.ndarray:
        return self.camera.blur_px(depth_m, focus_m)

    def scale(self, depth_m, focus_m) -> np.ndarray:
        b = self.camera.blur_px(depth_m, focus_m)
        return np.maximum(1.0, (b + self.spec.margin_px) / (self.spec.size - 1))

    def __call__(self, x, y, depth_m, focus_m) -> tuple[np.ndarray, np.ndarray]:
        x, y, d, f = (np.asarray(a, np.float64).ravel() for a in np.broadcast_arrays(x, y, depth_m, focus_m))
        cam, ab = self.camera, self.camera.aberrations
        best = 1.0 / f + cam.shift_diopters(x, y, f)
        half = 0.5 * ab.a2 * cam.radius(x, y) ** 2
        # blur about the tangential (radial extent) and sagittal (azimuthal extent) foci, floored by b0
        b_r = np.hypot(cam.blur_about_px(d, best + half), ab.b0_px)
        b_t = np.hypot(cam.blur_about_px(d, best - half), ab.b0_px)
        s = self.scale(d, f)
        k = self.spec.size
        off = (np.arange(k) - k // 2, )[0]
        cols = off[None, None, :] * s[:, None, None]  # (N, 1, k) px, right
        up = -off[None, :, None] * s[:, None, None]  # (N, k, 1) px, up (row 0 at the top)
        a = cam.aspect_wh
        ex, ey = x * a, y
        norm = np.hypot(ex, ey)
        ex, ey = np.where(norm > 1e-9, ex / np.maximum(norm, 1e-12), 1.0), np.where(norm > 1e-9, ey / np.maximum(norm, 1e-12), 0.0)
        u_r = cols * ex[:, None, None] + up * ey[:, None, None]
        u_t = -cols * ey[:, None, None] + up * ex[:, None, None]
        # half-axes widened by the cell (a kernel narrower than a cell still covers its own cell)
        ar = np.sqrt((b_r / 2) ** 2 + (0.5 * s) ** 2)[:, None, None]
        at = np.sqrt((b_t / 2) ** 2 + (0.5 * s) ** 2)[:, None, None]
        rho2 = (u_r / ar) ** 2 + (u_t / at) ** 2
        p = float(ab.shape_p)
        c = 2.0 ** (2.0 / p)  # p = 2: sigma = blur / 4; p -> inf: a uniform disk of the blur's diameter
        ker = np.exp(-c * rho2 ** (p / 2))
        ker /= ker.sum((1, 2), keepdims=True)
        return ker.astype(np.float32), s.astype(np.float32)
