"""aat-lens command line: JSON keys, PNG output, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import LENSES

from training.cli.lens import main

RF50 = str(LENSES / "canon_rf50mm_f1.8.json")


def test_info_json_has_the_documented_keys(capsys):
    assert main(["info", RF50, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    for k in ("efl_mm", "bfl_mm", "fno", "entrance_pupil_mm", "hfov_deg", "sensor_mm", "pixel_um"):
        assert k in d
    assert d["efl_mm"] == pytest.approx(49.56, abs=0.05)  # the patent's f = 49.56 mm
    assert d["pixel_um"] == pytest.approx(37.5)


def test_info_table(capsys):
    assert main(["info", RF50]) == 0
    out = capsys.readouterr().out
    assert "STOP" in out and "EFL" in out and "asphere" in out


def test_spot_json_and_png(tmp_path, capsys):
    png = tmp_path / "spot.png"
    assert main(["spot", RF50, "--field-deg", "10", "--focus-m", "2", "--json", "--png", str(png)]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["rms_um"] > 0 and png.stat().st_size > 1000
    with pytest.raises(SystemExit, match="exists"):
        main(["spot", RF50, "--field-deg", "10", "--focus-m", "2", "--png", str(png)])
    defocused = main(["spot", RF50, "--field-deg", "0", "--focus-m", "2", "--defocus-mm", "0.2", "--json"])
    assert defocused == 0
    # 0.2 mm of defocus at F/1.88 gives a blur disk of radius ~53 um (RMS ~ radius / sqrt(2) ~ 38 um)
    assert 25 < json.loads(capsys.readouterr().out)["rms_um"] < 50


def test_layout_png(tmp_path):
    png = tmp_path / "layout.png"
    assert main(["layout", RF50, "--png", str(png), "--focus-m", "1.5"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_lens_file_is_a_one_line_error(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "aat-lens-v1", "surfaces": []}')
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("aat-lens: error:") and "bad.json" in err and "\n" not in err


def test_focus_map_writes_draws_and_keeps_an_existing_map(tmp_path, capsys, monkeypatch):
    import training.optics.field_focus as ff
    from aat_deploy.focus.bestfocus import load_json

    traced = ff.best_focus_map
    small = lambda lens, table=None, progress=False: traced(lens, radii=[0.0, 0.6, 1.0], focus_diopters=[0.2, 1.0, 2.0],
                                                          table=table)
    monkeypatch.setattr(ff, "best_focus_map", small)  # a 3 x 3 map: seconds, not the full 13 x 33
    out, png = tmp_path / "map.json", tmp_path / "map.png"
    assert main(["focus-map", RF50, "--no-calibrate", "--out", str(out), "--png", str(png), "-q"]) == 0
    fmap = load_json(out)
    assert fmap.radius.tolist() == [0.0, 0.6, 1.0] and fmap.offset_diopters is None
    assert fmap.notes["lens_file"] == RF50 and fmap.notes["calibration_points"] == []
    assert fmap.frame_diopters([1.0], [0.0])[0, 0] == pytest.approx(1.0, abs=0.02)  # on axis: the nominal focus
    assert png.stat().st_size > 1000
    before = out.read_bytes()
    capsys.readouterr()
    assert main(["focus-map", RF50, "--out", str(out)]) == 2  # never replaced without --force
    assert "exists" in capsys.readouterr().err
    monkeypatch.setattr(ff, "best_focus_map", lambda *a, **k: pytest.fail("an existing map is not remade"))
    again = tmp_path / "again.png"
    assert main(["focus-map", RF50, "--out", str(out), "--png", str(again)]) == 0  # draws the stored map
    assert again.stat().st_size > 1000 and out.read_bytes() == before
    # --stamp stamps the stored map into a surrogate of this lens (what scripts/stamp_psf_optics.py did)
    import shutil

    import onnx

    from aat_deploy.focus.bestfocus import METADATA_KEY

    psf = shutil.copy(LENSES.parent / "models" / "psf_rf50.onnx", tmp_path / "psf.onnx")
    capsys.readouterr()
    assert main(["focus-map", RF50, "--out", str(out), "--stamp", str(psf)]) == 0
    assert METADATA_KEY in capsys.readouterr().out and out.read_bytes() == before
    md = {p.key: p.value for p in onnx.load(str(psf)).metadata_props}
    assert json.loads(md[METADATA_KEY]) == fmap.to_dict()


def test_focus_map_for_a_phone_lens_working_range(tmp_path, monkeypatch):
    """--near-m makes the traced map reach the lens's near working range (a phone lens at 5 cm); --calibrate-at and
    --sweep-d reach the calibration (a lens with ~30x less blur per diopter needs ~30x wider sweeps)."""
    import training.optics.field_focus as ff
    import training.render.focus_calibration as fc
    from aat_deploy.focus.bestfocus import load_json

    traced = ff.best_focus_map
    monkeypatch.setattr(ff, "best_focus_map", lambda lens, table=None, progress=False: traced(
        lens, radii=[0.0, 1.0], focus_diopters=[table.diopters[0], table.diopters[-1]], table=table))
    seen = {}

    def fake_calibrate(lens, fmap, cfg, progress=True):
        seen["cfg"] = cfg
        return fmap, []

    monkeypatch.setattr(fc, "calibrate", fake_calibrate)
    out = tmp_path / "phone.json"
    phone = str(LENSES / "cellphone_asphere.json")
    assert main(["focus-map", phone, "--near-m", "0.05", "--calibrate-at", "0.07,0.3", "--sweep-d", "5.5",
                 "--calibrate-radii", "0.8,0,0.7", "--out", str(out), "-q"]) == 0
    fmap = load_json(out)
    assert fmap.focus_diopters[-1] == pytest.approx(20.0)  # the map reaches 5 cm
    assert seen["cfg"].focus_m == (0.07, 0.3) and seen["cfg"].sweep_d == 5.5
    assert seen["cfg"].radii == (0.0, 0.7, 0.8)
    with pytest.raises(SystemExit):
        main(["focus-map", phone, "--calibrate-radii", "0.5,1.2", "--out", str(out), "--force", "-q"])


def test_focus_map_recalibrate_keeps_the_traced_map(tmp_path, monkeypatch, capsys):
    """--recalibrate calibrates a stored map again without tracing: its traced part kept, its old calibration
    dropped before the new one; without --force nothing is written; another lens's map is refused."""
    import dataclasses

    import training.optics.field_focus as ff
    import training.render.focus_calibration as fc
    from aat_deploy.focus.bestfocus import load_json

    stored = load_json(LENSES / "best_focus" / "canon_rf50mm_f1.8.json")
    src = tmp_path / "stored.json"
    dataclasses.replace(stored, offset_diopters=np.full_like(stored.object_diopters, 0.3)).save_json(src)
    monkeypatch.setattr(ff, "best_focus_map", lambda *a, **k: pytest.fail("traced anew"))
    seen = {}

    def fake_calibrate(lens, fmap, cfg, progress=True):
        seen["offset"], seen["cfg"] = fmap.offset_diopters, cfg
        return dataclasses.replace(fmap, offset_diopters=np.full_like(fmap.object_diopters, -0.1)), []

    monkeypatch.setattr(fc, "calibrate", fake_calibrate)
    out = tmp_path / "new.json"
    args = ["focus-map", RF50, "--recalibrate", str(src), "--calibrate-radii", "0,0.5", "--calibrate-textures", "5",
            "--out", str(out), "-q"]
    assert main(args) == 2 and not out.exists() and "--force" in capsys.readouterr().err
    assert main(args + ["--force"]) == 0
    new = load_json(out)
    assert seen["offset"] is None and seen["cfg"].radii == (0.0, 0.5) and seen["cfg"].n_textures == 5
    assert (seen["cfg"].measure, seen["cfg"].prefilter_px) == ("mlap2", 1.0)  # the runtime's unless given
    np.testing.assert_array_equal(new.object_diopters, stored.object_diopters)
    assert np.all(new.offset_diopters == -0.1)
    # --calibrate-measure / --calibrate-prefilter-px: the map belongs to that measure (its notes say which)
    assert main(args + ["--force", "--calibrate-measure", "narrowband", "--calibrate-prefilter-px", "0"]) == 0
    assert (seen["cfg"].measure, seen["cfg"].prefilter_px) == ("narrowband", 0.0)
    assert seen["cfg"].crop_px == 64  # the default patch unless given
    assert main(args + ["--force", "--calibrate-crop-px", "16"]) == 0 and seen["cfg"].crop_px == 16
    with pytest.raises(SystemExit):
        main(args + ["--force", "--calibrate-measure", "fog"])
    phone = str(LENSES / "cellphone_asphere.json")
    assert main(["focus-map", phone, "--recalibrate", str(src), "--out", str(tmp_path / "x.json"), "--force",
                 "-q"]) == 2
    assert "not" in capsys.readouterr().err and not (tmp_path / "x.json").exists()


def test_calibration_points_outside_a_surrogates_range_are_not_rendered():
    """A surrogate clamps depths beyond its range: a point whose traced best focus lies there is left out (NaN,
    with a note) instead of measured on an object rendered at the range's end."""
    from aat_deploy.focus.bestfocus import load_json
    from aat_deploy.lens.io import load_lens
    from training.render.focus_calibration import CalibrationConfig, measure_point

    lens = load_lens(RF50)
    fmap = load_json(LENSES / "best_focus" / "canon_rf50mm_f1.8.json")
    p = measure_point(lens, fmap, 0.5, 1.0, CalibrationConfig(), sim=object(), ranges=((0.0, 0.5), (0.0, 5.0)))
    assert np.isnan(p["offset_diopters"]) and "outside the PSFs' depth range" in p["note"]
