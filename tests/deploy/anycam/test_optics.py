"""The any-camera model's camera optics (aat_deploy.anycam.optics) and focus maps (aat_deploy.anycam.maps): parsing
--camera (hypothesis: any text is either read or refused in one line), EXIF sources, the thin-lens defocus scale
against its hand-computed value, and the maps of a thin lens and of a lens's best-focus map."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aat_deploy.anycam.maps import FocusMapping
from aat_deploy.anycam.optics import CameraOptics, from_exif, parse_camera
from aat_deploy.errors import CaptureError
from aat_deploy.focus.bestfocus import BestFocusMap


def test_parse_camera_reads_three_numbers():
    c = parse_camera("50, 1.8, 4.3", 6000)
    assert (c.focal_mm, c.f_number, c.pixel_um, c.native_width_px) == (50.0, 1.8, 4.3, 6000)
    assert c.pixel_um_at(1500) == pytest.approx(17.2)


@pytest.mark.parametrize("text", ["50,1.8", "50,1.8,4.3,1", "a,b,c", "50,-1.8,4", "50,1.8,nan", "0,1,1", "1e9,2,3", ""])
def test_parse_camera_refuses_in_one_line(text):
    with pytest.raises(ValueError) as e:
        parse_camera(text, 1000)
    assert "\n" not in str(e.value) and "--camera" in str(e.value)


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=40))
def test_parse_camera_never_fails_otherwise(text):
    try:
        c = parse_camera(text, 1000)
    except ValueError as e:
        assert "\n" not in str(e)
    else:
        assert all(math.isfinite(v) and v > 0 for v in (c.focal_mm, c.f_number, c.pixel_um))


def test_thin_lens_defocus_scale_matches_the_hand_computed_blur():
    # 50 mm f/2 focused at 2 m: entrance pupil 25 mm; image distance v_f = 1/(1/50 - 1/(2000 - v_f)) ...
    c = CameraOptics(50.0, 2.0, 5.0, 1000, "test")
    k = c.defocus_px_per_d(2.0, 1000)
    # near focus the blur diameter is A * v_f * |1/u - 1/u_f| (A the pupil, v_f the image distance, u the object's
    # distance from the lens, u_f = 2000 mm - v_f); per diopter of the sensor-referred distance d = u + v_f,
    # d(1/u) / d(1/d) = (d / u)^2
    f, big = 50.0, 2000.0
    v_f = 2 * big * f / (big + math.sqrt(big * big - 4 * big * f))
    expected = 25.0 * v_f * 1e-3 * (big / (big - v_f)) ** 2 / 5.0e-3  # mm of blur per diopter / pixel pitch (mm)
    assert k == pytest.approx(expected, rel=0.02)
    assert c.defocus_px_per_d(2.0, 500) == pytest.approx(k / 2, rel=1e-9)  # half the pixels, half the blur in px


def _meta(**kw):
    base = dict(focal_length_mm=None, f_number=None, focal_length_35mm=None, focal_plane_px_per_mm=None,
                width=None, height=None)
    base.update(kw)
    return SimpleNamespace(**base)


def test_exif_sensor_from_focal_plane_resolution_or_35mm_equivalent():
    c = from_exif([_meta(focal_length_mm=50, f_number=1.8, focal_plane_px_per_mm=250.0, width=6000, height=4000)],
                  6000, "cap")
    assert c.pixel_um == pytest.approx(4.0) and "FocalPlane" in c.source
    # an iPhone-like JPEG: 3.99 mm, 35 mm equivalent 28 mm, 4032 x 3024: crop 7.02, diagonal 6.16 mm
    c = from_exif([_meta(focal_length_mm=3.99, f_number=1.8, focal_length_35mm=28.0, width=4032, height=3024)],
                  4032, "cap")
    diag = math.hypot(36, 24) * 3.99 / 28.0
    assert c.pixel_um * 1e-3 * math.hypot(4032, 3024) == pytest.approx(diag, rel=1e-6)
    # frames resized after capture: the pitch at the frames' own width
    c2 = from_exif([_meta(focal_length_mm=3.99, f_number=1.8, focal_length_35mm=28.0, width=4032, height=3024)],
                   1008, "cap")
    assert c2.pixel_um == pytest.approx(4 * c.pixel_um)


@pytest.mark.parametrize("kw,missing", [(dict(f_number=2.0, focal_plane_px_per_mm=200.0), "focal length"),
                                        (dict(focal_length_mm=5.0, focal_length_35mm=26.0), "f-number"),
                                        (dict(focal_length_mm=5.0, f_number=2.0), "sensor size")])
def test_exif_refuses_what_it_cannot_know_in_one_line(kw, missing):
    with pytest.raises(CaptureError) as e:
        from_exif([_meta(**kw)], 1000, "captures/x")
    msg = str(e.value)
    assert missing in msg and "--camera" in msg and "\n" not in msg and msg.startswith("captures/x")


def test_thin_lens_map_is_the_reported_focus_everywhere():
    mp = FocusMapping("thin_lens", optics=CameraOptics(50, 2.0, 5.0, 400, "t"))
    fd = mp.frame_diopters([0.5, 1.0, 4.0], 6, 8)
    assert fd.shape == (3, 6, 8) and np.allclose(fd[:, 2, 3], [2.0, 1.0, 0.25])
    k = mp.defocus_px_per_d([0.5, 1.0, 4.0], 6, 8)
    assert k.shape == (1, 6, 8) and np.allclose(k, mp.optics.defocus_px_per_d(2 / (2 + 0.25), 8))


def test_best_focus_map_moves_focus_with_the_field_radius():
    bf = BestFocusMap(np.array([0.0, 0.5, 1.0]), np.array([0.1, 1.0, 3.0]),
                      np.array([[0.1, 1.0, 3.0], [0.08, 0.98, 2.98], [0.0, 0.9, 2.9]]), (36.0, 24.0))
    mp = FocusMapping("best_focus", best_focus=bf)
    fd = mp.frame_diopters([1.0], 60, 90)
    assert fd[0, 30, 45] == pytest.approx(1.0, abs=2e-3)  # centre
    assert fd[0, 0, 0] == pytest.approx(0.9, abs=5e-3)  # corner: 0.1 D farther


def test_calibration_map_applies_the_focus_error_the_tilt_and_the_measured_blur(tmp_path):
    from aat_deploy.anycam.model import mapping_from_args
    from aat_deploy.calibrate.format import CameraCalibration, CameraIdentity, FieldPoly, FocusError, save_calibration

    # best focus tilted along x by 0.1 D edge to edge; the reported focus 10 % too far (scale 0.9); blur 20 px/D
    tilt = FieldPoly(np.array([[1, 0]]), np.array([[0.05]]), (0.1, 3.0))
    blur = FieldPoly(np.array([[0, 0]]), np.array([[20.0]]), (0.1, 3.0))
    cal = CameraCalibration(CameraIdentity(focal_length_mm=50, f_number=2.0), (200, 100),
                            FocusError("scale", scale=1 / 0.9), tilt, blur, (36.0, 18.0))
    path = save_calibration(cal, tmp_path / "cam.json")
    mp = mapping_from_args(calibration=path)
    assert mp.kind == "calibration" and mp.lens_optics[:3] == (50, 2.0, 36.0)
    fd = mp.frame_diopters([1.0, 2.0], 10, 20)
    on_axis = np.array([1.0, 0.5]) / 0.9
    assert np.allclose(fd[:, 5, 10], on_axis, atol=3e-3)
    assert fd[0, 5, -1] - fd[0, 5, 0] == pytest.approx(0.1 * 19 / 20, abs=3e-3)  # the tilt, pixel centres
    k = mp.defocus_px_per_d([1.0, 2.0], 10, 20)
    assert np.allclose(k, 20.0 * 20 / 200)  # measured at 200 px across, used at 20
