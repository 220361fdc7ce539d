"""The best-focus map against independent optics (aat-lens's spot diagrams), and the aberration-aware classical
method on rendered stacks of the RF50 with known depth, at the centre and in the corners."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import ROOT

from aat_deploy.focus import FocusConfig, classical_depth
from aat_deploy.focus.bestfocus import for_lens, from_psf, load_json, map_path_for_lens
from aat_deploy.lens.io import load_lens
from aat_deploy.optics.paraxial import paraxial_data
from training.optics.spot import spot
from training.psf.geometry import focus_table

RF50 = ROOT / "lenses/canon_rf50mm_f1.8.json"


def _best_plane_offset_mm(lens, r: float, object_m: float, sensor_z_mm: float, delta_mm: float = 0.05) -> float:
    """Where the RMS spot of a point at field radius r is smallest, relative to the sensor at sensor_z_mm: the
    vertex of RMS^2 over three planes (exactly quadratic for straight rays), from `aat-lens spot`'s code."""
    p = paraxial_data(lens)
    field_deg = math.degrees(math.atan(r * lens.sensor.half_diagonal_mm / p.efl_mm))
    rms2 = [spot(lens, field_deg, object_m=object_m, sensor_z_mm=sensor_z_mm, defocus_mm=d, grid=48).rms_um ** 2
            for d in (-delta_mm, 0.0, delta_mm)]
    return delta_mm * (rms2[0] - rms2[2]) / (2 * (rms2[0] - 2 * rms2[1] + rms2[2]))


@pytest.mark.parametrize("r,focus_m", [(0.0, 1.0), (0.5, 2.0), (0.8, 0.6), (0.9, 1.0), (0.9, 5.0)])
def test_shipped_map_agrees_with_spot_diagrams(r, focus_m):
    """The object distance the map puts in best focus has its smallest RMS spot on that frame's sensor (within
    10 um, about 0.004 D); the nominal focus distance does not, off axis (field curvature)."""
    lens = load_lens(RF50)
    fmap = load_json(map_path_for_lens(RF50))
    assert fmap.lens_hash == lens.prescription_hash()
    zs = float(focus_table(lens)(focus_m))
    d_star = float(fmap.frame_diopters([focus_m], [r], calibrated=False)[0, 0])
    assert abs(_best_plane_offset_mm(lens, r, 1.0 / d_star, zs)) < 0.010
    if r >= 0.8:
        assert abs(_best_plane_offset_mm(lens, r, focus_m, zs)) > 0.05  # a thin lens's answer is off by far more


def test_map_on_axis_is_the_focus_table():
    fmap = load_json(map_path_for_lens(RF50))
    f = 1.0 / np.array([0.5, 1.0, 3.0, 10.0])
    np.testing.assert_allclose(fmap.frame_diopters(1 / f, [0.0], calibrated=False)[:, 0], f, atol=2e-3)


def test_stamped_surrogate_and_lens_file_carry_the_same_map():
    a = from_psf(ROOT / "models/psf_rf50.onnx")
    b, source = for_lens(RF50, compute=False)
    assert source.endswith("canon_rf50mm_f1.8.json")
    np.testing.assert_allclose(a.object_diopters, b.object_diopters)
    np.testing.assert_allclose(a.offset_diopters, b.offset_diopters)


def _plane_stack(depth_m: float, focus_m: np.ndarray, origin: tuple[int, int], n: int = 128, seed: int = 0):
    """A photo-textured plane rendered through the RF50's surrogate PSFs at the crop `origin` of its sensor."""
    import torch

    from aat_deploy.render import effects as fx
    from training.data.textures import photo_texture
    from training.render.layered import LayeredConfig
    from training.render.simulator import Simulator
    from training.render.sources import OnnxPSF

    lens = load_lens(RF50)
    sim = Simulator(lens, OnnxPSF(ROOT / "models/psf_rf50.onnx", lens, threads=1), fx.parse(["aberrations"]),
                    LayeredConfig(cell_px=32))
    tex = photo_texture(np.random.default_rng(seed), n, n, "test").astype(np.float32)
    st = sim.render_stack(torch.from_numpy(np.ascontiguousarray(tex.transpose(2, 0, 1))),
                          torch.full((n, n), depth_m), focus_m, origin=origin)
    return st.frames.numpy()


def _depth_on_sensor(frames, focus_m, fmap, origin, sensor_hw=(640, 960)):
    """Run the method on a crop, with the map's field radii of the crop's place on the sensor."""
    from dataclasses import replace

    n = frames.shape[-1]
    if fmap is not None:  # a map whose radius lookup sees the crop where it is: shift the sensor grid
        full_r = fmap.radius_px(*sensor_hw)
        crop_r = full_r[origin[0]:origin[0] + n, origin[1]:origin[1] + n]
        fmap = _CropMap(fmap, crop_r)
    return classical_depth(frames, focus_m, fmap, replace(FocusConfig(), fill="none"))


class _CropMap:
    """A BestFocusMap whose `radius_px` returns the radii of a crop of the sensor (tests only)."""

    def __init__(self, fmap, radii):
        self._m, self._r = fmap, radii

    def __getattr__(self, name):
        return getattr(self._m, name)

    def radius_px(self, h, w):
        assert (h, w) == self._r.shape
        return self._r


@pytest.mark.parametrize("depth_m", [1.6, 2.5])
@pytest.mark.parametrize("where", ["centre", "corner"])
def test_rendered_plane_depth_recovered_centre_and_corner(where, depth_m):
    """A photo-textured plane, 12 frames over 1.2-8 m (0.064 D apart), median over a 96 px patch, default settings:
    at the centre both mappings are within 0.015 D (measured -0.012 / -0.013 at 1.6 m, +0.011 / +0.010 at 2.5 m: the
    1 px pre-filter rounds the focus curve's peak, which the `ratio` estimator's power-law model places about a
    fifth of a frame off; without it 0.003, but the pre-filter halves the error under noise, chosen on validation
    stacks by benchmarks/select_focus_noise.py); in the top-left corner (field radius about 0.8) the
    aberration-aware one is within 0.012 D and the thin-lens one is off by more than 0.015 D and twice as much
    (measured thin 0.047 at 1.6 m and 0.077 at 2.5 m, aware 0.001 and -0.010): the RF50's field curvature."""
    focus = 1.0 / np.linspace(1 / 1.2, 1 / 8.0, 12)
    origin = (256, 416) if where == "centre" else (8, 12)
    frames = _plane_stack(depth_m, focus, origin)
    fmap = load_json(map_path_for_lens(RF50))
    inner = (slice(16, -16), slice(16, -16))
    thin = np.median(1 / _depth_on_sensor(frames, focus, None, origin).depth_m[inner]) - 1 / depth_m
    aware = np.median(1 / _depth_on_sensor(frames, focus, fmap, origin).depth_m[inner]) - 1 / depth_m
    if where == "centre":
        assert abs(aware) < 0.015 and abs(thin) < 0.015, (thin, aware)
    else:
        assert abs(aware) < 0.012 and abs(thin) > 0.015 and abs(aware) < 0.5 * abs(thin), (thin, aware)


def test_lens_without_a_stored_map_is_traced_on_the_spot(tmp_path):
    """--lens with no best_focus/<stem>.json and torch installed: a coarse uncalibrated map, traced now, that agrees
    with the shipped one's traced values within 0.01 D at sample points."""
    import shutil

    copy = tmp_path / "rf50_copy.json"
    shutil.copy(RF50, copy)
    m, source = for_lens(copy)
    assert source.startswith("traced now") and m.offset_diopters is None
    ref = load_json(map_path_for_lens(RF50))
    r, f = [0.0, 0.5, 0.9], [0.7, 2.0, 6.0]
    np.testing.assert_allclose(m.frame_diopters(f, r, calibrated=False), ref.frame_diopters(f, r, calibrated=False),
                               atol=0.01)
    with pytest.raises(Exception, match="no best-focus map"):
        for_lens(copy, compute=False)


def test_sagittal_and_tangential_foci_bracket_the_smallest_spot():
    """image_shift_mm along one direction: the tangential (radial spread) and sagittal (azimuthal spread) foci of
    the phone lens's outer field lie apart (astigmatism), and the smallest RMS spot, whose square is the sum of the
    two spreads, lies between them, weighted by how fast each grows; on axis all three coincide."""
    from training.optics.field_focus import N_RAYS, _pupil, image_shift_mm

    lens = load_lens(ROOT / "lenses/cellphone_asphere.json")
    pupil = _pupil(lens, N_RAYS)
    s = lens.sensor
    radial = np.array([s.width_mm, s.height_mm]) / math.hypot(s.width_mm, s.height_mm)
    zs = float(focus_table(lens, near_m=0.05)(0.1))
    for r in (0.0, 0.8):
        t = image_shift_mm(lens, r, 0.1, zs, pupil, direction=radial)
        sg = image_shift_mm(lens, r, 0.1, zs, pupil, direction=(-radial[1], radial[0]))
        rms = image_shift_mm(lens, r, 0.1, zs, pupil)
        if r == 0:
            assert abs(t - sg) < 5e-4 and abs(rms - t) < 5e-4  # mm: the pupil sampling's own asymmetry
        else:
            assert abs(t - sg) > 0.01  # mm: diopters apart on this lens
            assert min(t, sg) < rms < max(t, sg)
